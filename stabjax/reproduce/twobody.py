"""`stabjax reproduce twobody`: Bezglasnyi & Mysina (2011), carrier + rotor (docs/models/twobody.md).

The paper has no numerical example. We use the test case of docs/models/twobody.md ("Test case"), a small
spacecraft-like carrier I1 = diag(10, 8, 6) kg m^2 and an *unbalanced* rotor with products of
inertia, I2 = [[2, .3, .2], [.3, 1.5, -.1], [.2, -.1, 1]] kg m^2 (I2xx != I2yy), spinning at
delta' = 3 rad/s; alpha = 2 N m (alpha_i = 2, 1.5, 1 for the triaxial task), r0 = e_z; the
rotating frame turns at w0(t) = (0.3 sin 0.5t, 0.2, 0.4 cos 0.3t) rad/s (carrier components).

Figures written to ``out_dir``:

* ``examples.png``: one panel per control (Theorems 1-4): error angle and |x| against t for
  the physically correct loop, the paper's printed gyroscopic terms (variant 1) and, in the
  rotating frame, the printed kinematics s' = -(w0 + x) x s (which does not converge).
* ``b_rate_map.png``: converged fraction over random starts in the (b, delta') plane with the
  exact bound b*(delta') and the printed-equation bound drawn (both variants simulated).
* ``b_asym_map.png``: the same against the rotor asymmetry I2xx - I2yy.
* ``random_starts.png``: converged fraction +- standard error for random starts over the
  sphere / SO(3) (Theorems 1, 2, 4), for starts near the unstable equilibria, and for the
  printed rotating-frame kinematics; ``summary.txt`` lists the numbers and the failures.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from ..fold import verdict as V
from ..config import IntegrateConfig
from ..engines.simulate import batch_params, simulate, solve_batch
from ..present.labels import cell_note
from ..present.maps import converged_fraction, plot_sweep
from ..model.registry import get_system
from ..run.sweep import run_spec
from ..systems import twobody_theory as tt

ICFG = dict(rtol=1e-8, atol=1e-10, n_checkpoints=400)


def _examples(out_dir: Path, quick: bool) -> Path:
    t1 = 100.0 if quick else 200.0
    ts = np.linspace(0.0, t1, 801)
    fig, axs = plt.subplots(2, 2, figsize=(11, 7.5), constrained_layout=True)
    cases = [
        ("twobody_uniaxial", "Theorem 1: uniaxial, König frame, b = 3 (b* = 2.35)", {}),
        ("twobody_triaxial", "Theorem 2: triaxial, König frame, b = 3", {}),
        ("twobody_uniaxial_rotating", "Theorem 3: uniaxial, rotating frame, b = 4.1 (b* = 3.10)", {}),
        ("twobody_triaxial_rotating", "Theorem 4: triaxial, rotating frame, b = 4.1", {}),
    ]
    for ax, (name, title, base) in zip(axs.ravel(), cases):
        sys_ = get_system(name)
        runs = [("physical", {"variant": 0}, "-"), ("printed G = I2 delta^T (variant 1)", {"variant": 1}, "--")]
        if sys_.rotating:
            runs.append(("printed kinematics s' = -(w0+x) x s", {"variant": 0, "kinematics": 1}, ":"))
        for label, over, ls in runs:
            ds = simulate(sys_, {**base, **over}, t1=t1, ts=ts, rtol=1e-10, atol=1e-12)
            ax.semilogy(ds.t, np.maximum(ds["angle"], 1e-16), ls=ls, color="tab:blue", lw=1.1,
                        label=f"angle, {label}")
            ax.semilogy(ds.t, np.maximum(ds[sys_.observables[1]], 1e-16), ls=ls, color="tab:orange", lw=1.0,
                        label=f"|{'x' if sys_.rotating else 'w'}|, {label}")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("time t [s]")
        ax.set_ylim(1e-13, 10)
        ax.legend(fontsize=6.5, loc="lower left")
    fig.suptitle("Bezglasnyi & Mysina controls on the test-case carrier + unbalanced rotor", fontsize=10)
    p = out_dir / "examples.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p


def _spec(system, name, grid, params, n, t1, seed=0, sample=None):
    sample = sample or {"s0": {"dist": "sphere"}, "w0": {"dist": "ball", "radius": 0.5}}
    return {"system": system, "name": name, "params": params, "grid": grid,
            "sample": {"n": n, "seed": seed, **sample}, "integrate": {"t1": t1, **ICFG}}


def _bstar_curves(system, key, values, base):
    s = get_system(system)
    p = batch_params(s, base, n=len(values))
    if "[" in key:
        nm, idx = key.split("[")
        idx = tuple(int(i) for i in idx.rstrip("]").split(","))
        p[nm][(slice(None),) + idx] = values
    else:
        p[key] = np.asarray(values, float)
    p["b"] = np.zeros(len(values))
    d = s.theory(s.check(p)).derived
    return d["b_star_physical"], d["b_star_paper"]


def _map(out_dir: Path, quick: bool, fname, key, ylabel, lo, hi, base, title) -> Path:
    ny, nb, n = (4, 4, 3) if quick else (7, 8, 6)
    t1 = 150.0 if quick else 300.0
    grid = {key: {"start": lo, "stop": hi, "num": ny}, "b": {"start": 0.25, "stop": 8.0, "num": nb}}
    from matplotlib import patheffects

    from ..present.maps import legend_below

    fig, axs = plt.subplots(1, 2, figsize=(12, 6), constrained_layout=True)
    yy = np.linspace(lo, hi, 201)
    bphys, bpaper = _bstar_curves("twobody_uniaxial", key, yy, base)
    halo = [patheffects.withStroke(linewidth=3.8, foreground="k")]  # the white line shows on the legend's white too
    for ax, variant in zip(axs, (0, 1)):
        ds = run_spec(_spec("twobody_uniaxial", f"{fname}_v{variant}", grid, {**base, "variant": variant}, n, t1))
        plot_sweep(ds, ax=ax)
        handles = list(ax.get_legend().legend_handles) if ax.get_legend() else []
        handles.append(ax.plot(bphys, yy, color="w", lw=1.8, ls="-", path_effects=halo,
                               label="bound b* of the physically correct equations (exact)")[0])
        handles.append(ax.plot(bpaper, yy, color="#CC79A7", lw=1.8, ls="--",
                               label="bound b* of the paper's printed equations")[0])
        ax.set_xlim(0, 8.2)
        ax.set_ylabel(ylabel)
        simulated = "physically correct equations" if variant == 0 else "the paper's printed equations"
        ax.set_title(f"{title}\n{simulated} simulated; {cell_note(ds)}", fontsize=9)
        legend_below(ax, handles, ncol=1, width=80)
    p = out_dir / f"{fname}.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p


def _near(system, n, rng):
    """Starts within 1e-3 rad of the unstable equilibria, at rest."""
    s = get_system(system)
    p = batch_params(s, {}, n=n)
    if s.triaxial:
        eqs = [S for _, S, claim in tt.equilibria_triaxial(np.eye(3)) if claim == "unstable"]
        from ..systems.twobody import rotation_matrix
        p["S0"] = np.stack([eqs[i % 3] @ rotation_matrix(rng.normal(size=3), 1e-3) for i in range(n)])
    else:
        v = np.array([0.0, 0.0, -1.0]) + 1e-3 * rng.normal(size=(n, 3))
        p["s0"] = v / np.linalg.norm(v, axis=1, keepdims=True)
    p["x0" if s.rotating else "w0"] = np.zeros((n, 3))
    return s, p


def _random(system, n, rng, over=None):
    s = get_system(system)
    p = batch_params(s, over or {}, n=n)
    if s.triaxial:
        q = rng.normal(size=(n, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        w, x, y, z = q.T
        p["S0"] = np.stack([
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)
    else:
        v = rng.normal(size=(n, 3))
        p["s0"] = v / np.linalg.norm(v, axis=1, keepdims=True)
    u = rng.normal(size=(n, 3))
    u *= (rng.uniform(size=(n, 1)) ** (1 / 3)) / np.linalg.norm(u, axis=1, keepdims=True)
    p["x0" if s.rotating else "w0"] = u
    return s, s.check(p)


def _random_starts(out_dir: Path, quick: bool) -> tuple[Path, list[str]]:
    n = 8 if quick else 64
    icfg = IntegrateConfig(t1=300.0, **ICFG)  # escaping from near s0 = -r0 takes ~30 s, settling ~150 s more
    rng = np.random.default_rng(7)
    rows = []
    cases = [
        ("Thm 1 sphere", lambda: _random("twobody_uniaxial", n, rng)),
        ("Thm 1 near s0=-r0", lambda: _near("twobody_uniaxial", n, rng)),
        ("Thm 2 SO(3)", lambda: _random("twobody_triaxial", n, rng)),
        ("Thm 2 near pi-rot.", lambda: _near("twobody_triaxial", n, rng)),
        ("Thm 3 sphere", lambda: _random("twobody_uniaxial_rotating", n, rng)),
        ("Thm 4 SO(3)", lambda: _random("twobody_triaxial_rotating", n, rng)),
        ("Thm 3 printed kin.", lambda: _random("twobody_uniaxial_rotating", n, rng, {"kinematics": 1})),
    ]
    if quick:  # one compile per system is the cost; keep the König uniaxial cases only
        cases = [c for c in cases if c[0].startswith("Thm 1")]
    lines = []
    for label, make in cases:
        s, p = make()
        out = solve_batch(s, p, icfg)
        out = {k: (x[:, -1] if V.TRAILING_DIMS.get(k) == ("horizon",) and x.ndim == 2 else x)  # at t1
               for k, x in out.items()}
        v = out["verdict"]
        frac = float((v == V.CONVERGED).mean())
        se = float(np.sqrt(frac * (1 - frac) / len(v)))
        guaranteed = bool(s.theory(p).predicates["guaranteed"].ok.all())
        rows.append((label, frac, se, guaranteed))
        counts = V.counts(v)
        lines.append(f"{label:24s} converged {frac:.3f} +- {se:.3f} (n = {len(v)}); theory guarantees: {guaranteed}; "
                     + ", ".join(f"{k} {c}" for k, c in counts.items() if c))
        for i in np.nonzero(v != V.CONVERGED)[0][:3]:
            lines.append(f"    failure #{i}: verdict {V.NAMES[v[i]]}, final error {out['error_t1'][i]:.3g} rad")
    fig, ax = plt.subplots(figsize=(9, 4), constrained_layout=True)
    x = np.arange(len(rows))
    ax.bar(x, [r[1] for r in rows], yerr=[r[2] for r in rows], capsize=4,
           color=[V.COLORS[0] if r[3] else "0.6" for r in rows])
    ax.set_xticks(x, [r[0] for r in rows], rotation=20, fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("fraction converged (± SE)")
    ax.set_title(f"random starts (n = {n} each); green: theorem's condition holds", fontsize=9)
    p = out_dir / "random_starts.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p, lines


def run(out_dir: Path, quick: bool = False) -> list[Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    summary = ["Bezglasnyi & Mysina (2011), carrier + rotor: test-case parameters (docs/models/twobody.md)", ""]
    for name in ("twobody_uniaxial", "twobody_uniaxial_rotating"):
        s = get_system(name)
        d = s.theory(batch_params(s, {}, n=1)).derived
        summary.append(f"{name}: b* physical {d['b_star_physical'][0]:.4f}, paper's equations "
                       f"{d['b_star_paper'][0]:.4f}, formula as printed {d['b_star_printed'][0]:.4f}")
    if not quick:
        files.append(_examples(out_dir, quick))
    files.append(_map(out_dir, quick, "b_rate_map", "Omega_r", r"rotor rate relative to the carrier, $\delta'$ [rad/s]",
                      -6.0, 6.0, {}, "Theorem 1, damping gain against rotor rate"))
    if not quick:
        files.append(_map(out_dir, quick, "b_asym_map", "I2[0,0]",
                          r"rotor moment of inertia $I_{2xx}$ [kg m^2] ($I_{2yy}$ = 1.5)", 1.0, 3.0,
                          {"Omega_r": 3.0}, "Theorem 1, damping gain against rotor asymmetry"))
    p, lines = _random_starts(out_dir, quick)
    files.append(p)
    summary += [""] + lines
    s = out_dir / "summary.txt"
    s.write_text("\n".join(summary) + "\n")
    files.append(s)
    return files


__all__ = ["run", "converged_fraction"]
