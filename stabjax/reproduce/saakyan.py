"""`stabjax reproduce saakyan`: a documented example set for Saakyan's five closed loops.

The paper has no numerical example; the examples are ours (docs/models/saakyan.md, "Examples"):

* ``examples.png``: error metric angle(S0, H0) + |w1|/lam against time for
  B-1 moving target (the documented case, A,B,C = 4,3,2, omega0 = (0.2 sin 0.3t, 0.1, 0.15 cos 0.2t)),
  B-1 with a precession program and the body A,B,C = 5,6,4 (issue's choice),
  Corollary 2 with and without mu (the unstable case), B-2 with lam^2 = nu and off it,
  B-3 with the Theorem-3 torque and with (3.9)+(3.21) (double-counted term), B-4 with h
  between the exact and the printed bound (4.4).
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

from ..engine import simulate
from ..plotting import converged_fraction, plot_sweep
from ..sweep import run_spec
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
        ax.semilogy(ds.t, e, lw=1.0, label="error")
        ax.semilogy(ds.t, np.maximum(ds["angle"].values, 1e-16), lw=0.8, ls="--", label="angle(S0, H0)")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("t [s]")
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


def _plot_region(ds, png: Path):
    x, p, se = _frac_1d(ds, "rho")
    l = float(np.nanmin(ds["derived_l_spurious"].values))
    fig, ax = plt.subplots(figsize=(6.5, 4.2), constrained_layout=True)
    ax.errorbar(x, p, yerr=se, marker="o", capsize=3, label="converged fraction (+- s.e.)")
    ax.axvline(l, color="tab:red", ls="--", label=f"l of (1.18) = {l:.3f}")
    ax.axvline(2.0, color="k", ls=":", label="(1.22): 2")
    ax.set_xlabel(r"$|\delta_0|$ = rho   ($|w_1(0)| = \lambda\,$rho)")
    ax.set_ylabel("fraction converged")
    ax.set_ylim(-0.05, 1.05)
    ax.set_title(ds.attrs.get("sweep_name", ""), fontsize=9)
    ax.legend(fontsize=8)
    fig.savefig(png, dpi=90)
    plt.close(fig)


def _plot_gain(ds, png: Path):
    p, _ = converged_fraction(ds)
    lam, K = ds["lam"].values, ds["K"].values
    fig, ax = plt.subplots(figsize=(6.5, 4.6), constrained_layout=True)
    m = ax.pcolormesh(lam, K, p.transpose("K", "lam").values, vmin=0, vmax=1, cmap="viridis", shading="nearest")
    fig.colorbar(m, ax=ax, label="fraction converged (initial states in (1.22))")
    spec = json.loads(ds.attrs["fixed_params_json"])
    I, H = np.array(spec["I"]), np.array(spec["H"])
    lg = np.linspace(lam.min(), lam.max(), 50)
    ax.plot(lg, T.axis_roles(I)[0] * lg, "w-", label="(1.10) K = lam m1")
    ax.plot(lg, T.c121(I, H, 1.0, 1.0).margin * 0 + (3 * I.max() - 2 * I.min()) * lg, "r--", label="(1.21)")
    ex = T.exact_axis_bound(I, H, 1.0)
    if np.isfinite(ex):
        ax.plot(lg, ex * lg, "c:", lw=2, label="exact, no spurious spins [D]")
    if T.principal_axis(H) == np.argsort(I)[1]:
        ax.plot(lg, T.middle_axis_bound(I, 1.0) * lg, "m-.", label="middle-axis condition")
    ax.set_xlabel(r"$\lambda$")
    ax.set_ylabel("K")
    ax.set_ylim(K.min(), K.max())
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(ds.attrs.get("sweep_name", ""), fontsize=9)
    fig.savefig(png, dpi=90)
    plt.close(fig)


def _plot_ratio(ds, png: Path, dim: str, xvals, xlabel: str):
    p, se = converged_fraction(ds)
    fig, ax = plt.subplots(figsize=(6.5, 4.2), constrained_layout=True)
    other = [d for d in p.dims if d != dim]
    if other:
        for v in ds[other[0]].values:
            ax.errorbar(xvals, p.sel({other[0]: v}).values, yerr=se.sel({other[0]: v}).values, marker="o",
                        capsize=2, label=f"{other[0]} = {v:g}")
    else:
        ax.errorbar(xvals, p.values, yerr=se.values, marker="o", capsize=3, label="converged fraction")
    ax.axvline(1.0, color="k", ls=":")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("fraction converged")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(fontsize=8)
    ax.set_title(ds.attrs.get("sweep_name", ""), fontsize=9)
    fig.savefig(png, dpi=90)
    plt.close(fig)


def _sweeps(out_dir: Path, quick: bool) -> list[Path]:
    files: list[Path] = []
    specs = shipped_specs("saakyan_")
    if quick:
        specs = [s for s in specs if s in QUICK_SWEEPS]
    for stem in specs:
        spec = load_shipped(stem)
        if quick:
            spec = _shrink(spec)
        ds = run_spec(spec)
        png = out_dir / f"{stem}.png"
        plot_sweep(ds, png)
        files.append(png)
        extra = out_dir / f"{stem}_fraction.png"
        if stem.startswith("saakyan_region"):
            _plot_region(ds, extra)
        elif stem.startswith("saakyan_gain") and "lam" in ds.dims and "K" in ds.dims:
            _plot_gain(ds, extra)
        elif stem == "saakyan_gravity_ratio":
            lam = float(json.loads(ds.attrs["fixed_params_json"])["lam"])
            _plot_ratio(ds, extra, "nu", lam**2 / ds["nu"].values, r"$\lambda^2/\nu$ (Theorem 2: = 1)")
        elif stem == "saakyan_gyrostat_h":
            fp = json.loads(ds.attrs["fixed_params_json"])
            _plot_ratio(ds, extra, "h", ds["h"].values / (fp["lam"] * max(fp["I"])), r"$h/(\lambda m_1)$ (Theorem 3: > 1)")
        elif stem == "saakyan_gyrostat_gravity_44":
            hp = float(np.nanmax(ds["derived_h44_printed"].values))
            _plot_ratio(ds, extra, "h", ds["h"].values / hp, "h / printed (4.4) bound (exact bound <= 0)")
        else:
            continue
        files.append(extra)
    return files


def run(out_dir: Path, quick: bool = False) -> list[Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = _examples(out_dir, quick)
    files += _sweeps(out_dir, quick)
    return files
