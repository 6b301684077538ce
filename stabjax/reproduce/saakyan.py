"""`stabjax reproduce saakyan`: a documented example set for Saakyan's five closed loops.

The paper has no numerical example; the examples are ours (docs/models/saakyan.md, "Examples"):

* ``examples.png``: error metric angle(S0, H0) + |w1|/lam against time for
  B-1 moving target (the documented case, A,B,C = 4,3,2, omega0 = (0.2 sin 0.3t, 0.1, 0.15 cos 0.2t)),
  B-1 with a precession program and the body A,B,C = 5,6,4 (issue's choice),
  Corollary 2 with and without mu (the unstable case), B-2 with lam^2 = nu and off it,
  B-3 with the Theorem-3 torque and with (3.9)+(3.21) (double-counted term), B-4 with h
  between the exact and the printed bound (4.4).
* the minimal fatal shock of the target motion along the gain, H0 on each principal axis, against the radii of
  (1.18) and (1.22) (``sweeps/saakyan_shock_*.toml``, :mod:`stabjax.explore.shock`): a figure per axis and the numbers,
  witnesses and replay commands in ``saakyan_shock.json`` / ``saakyan_shock.txt`` (not in quick mode);
* one verdict map per shipped sweep ``sweeps/saakyan_*.toml`` (the engine's ``plot_sweep``),
  plus: region-of-attraction curves (converged fraction +- standard error against |delta0|,
  with the guaranteed radii l of (1.18) and 2 of (1.22)), gain maps with the (1.10), (1.21),
  exact [D] and middle-axis boundaries, and the lam^2/nu and h/(lam m1) axes across 1.

``quick=True`` runs four examples (two systems) on short horizons and one shrunken sweep (for tests).
"""
from __future__ import annotations

import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from ..fold import verdict as V
from ..engines.simulate import simulate
from ..present.labels import words
from ..present.maps import axis_label, converged_fraction, legend_below, plot_sweep
from ..run.sweep import run_spec
from ..systems import saakyan_theory as T
from . import load_shipped, shipped_specs


_H = tuple(np.round(np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]), 12))
_S = tuple(np.round(np.array([0.2, 0.9, -0.3]) / np.linalg.norm([0.2, 0.9, -0.3]), 12))

# (label, system, params, t1)
EXAMPLES = [
    ("B-1 moving S (documented case), K = 7.2", "saakyan_moving",
     dict(I=(4.0, 3.0, 2.0), lam=0.5, K=7.2, H=_H, S0=_S), 100.0),
    ("B-1 precession program, A,B,C = 5,6,4", "saakyan_moving",
     dict(I=(5.0, 6.0, 4.0), lam=0.5, K=6.0, H=_H, S0=_S, w0c=(0.0, 0.0, 0.2), w0a=(0.1, 0.1, 0.0),
          w0f=(0.5, 0.5, 0.0), w0phi=(np.pi / 2, 0.0, 0.0)), 100.0),
    ("Cor. 2 fixed S, middle axis (5,6,4), K = 5", "saakyan_fixed",
     dict(I=(5.0, 6.0, 4.0), lam=0.5, K=5.0, H=(1.0, 0.0, 0.0), S0=_S), 100.0),
    ("Cor. 2 without mu: unstable", "saakyan_fixed",
     dict(I=(5.0, 6.0, 4.0), lam=0.5, K=5.0, H=_H, init=1.0, rho=1e-4, use_mu=0.0), 100.0),
    ("B-2 lam^2 = nu = 0.3, K = 6", "saakyan_gravity",
     dict(I=(4.0, 3.0, 2.0), lam=float(np.sqrt(0.3)), K=6.0, nu=0.3, H=_H, S0=_S), 100.0),
    ("B-2 off the knife edge, lam^2/nu = 2, K = 1", "saakyan_gravity",
     dict(I=(4.0, 3.0, 2.0), lam=0.5, K=1.0, nu=0.125, H=_H, S0=_S), 100.0),
    ("B-3 Theorem-3 torque, h = 6", "saakyan_gyrostat",
     dict(I=(4.0, 3.0, 2.0), Jw=(0.3, 0.2, 0.4), lam=0.5, h=6.0, H=_H, S0=_S,
          eta0=tuple(np.array([0.8, -0.6, 2.0]) - 6 * np.array(_H))), 100.0),
    ("B-3 (3.9)+(3.21): term counted twice", "saakyan_gyrostat",
     dict(I=(4.0, 3.0, 2.0), Jw=(0.3, 0.2, 0.4), lam=0.5, h=6.0, H=_H, S0=_S, torque=1.0,
          eta0=tuple(np.array([0.8, -0.6, 2.0]) - 6 * np.array(_H))), 100.0),
    ("B-4 h = 0.8: exact (4.4) yes, printed no", "saakyan_gyrostat_gravity",
     dict(I=(4.0, 3.0, 2.0), Jw=(1.0, 1.0, 1.0), lam=1.0, nu=1.0, h=0.8, H=_H, S0=_S), 400.0),
]

