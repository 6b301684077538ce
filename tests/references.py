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
