"""Discovery settings measured on the examples (docs/performance.md): python -m benchmarks.discovery_eps"""
import numpy as np, tomllib
from stabjax.run.sweep import run_spec
from stabjax.mapping.discover import discover, DiscoveryConfig
for ex in ["pendulum", "duffing", "lorenz", "lorenz63"]:
    spec = tomllib.load(open(f"examples/{ex}/spec.toml","rb"))
    spec["system"] = f"examples/{ex}/" + spec["system"]
    spec["sample"]["n"] = 1000
    if ex != "lorenz63":
        spec["outcomes"] = {"lyapunov": True}
    ds = run_spec(spec)
    res = {k: ds[k].values.reshape(1000, *ds[k].shape[1:]) for k in ("feat_mean", "feat_std", "feat_min", "feat_max", "feat_final", "lyapunov", "solver_status")}
    obs = tuple(str(o) for o in ds["observable"].values)
    ok = res["solver_status"] == 0
    ref = ds["outcome"].values.ravel()
    if ex == "lorenz63":  # physical reference: at rest (std x < 1e-3) at C+ / C-, else the chaotic attractor
        sx, mx = res["feat_std"][:, 0], res["feat_mean"][:, 0]
        ref = np.where(sx < 1e-3, np.where(mx > 0, 0, 1), 2)
    for eps in [0.01, 0.02, 0.05, 0.1, 0.2]:
        row = []
        for ms in [3, 5, 10]:
            d = discover(res, obs, DiscoveryConfig(eps=eps, min_samples=ms), ok, 1e-8, 1e-8)
            lab = d.labels[ok]
            r = ref[ok]
            # majority map found -> declared, one-to-one?
            used = np.unique(lab[lab >= 0])
            m = {g: np.bincount(r[lab == g]).argmax() for g in used}
            agree = np.mean([(m.get(l, -9) == x) for l, x in zip(lab, r)])
            row.append(f"ms={ms}: {len(used)} groups {'1:1' if len(set(m.values())) == len(m) else 'MERGED'} agree {agree:.3f} uncl {np.mean(lab < 0):.3f}")
        print(ex, f"eps={eps}", " | ".join(row))