# what each shipped sweep's map shows, in words (the figures' titles; a spec without one is an error)
TITLES = {
    "saakyan_double_count": "gyrostat (B-3): Theorem 3's torque against (3.9) with (3.21) as printed",
    "saakyan_gain_max_axis": "fixed direction (Cor. 2): gains, H0 along the axis of largest moment",
    "saakyan_gain_mid_axis": "fixed direction (Cor. 2): gains, H0 along the axis of middle moment",
    "saakyan_gain_min_axis": "fixed direction (Cor. 2): gains, H0 along the axis of smallest moment",
    "saakyan_gravity_ratio": "central gravity field (Theorem 2): gravity parameter against gain",
    "saakyan_gyrostat_gravity_44": "gyrostat in a gravity field (Theorem 4): gain across the bound (4.4)",
    "saakyan_gyrostat_h": "gyrostat (Theorem 3): gain h, random starts anywhere",
    "saakyan_no_mu": "fixed direction (Cor. 2) without and with the stabilising torque mu",
    "saakyan_region_axis": "fixed direction (Cor. 2): size of the initial perturbation, H0 along a principal axis",
    "saakyan_region_generic": "fixed direction (Cor. 2): size of the initial perturbation, H0 off the principal axes",
    "saakyan_shock_max_axis": "fixed direction (Cor. 2): minimal fatal shock against (1.18) and (1.22), H0 along the "
                              "axis of largest moment",
    "saakyan_shock_mid_axis": "fixed direction (Cor. 2): minimal fatal shock against (1.18) and (1.22), H0 along the "
                              "axis of middle moment",
    "saakyan_shock_min_axis": "fixed direction (Cor. 2): minimal fatal shock against (1.18) and (1.22), H0 along the "
                              "axis of smallest moment",
    "saakyan_shock_gyrostat": "gyrostat (Theorem 3): minimal fatal shock against the claim of convergence from every "
                              "start",
}
_AXIS = {0: "smallest", 1: "middle", 2: "largest"}
# one colour per theorem on every Saakyan figure (Okabe & Ito): Cor. 2 (Theorem 1) black, Cor. 1 vermillion,
# our exact bound sky blue, the paper's middle-axis condition reddish purple
C_TH1, C_COR1, C_EXACT, C_MID = "k", "#D55E00", "#56B4E9", "#CC79A7"

QUICK_SWEEPS = ("saakyan_region_generic",)
QUICK_EXAMPLES = (2, 3, 6, 7)  # one compile per system: fixed with/without mu, B-3 both torques


