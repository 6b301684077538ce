"""Independent NumPy transcriptions of the models, shared by the tests (SciPy DOP853 references)."""
import math

import numpy as np


def monoaxial_rhs(t, y, J, D, a, mu, b, sigma, alpha, omega0, r):
    """Monoaxial (2), (4), (14) with the torques evaluated on s/|s| (docs/models/monoaxial.md, numerical notes)."""
    w, s = y[:3], y[3:]
    sh = s / np.linalg.norm(s)
    u = np.cross(sh - r, r)
    m_r = -a * np.linalg.norm(sh - r) ** (mu - 1) * np.cross(sh, r)
    m_p = b * math.cos(omega0 * t**alpha) * np.linalg.norm(u) ** (sigma - 1) * u
    dw = (-np.cross(w, J * w) - D @ w + m_r + m_p) / J
    return np.concatenate([dw, -np.cross(w, s)])


R_PAPER = np.ones(3) / math.sqrt(3)
S0_PAPER = np.array([math.sin(0.8), math.sin(0.5) * math.cos(0.8), math.cos(0.5) * math.cos(0.8)])


def monoaxial_paper(alpha, t_eval, rtol=1e-12, atol=1e-14):
    """The paper example (docs/models/monoaxial.md: J = (5, 6, 4), D = 2 I, a = 1, mu = 3/2, b = 2, sigma = 4/3,
    omega0 = 1, w0 = (1, 1, 1), s0 the paper's direction) by SciPy DOP853: states (len(t_eval), 6), the angle
    between s and r (atan2(|s x r|, s.r), as the model's observable) and |w|. Cached: one run per call pattern."""
    return _monoaxial_paper(float(alpha), tuple(float(t) for t in t_eval), rtol, atol)


@__import__("functools").lru_cache(maxsize=8)
def _monoaxial_paper(alpha, t_eval, rtol, atol):
    from scipy.integrate import solve_ivp

    p = (np.array([5.0, 6, 4]), 2 * np.eye(3), 1.0, 1.5, 2.0, 4 / 3, alpha, 1.0, R_PAPER)
    y0 = np.concatenate([np.ones(3), S0_PAPER])
    sol = solve_ivp(monoaxial_rhs, (0, t_eval[-1]), y0, method="DOP853", rtol=rtol, atol=atol, t_eval=t_eval, args=p)
    assert sol.success
    y = sol.y.T
    s = y[:, 3:]
    angle = np.arctan2(np.linalg.norm(np.cross(s, R_PAPER), axis=1), s @ R_PAPER)
    return y, angle, np.linalg.norm(y[:, :3], axis=1)


def rounded_like(x, quoted: str) -> float:
    """``x`` rounded to the significant digits of the figure ``quoted`` ("0.172", "1.6e-2"): a document's
    figure is checked as the reference printed to the digits the document shows."""
    mant = quoted.lower().split("e")[0].lstrip("-0.").replace(".", "")
    return float(f"{x:.{max(len(mant), 1) - 1}e}")
