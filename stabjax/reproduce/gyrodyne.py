"""``stabjax reproduce gyrodyne``: Khoroshilov's CMG cluster near the resonance 2 omega_01 ~ Omega_2.

The paper gives no numbers (docs/models/gyrodyne.md, "Regression case"). The documented example (the defaults of
:class:`stabjax.systems.gyrodyne.Gyrodyne`) is a small agile spacecraft with four mini-CMGs:

* I = (60, 50, 40) kg m^2, rotor momenta H = 8 N m s (H/I ~ 0.15: the parametric term
  -d theta' phi is proportional to d/I, and the tongue can only open if (H/I)^2 nu / 12 exceeds
  the damping ratio -- so a momentum-rich cluster is needed);
* stiffness Kp: theta 6, phi 4, cross term a' = b'' = 1.5 N m/rad (a' != 0 is required by the
  normal coordinates), psi 8 N m/rad -> omega_01 ~ 0.43 rad/s, omega_02 ~ 0.24 rad/s;
* light rate damping Kd ~ 0.03 N m s/rad (damping ratio ~ 1e-3): the K gains are the paper's
  mu-small terms, and this is the regime where averaging applies;
* scanning torque A_2 = 1 N m on slot 2 at Omega_2 = 2 (omega_01 - eps): gimbal-rate amplitude
  A_2/H ~ 0.12 rad/s, gimbal angle ~ 0.15 rad, body angle ~ 0.02 rad;
* tetrahedron turned 0.3 rad about z, so the four active sets are not equivalent.

Outputs: ``gyrodyne_theory.txt`` (coefficients for the four active sets, printed vs corrected
vs numerically averaged), ``gyrodyne_growth.png`` (growth rate of a mode-1 disturbance against
eps: averaged theory with corrected and printed p2, p3 against simulation of models 0, 1, 2),
and without ``quick`` the verdict map of every shipped ``sweeps/gyrodyne_*.toml`` with the averaged-theory
boundary: (eps, A_2), (eps, damping gain), the four active sets, failover, and the three models along eps
(``gyrodyne_<name>.png``; about 5 minutes on 2 CPU cores).
"""
from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from ..config import IntegrateConfig

from ..engines.simulate import batch_params, solve_batch
from ..model.registry import get_system
from ..systems import gyrodyne_theory as T

# what each shipped sweep's map shows, in words (the figures' titles; a spec without one is an error)
TITLES = {
    "gyrodyne_active_sets": "Resonance tongue of each active set of three gyros (quasi-linear model)",
    "gyrodyne_eps_A2": "Resonance tongue: detuning against the scanning amplitude of slot 2",
    "gyrodyne_eps_gain": "Resonance tongue: detuning against the damping gain",
    "gyrodyne_failover": "Failover: which gyro fails and when (the spare takes its slot)",
    "gyrodyne_full_vs_quasi": "Three models along the detuning: normal coordinates, quasi-linear, full",
}
# the grid axis A[1] is entry 1 of the amplitudes, i.e. the paper's A_2 (slot 2)
A2_LABEL = r"scanning amplitude of slot 2 ($A_2$) [N m]"


def theory_table(S) -> str:
    lines = ["Khoroshilov CMG cluster, default example (docs/models/gyrodyne.md); mu = 1, physical units", ""]
    hdr = f"{'spare':>5} {'map':>4} {'omega01':>9} {'omega02':>9} {'p0':>10} {'p1':>10} {'p2':>10} {'p3':>10} " \
          f"{'g1':>10} {'g2':>10} {'p2 print':>10} {'p3 print':>10} {'|avg-num|':>9} {'A2*/A2':>7}"
    lines.append(hdr)
    for spare in (4.0, 3.0, 2.0, 1.0):
        for mapping in (0.0, 1.0):
            p = S.check(S.params.resolve(dict(spare=spare, mapping=mapping)))
            pre, _, _ = T.normal_coefficients(p)
            co, na = T.averaged(pre), T.numerical_average(pre)
            p2l, p3l = T.p23_printed(pre)
            dev = max(abs(co[k] - na[k]) for k in ("p0", "p1", "p2", "p3", "g1", "g2"))
            ratio = abs(co["p1"]) / np.hypot(co["p2"], co["p3"])
            lines.append(
                f"{spare:5.0f} {'cons' if mapping else 'pap':>4} {co['w01']:9.5f} {co['w02']:9.5f} {co['p0']:10.3e} "
                f"{co['p1']:10.3e} {co['p2']:10.3e} {co['p3']:10.3e} {co['g1']:10.3e} {co['g2']:10.3e} "
                f"{p2l:10.3e} {p3l:10.3e} {dev:9.1e} {ratio:7.3f}")
    lines += ["", "p2, p3: corrected chain D(Omega_2) -> U, W (gyrodyne.md misprint 13); 'print': the paper's alpha-version;",
              "|avg-num|: largest difference to the numerical average of (3.1) over the fast phase;",
              "A2*/A2: the tongue opens where this is < 1 (A2* = |p1| / sqrt(p2^2+p3^2) per unit A2)."]
    return "\n".join(lines)