def _examples(out_dir: Path, quick: bool) -> list[Path]:
    examples = [EXAMPLES[i] for i in QUICK_EXAMPLES] if quick else EXAMPLES
    fig, axs = plt.subplots(3, 3, figsize=(13, 9.5), constrained_layout=True, sharex=False)
    summary = []
    for ax in axs.ravel()[len(examples):]:
        ax.set_visible(False)
    for ax, (label, name, over, t1) in zip(axs.ravel(), examples):
        t1 = 30.0 if quick else t1
        ds = simulate(name, over, t1=t1, ts=np.linspace(0, t1, 301), rtol=1e-10, atol=1e-12)
        e = np.maximum(ds["error"].values, 1e-16)
        ax.semilogy(ds.t, e, lw=1.0, color="#0072B2", label=r"error metric, angle + $|w_1|/\lambda$")
        ax.semilogy(ds.t, np.maximum(ds["angle"].values, 1e-16), lw=0.8, ls="--", color="#D55E00",
                    label="angle between S0 and H0 [rad]")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("time t [s]")
        ax.set_ylim(1e-13, max(10.0, e.max() * 2))
        ax.grid(alpha=0.3)
        summary.append(dict(label=label, system=name, t1=t1, error_t0=float(e[0]), error_t1=float(e[-1]),
                            angle_t1=float(ds["angle"].values[-1])))
    axs[0, 0].legend(fontsize=8)
    fig.suptitle("Saakyan (1974): the five closed loops, error = angle(S0,H0) + |w1|/lam", fontsize=11)
    png = out_dir / "saakyan_examples.png"
    fig.savefig(png, dpi=90)
    plt.close(fig)
    js = out_dir / "saakyan_examples.json"
    js.write_text(json.dumps(summary, indent=1))
    return [png, js]


