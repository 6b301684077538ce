"""Reproduce Aleksandrov & Tikhonov (2019), Figs. 1-2, and the alpha-sweep of their example.

* Fig. 1 (alpha = 1/3, (7) violated): direction cosines of s on the paper-like horizon
  (t <= 1e4, where the excursions to the inverted position look like jumps), and beside it
  t <= 1e5, where the excursions are seen to *shrink* window after window (docs/models/monoaxial.md, "Findings"):
  the paper's "unstable" is a finite-horizon statement.
* Fig. 2 (alpha = 7/9, (7) holds): the cosines converge to 1/sqrt(3); beside it the angle on
  log-log axes, showing the algebraic (not exponential) decay.
* The alpha-sweep at sigma = 4/3, mu = 3/2 with the Theorem 1 bound alpha > 2/3 drawn, at
  two horizons, so the horizon dependence of the verdicts is visible.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..engine import simulate  # noqa: E402
from ..plotting import plot_sweep  # noqa: E402
from ..sweep import run_spec, write  # noqa: E402


def _cosines(ax, ds, title):
    for i, c in enumerate(("tab:blue", "tab:orange", "tab:green")):
        ax.plot(ds.t, ds.s.isel(axis=i), color=c, lw=0.8, label=fr"$\gamma_{i + 1}$")
    ax.axhline(1 / np.sqrt(3), color="k", lw=0.5, ls=":")
    ax.set_xlabel("t")
    ax.set_title(title, fontsize=9)
    ax.set_ylim(-1.05, 1.05)


def _windows(ax, alpha, t1):
    k = np.arange(1, 200)
    tk = ((2 * k - 0.5) * np.pi) ** (1 / alpha)
    te = ((2 * k + 0.5) * np.pi) ** (1 / alpha)
    for a, b in zip(tk, te):
        if a < t1:
            ax.axvspan(a, min(b, t1), color="0.9", zorder=0)


def run(out_dir: Path, quick: bool = False) -> list[Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    short1, long1 = (2e3, 1e4) if quick else (1e4, 1e5)
    short2, long2 = (200.0, 1e3) if quick else (200.0, 1e4)
    n = 4001 if quick else 40001

    # Fig. 1: alpha = 1/3
    a13s = simulate("monoaxial", {"alpha": 1 / 3}, t1=short1, ts=np.linspace(0, short1, n), rtol=1e-10, atol=1e-12)
    a13l = simulate("monoaxial", {"alpha": 1 / 3}, t1=long1, ts=np.linspace(0, long1, n), rtol=1e-10, atol=1e-12)
    fig, axs = plt.subplots(1, 2, figsize=(11, 3.8), constrained_layout=True)
    _cosines(axs[0], a13s, fr"Fig. 1 ($\alpha$ = 1/3): paper-like horizon t $\leq$ {short1:g}")
    _cosines(axs[1], a13l, fr"$\alpha$ = 1/3, longer horizon t $\leq$ {long1:g}: excursions shrink")
    for ax, t1 in zip(axs, (short1, long1)):
        _windows(ax, 1 / 3, t1)
    axs[0].legend(fontsize=8, loc="lower right")
    fig.suptitle("grey: windows where cos(t^α) > 0 (the perturbation destabilises s = r)", fontsize=9)
    p = out_dir / "fig1_alpha_1_3.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)

    # Fig. 2: alpha = 7/9
    a79s = simulate("monoaxial", {"alpha": 7 / 9}, t1=short2, ts=np.linspace(0, short2, 4001), rtol=1e-10, atol=1e-12)
    a79l = simulate("monoaxial", {"alpha": 7 / 9}, t1=long2, ts=np.geomspace(1e-2, long2, 2000), rtol=1e-10, atol=1e-12)
    fig, axs = plt.subplots(1, 2, figsize=(11, 3.8), constrained_layout=True)
    _cosines(axs[0], a79s, r"Fig. 2 ($\alpha$ = 7/9): cosines converge to $1/\sqrt{3}$")
    axs[0].legend(fontsize=8)
    axs[1].loglog(a79l.t, a79l.angle, lw=0.9, label="angle(s, r)")
    axs[1].loglog(a79l.t, a79l.wnorm, lw=0.9, label=r"$|\omega|$")
    axs[1].set_xlabel("t")
    axs[1].set_title(r"$\alpha$ = 7/9: algebraic decay (log-log)", fontsize=9)
    axs[1].legend(fontsize=8)
    p = out_dir / "fig2_alpha_7_9.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)

    for ds, name in ((a13l, "traj_alpha_1_3.nc"), (a79s, "traj_alpha_7_9.nc")):
        if not quick:
            files.append(write(ds.isel(t=slice(None, None, 10)), out_dir / name))

    # alpha sweep of the example, two horizons
    num = 8 if quick else 36
    horizons = (2e3, 8e3) if quick else (2e4, 2e5)
    fig, axs = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    for ax, t1 in zip(axs, horizons):
        spec = {"system": "monoaxial", "name": f"at2019_alpha_t{t1:g}",
                "grid": {"alpha": {"start": 0.3, "stop": 1.0, "num": num}},
                "integrate": {"t1": t1, "rtol": 1e-9, "atol": 1e-11, "n_checkpoints": 4000}}
        ds = run_spec(spec, out_dir / f"alpha_sweep_t{t1:g}.nc", progress=False)
        plot_sweep(ds, ax=ax)
        ax.set_title(fr"$\sigma$ = 4/3, $\mu$ = 3/2: Theorem 1 needs $\alpha$ > 2/3  (t1 = {t1:g})", fontsize=9)
        files.append(out_dir / f"alpha_sweep_t{t1:g}.nc")
    p = out_dir / "alpha_sweep.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)
    return files