def growth_curve(S, eps, models, t1, n_ck):
    """Simulated growth rate of E1 for each model over eps (one compiled batch)."""
    n = len(eps) * len(models)
    p = batch_params(S, {}, n)
    p["model"] = np.repeat(np.asarray(models, float), len(eps))
    p["mapping"] = np.where(p["model"] == 0, 0.0, 1.0)  # model 0 shows the paper's projection
    p["eps"] = np.tile(np.asarray(eps, float), len(models))
    p = S.check(p)
    icfg = IntegrateConfig(t1=t1, rtol=1e-8, atol=1e-11, max_steps=600_000, n_checkpoints=n_ck)
    res = solve_batch(S, p, icfg)
    th = S.theory(p)
    return p, res, th


def run(out_dir: Path, quick: bool = False) -> list[Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    S = get_system("gyrodyne")
    paths = []
    txt = out_dir / "gyrodyne_theory.txt"
    txt.write_text(theory_table(S) + "\n")
    paths.append(txt)

    if quick:
        eps, models, t1, n_ck = np.array([-0.002, 0.0, 0.002]), [1], 3000.0, 200
    else:
        eps, models, t1, n_ck = np.linspace(-0.003, 0.003, 13), [0, 1, 2], 6000.0, 400
    p, res, th = growth_curve(S, eps, models, t1, n_ck)
    fine = np.linspace(eps.min(), eps.max(), 400)
    pf = batch_params(S, {}, fine.size)
    pf["eps"] = fine
    thf = S.theory(pf)
    fig, ax = plt.subplots(figsize=(7, 5.6), constrained_layout=True)
    ax.plot(fine, thf.derived["growth_pred"], "k-", label="averaged theory, eq. (3.3), corrected p2, p3")
    ax.plot(fine, thf.derived["growth_pred_printed"], "k:", label="averaged theory, eq. (3.3), printed p2, p3")
    marks = {0: ("s", "#0072B2", "simulated: normal coordinates, eq. (1.3), paper's mapping"),
             1: ("o", "#D55E00", "simulated: quasi-linear model, eq. (1.2)"),
             2: ("^", "#009E73", "simulated: full nonlinear model")}
    for m in models:
        sel = p["model"] == m
        ax.plot(p["eps"][sel], res["growth1"][sel], marks[m][0], color=marks[m][1], mfc="none", mew=1.3,
                label=marks[m][2])
    ax.axhline(0, color="0.6", lw=0.8)
    ax.set_xlabel(r"detuning from resonance, $\varepsilon=\omega_{01}-\Omega_2/2$ [rad/s]")
    ax.set_ylabel(r"growth rate of the mode-1 amplitude $E_1$ [1/s]")
    ax.set_title("Gyrodyne cluster: parametric resonance tongue (default example)")
    from ..present.maps import legend_below

    legend_below(ax, ax.get_legend_handles_labels()[0], ncol=1, width=70)
    png = out_dir / "gyrodyne_growth.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    paths.append(png)
    with open(out_dir / "gyrodyne_growth.txt", "w") as fh:
        fh.write("model eps growth_sim growth_pred verdict\n")
        for i in range(p["eps"].size):
            fh.write(f"{p['model'][i]:.0f} {p['eps'][i]: .5f} {res['growth1'][i]: .4e} "
                     f"{th.derived['growth_pred'][i]: .4e} {int(res['verdict'][i])}\n")
    paths.append(out_dir / "gyrodyne_growth.txt")

    if not quick:
        from ..run.sweep import run_spec

        from . import load_shipped, shipped_specs

        for stem in shipped_specs("gyrodyne_"):
            paths.append(plot_map(run_spec(load_shipped(stem)), stem, out_dir))
    return paths


def plot_map(ds, stem: str, out_dir: Path) -> Path:
    """The verdict map of shipped sweep ``stem``, titled in words, the A[1] axis named as the paper does."""
    from ..present.maps import plot_sweep, save

    fig = plot_sweep(ds, title=TITLES[stem])
    for ax in fig.axes:
        for get, set_ in ((ax.get_xlabel, ax.set_xlabel), (ax.get_ylabel, ax.set_ylabel)):
            if "$A[1]$" in get():
                set_(A2_LABEL)
    png = out_dir / f"{stem}.png"
    save(fig, png)
    return png