def _shrink(spec: dict) -> dict:
    spec = json.loads(json.dumps(spec))
    if "sample" in spec:
        spec["sample"]["n"] = min(int(spec["sample"].get("n", 4)), 4)
    for k, v in list(spec.get("grid", {}).items()):
        if isinstance(v, dict):
            spec["grid"][k] = dict(v, num=min(int(v["num"]), 3))
        else:
            spec["grid"][k] = v[:: max(1, len(v) // 3)][:3]
    spec.setdefault("integrate", {})["t1"] = min(float(spec["integrate"].get("t1", 100.0)), 100.0)
    return spec


def _frac_1d(ds, dim):
    p, se = converged_fraction(ds)
    return ds[dim].values, p.values, se.values


def _fixed(ds) -> dict:
    return json.loads(ds.attrs["fixed_params_json"])


def _where_h0(ds) -> str:
    """Where H0 lies, in words: along the axis of largest / middle / smallest moment, or off them."""
    fp = _fixed(ds)
    k = int(T.principal_axis(np.array(fp["H"], float)))
    if k < 0:
        return "H0 off the principal axes"
    rank = int(np.argsort(np.argsort(np.array(fp["I"], float)))[k])
    return f"H0 along the axis of {_AXIS[rank]} moment"


def _n(ds) -> str:
    return f"n = {ds.sizes['sample']} random starts per point"


def _halo(lw: float):
    from matplotlib import patheffects

    return [patheffects.withStroke(linewidth=lw + 2.5, foreground="white")]


def _plot_region(ds, png: Path):
    x, p, se = _frac_1d(ds, "rho")
    l = float(np.nanmin(ds["derived_l_spurious"].values))
    fp = _fixed(ds)
    fig, ax = plt.subplots(figsize=(6.5, 4.8), constrained_layout=True)
    ax.errorbar(x, p, yerr=se, marker="o", capsize=3, color=V.COLORS[V.CONVERGED], label="fraction converged ± SE")
    ax.axvline(l, color=C_TH1, ls="--", lw=1.8,
               label=fr"guaranteed radius of Cor. 2 (Theorem 1), region (1.18): $\rho$ = l = {l:.3f}")
    cor1 = bool(np.asarray(ds["theory_c121"].values).any()) if "theory_c121" in ds else True
    why = "" if cor1 else (" (not claimed here: H0 is not principal)" if "off" in _where_h0(ds) else
                           " (not claimed here: (1.21) fails)")
    ax.axvline(2.0, color=C_COR1, ls=":", lw=2, label=fr"radius of Cor. 1, region (1.22): $\rho$ = 2{why}")
    ax.set_xlabel(r"initial distance of S0 from H0, $|\delta(0)| = \rho$   (and $|w_1(0)| = \lambda\rho$)")
    ax.set_ylabel("fraction converged")
    ax.set_ylim(-0.05, 1.05)
    ax.set_title(f"Region of attraction, fixed direction (Cor. 2): {_where_h0(ds)}\n"
                 fr"$\lambda$ = {fp['lam']:g} rad/s, K = {fp['K']:g} N m s; {_n(ds)}", fontsize=9)
    legend_below(ax, ax.get_legend_handles_labels()[0], ncol=1, width=70)
    fig.savefig(png, dpi=100)
    plt.close(fig)


def _plot_gain(ds, png: Path):
    p, _ = converged_fraction(ds)
    lam, K = ds["lam"].values, ds["K"].values
    fig, ax = plt.subplots(figsize=(6.5, 5.6), constrained_layout=True)
    m = ax.pcolormesh(lam, K, p.transpose("K", "lam").values, vmin=0, vmax=1, cmap="viridis", shading="nearest")
    fig.colorbar(m, ax=ax, label="fraction converged (starts inside region (1.22))")
    spec = _fixed(ds)
    I, H = np.array(spec["I"]), np.array(spec["H"])
    lg = np.linspace(lam.min(), lam.max(), 50)
    m1, _, m2 = (float(v) for v in T.axis_roles(I))
    ax.plot(lg, m1 * lg, color=C_TH1, ls="-", lw=2, path_effects=_halo(2),
            label=r"gain bound of Cor. 2 (Theorem 1), eq. (1.10): K = $\lambda m_1$" + f" = {m1:g} " + r"$\lambda$")
    ax.plot(lg, (3 * m1 - 2 * m2) * lg, color=C_COR1, ls="--", lw=2, path_effects=_halo(2),
            label=r"gain bound of Cor. 1, eq. (1.21): K = $\lambda(3 m_1 - 2 m_2)$" + f" = {3 * m1 - 2 * m2:g} "
                  r"$\lambda$")
    ex = T.exact_axis_bound(I, H, 1.0)
    if np.isfinite(ex):
        ax.plot(lg, ex * lg, color=C_EXACT, ls=":", lw=2.5, path_effects=_halo(2.5),
                label=f"exact bound for no off-target steady spin (ours): K = {float(ex):g} " + r"$\lambda$")
    if T.principal_axis(H) == np.argsort(I)[1]:
        mb = float(T.middle_axis_bound(I, 1.0))
        ax.plot(lg, mb * lg, color=C_MID, ls="-.", lw=2, path_effects=_halo(2),
                label=f"the paper's middle-axis condition: K = {mb:g} " + r"$\lambda$")
    ax.set_xlabel(axis_label(ds, "lam"))
    ax.set_ylabel(axis_label(ds, "K"))
    ax.set_ylim(K.min(), K.max())
    legend_below(ax, ax.get_legend_handles_labels()[0], ncol=1, width=80)
    ax.set_title(f"Gains of the fixed-direction loop (Cor. 2): {_where_h0(ds)}\n"
                 f"I = {', '.join(f'{v:g}' for v in I)} kg m^2; {_n(ds)}", fontsize=9)
    fig.savefig(png, dpi=100)
    plt.close(fig)


_SERIES = (("#0072B2", "o"), ("#D55E00", "s"), ("#009E73", "^"), ("#CC79A7", "D"), ("#E69F00", "v"))


def _plot_ratio(ds, png: Path, dim: str, xvals, xlabel: str, title: str, bound: str):
    """Converged fraction against a ratio whose bound is 1 (the line ``bound`` says which), one series
    per value of the other grid axis (set a little apart, so that equal fractions do not hide each other)."""
    p, se = converged_fraction(ds)
    fig, ax = plt.subplots(figsize=(6.5, 4.8), constrained_layout=True)
    other = [d for d in p.dims if d != dim]
    xvals = np.asarray(xvals, float)
    if other:
        vals = ds[other[0]].values
        step = 0.012 * np.ptp(xvals)
        unit = str(ds[other[0]].attrs.get("units", ""))
        unit = "" if unit in ("", "1", "-") else unit
        # "potential gain K = alpha/lam" -> "potential gain K = 2 N m s"
        name = words(str(ds[other[0]].attrs.get("long_name", "")), "").split(" = ")[0] or other[0]
        for i, v in enumerate(vals):
            col, mk = _SERIES[i % len(_SERIES)]
            ax.errorbar(xvals + (i - (len(vals) - 1) / 2) * step, p.sel({other[0]: v}).values,
                        yerr=se.sel({other[0]: v}).values, marker=mk, color=col, capsize=2, ms=5,
                        label=f"{name} = {v:g} {unit}".rstrip())
    else:
        ax.errorbar(xvals, p.values, yerr=se.values, marker="o", capsize=3, color=V.COLORS[V.CONVERGED],
                    label="fraction converged ± SE")
    ax.axvline(1.0, color="k", ls=":", lw=1.8, label=bound)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("fraction converged")
    ax.set_ylim(-0.05, 1.05)
    legend_below(ax, ax.get_legend_handles_labels()[0], ncol=2, width=60)
    ax.set_title(f"{title}\n{_n(ds)}", fontsize=9)
    fig.savefig(png, dpi=100)
    plt.close(fig)


def _sweeps(out_dir: Path, quick: bool) -> list[Path]:
    files: list[Path] = []
    specs = shipped_specs("saakyan_")
    if quick:
        specs = [s for s in specs if s in QUICK_SWEEPS]
    shocks = []
    for stem in specs:
        spec = load_shipped(stem)
        if "shock" in spec:  # a minimal-fatal-shock search, not a sweep (below)
            shocks.append(stem)
            continue
        if quick:
            spec = _shrink(spec)
        ds = run_spec(spec)
        files += plot_sweep_figures(ds, stem, out_dir)
    if shocks and not quick:
        files += _shocks(out_dir, shocks)
    return files


def _shocks(out_dir: Path, stems: list[str]) -> list[Path]:
    """The minimal fatal shock of the target motion along the gain, for H0 on each principal axis against the radii
    of (1.18) and (1.22), and for the gyrostat against Theorem 3's global claim (``sweeps/saakyan_shock_*.toml``): a
    figure per spec, and the numbers with their witnesses and the commands replaying them in ``saakyan_shock.json``
    and ``saakyan_shock.txt``."""
    from ..explore.shock import shock_spec
    from ..explore.shock_result import VERDICTS, witness_replay
    from ..present.shock import format_summary, plot_shock

    files, rows, texts = [], [], []
    for stem in stems:
        ds = shock_spec(load_shipped(stem))
        png = out_dir / f"{stem}.png"
        plot_shock(ds, png, title=TITLES[stem])
        files.append(png)
        texts.append(format_summary(ds, limit=50))
        names = ds.attrs["outcome_names"].split()
        gain = ds["shock_norm"].dims[0]  # K, or h for the gyrostat
        theorems = [str(v)[len("theory_radius_"):] for v in ds.data_vars if str(v).startswith("theory_radius_")]
        for K in ds[gain].values:
            p = ds.sel({gain: K})
            hi, lo = float(p.shock_norm), float(p.shock_norm_lo)
            row = {"spec": stem, "where": _where_h0(ds), gain: float(K), "attractor": names[int(p.base_outcome)],
                   "delta_star": None if np.isnan(hi) else hi, "bracket": [lo, None if np.isnan(hi) else hi],
                   "trajectories": int(p.shock_trajectories)}
            for th in theorems:
                row[th] = {"radius": float(p[f"theory_radius_{th}"]),
                           "verdict": VERDICTS[int(p[f"theory_verdict_{th}"])],
                           "factor": [float(p[f"theory_factor_lo_{th}"]), float(p[f"theory_factor_hi_{th}"])]}
            if np.isfinite(hi):
                dev = p.shock_state_delta.values
                rep = witness_replay(ds, **{gain: K})
                S0 = np.asarray(rep["params"]["S0"], float)
                row["witness"] = {"S0": (S0 / np.linalg.norm(S0)).tolist(), "w1_0": dev[:3].tolist(),
                                  "norm_w1_0_over_lam": float(np.linalg.norm(dev[:3])), "norm_delta_0":
                                  float(np.linalg.norm(dev[3:])), "outcome": names[int(p.shock_witness_outcome)],
                                  "recheck_outcome": names[int(p.shock_witness_recheck)] if "shock_witness_recheck"
                                  in p else None, "replay": rep["command"]}
            rows.append(row)
    js = out_dir / "saakyan_shock.json"
    js.write_text(json.dumps(rows, indent=1))
    txt = out_dir / "saakyan_shock.txt"
    txt.write_text("\n\n".join(texts) + "\n")
    return files + [js, txt]


def plot_sweep_figures(ds, stem: str, out_dir: Path) -> list[Path]:
    """The verdict map of shipped sweep ``stem`` and, for the region, gain and ratio sweeps, the
    converged-fraction figure with the paper's bounds (``<stem>_fraction.png``)."""
    png = out_dir / f"{stem}.png"
    plot_sweep(ds, png, title=TITLES[stem])
    files = [png]
    extra = out_dir / f"{stem}_fraction.png"
    fp = _fixed(ds)
    if stem.startswith("saakyan_region"):
        _plot_region(ds, extra)
    elif stem.startswith("saakyan_gain") and "lam" in ds.dims and "K" in ds.dims:
        _plot_gain(ds, extra)
    elif stem == "saakyan_gravity_ratio":
        lam = float(fp["lam"])
        _plot_ratio(ds, extra, "nu", lam**2 / ds["nu"].values, r"spin rate squared over gravity parameter, "
                    r"$\lambda^2/\nu$", f"Central gravity field: Theorem 2 needs " r"$\lambda^2 = \nu$ exactly"
                    f" (λ = {lam:g} rad/s)", r"Theorem 2's knife edge $\lambda^2 = \nu$")
    elif stem == "saakyan_gyrostat_h":
        _plot_ratio(ds, extra, "h", ds["h"].values / (fp["lam"] * max(fp["I"])),
                    r"gyrostat gain over the bound of Theorem 3, $h/(\lambda m_1)$",
                    "Gyrostat: Theorem 3 claims convergence from anywhere for " r"$h > \lambda m_1$",
                    r"bound of Theorem 3: $h = \lambda m_1$")
    elif stem == "saakyan_gyrostat_gravity_44":
        hp = float(np.nanmax(ds["derived_h44_printed"].values))
        he = float(np.nanmax(ds["derived_h44_exact"].values))
        _plot_ratio(ds, extra, "h", ds["h"].values / hp,
                    f"gyrostat gain h over the printed bound of eq. (4.4), h = {hp:.3g}",
                    "Gyrostat in a gravity field (Theorem 4): the bound of eq. (4.4), printed and exact",
                    f"printed bound of eq. (4.4): h = {hp:.3g} (the exact one: h > {max(he, 0.0):.3g})")
    else:
        return files
    return files + [extra]


def run(out_dir: Path, quick: bool = False) -> list[Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = _examples(out_dir, quick)
    files += _sweeps(out_dir, quick)
    return files
