"""Independent NumPy transcriptions of the models, shared by the tests (SciPy DOP853 references)."""
import math

import numpy as np


def monoaxial_rhs(t, y, J, D, a, mu, b, sigma, alpha, omega0, r):
    """Monoaxial (2), (4), (14) with the torques evaluated on s/|s| (docs/models/monoaxial.md, numerical notes),
    written out in scalars: SciPy calls it 12 times a DOP853 step, and NumPy's cross products and norms of
    3-vectors cost ten times the arithmetic (181 us against 17 us a call). :func:`monoaxial_rhs_vectors` is
    the same equations in vector form; a test holds the two equal."""
    w1, w2, w3, s1, s2, s3 = (float(v) for v in y)
    J1, J2, J3 = (float(v) for v in J)
    r1, r2, r3 = (float(v) for v in r)
    n = math.sqrt(s1 * s1 + s2 * s2 + s3 * s3)
    h1, h2, h3 = s1 / n, s2 / n, s3 / n  # s/|s|
    d1, d2, d3 = h1 - r1, h2 - r2, h3 - r3
    u1, u2, u3 = d2 * r3 - d3 * r2, d3 * r1 - d1 * r3, d1 * r2 - d2 * r1  # u = (s/|s| - r) x r
    c1, c2, c3 = h2 * r3 - h3 * r2, h3 * r1 - h1 * r3, h1 * r2 - h2 * r1  # s/|s| x r
    kr = -a * math.sqrt(d1 * d1 + d2 * d2 + d3 * d3) ** (mu - 1)
    kp = b * math.cos(omega0 * t**alpha) * math.sqrt(u1 * u1 + u2 * u2 + u3 * u3) ** (sigma - 1)
    (D11, D12, D13), (D21, D22, D23), (D31, D32, D33) = np.asarray(D, float).tolist()
    g1, g2, g3 = J1 * w1, J2 * w2, J3 * w3
    return np.array([(-(w2 * g3 - w3 * g2) - (D11 * w1 + D12 * w2 + D13 * w3) + kr * c1 + kp * u1) / J1,
                     (-(w3 * g1 - w1 * g3) - (D21 * w1 + D22 * w2 + D23 * w3) + kr * c2 + kp * u2) / J2,
                     (-(w1 * g2 - w2 * g1) - (D31 * w1 + D32 * w2 + D33 * w3) + kr * c3 + kp * u3) / J3,
                     -(w2 * s3 - w3 * s2), -(w3 * s1 - w1 * s3), -(w1 * s2 - w2 * s1)])


def monoaxial_rhs_vectors(t, y, J, D, a, mu, b, sigma, alpha, omega0, r):
    """:func:`monoaxial_rhs` in vector form, as the equations are written."""
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


# Saakyan's B-1 closed loop from the paper's component formulas (docs/models/saakyan.md), plain NumPy


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def mu_111(w1, beta, I, lam, K, w0):
    A, B, C = I
    b1, b2, b3 = beta
    p1, q1, r1 = w1
    p0, q0, r0 = w0
    return np.array([
        -K * p1 - (K - lam * (B + C)) * (b3 * q1 - b2 * r1) - (B * q0 * r1 - C * r0 * q1),
        -K * q1 - (K - lam * (A + C)) * (b1 * r1 - b3 * p1) - (C * r0 * p1 - A * p0 * r1),
        -K * r1 - (K - lam * (A + B)) * (b2 * p1 - b1 * q1) - (A * p0 * q1 - B * q0 * p1),
    ])


def ref_b1(P):
    """B-1 closed loop, torque components M_1..M_3 of docs/models/saakyan.md (omega0 harmonic program)."""
    A, B, C = P["I"]
    beta, lam, K = _unit(P["H"]), P["lam"], P["K"]
    alpha = lam * K
    b1, b2, b3 = beta

    def w0f(t):
        ph = np.asarray(P["w0f"]) * t + np.asarray(P["w0phi"])
        return np.asarray(P["w0c"]) + np.asarray(P["w0a"]) * np.sin(ph), np.asarray(P["w0a"]) * np.asarray(P["w0f"]) * np.cos(ph)

    def f(t, x):
        p, q, r = x[:3]
        S = x[3:]
        a1, a2, a3 = S / np.linalg.norm(S)
        (p0, q0, r0), (dp0, dq0, dr0) = w0f(t)
        w1 = x[:3] - np.array([p0, q0, r0]) - lam * beta
        mu = P["use_mu"] * mu_111(w1, beta, (A, B, C), lam, K, (p0, q0, r0))
        M1 = mu[0] + A * dp0 + (q0 * C * r - r0 * B * q) + lam * (b2 * C * r - b3 * B * q) + alpha * (a1 - b1)
        M2 = mu[1] + B * dq0 + (r0 * A * p - p0 * C * r) + lam * (b3 * A * p - b1 * C * r) + alpha * (a2 - b2)
        M3 = mu[2] + C * dr0 + (p0 * B * q - q0 * A * p) + lam * (b1 * B * q - b2 * A * p) + alpha * (a3 - b3)
        dp = (M1 - (C - B) * q * r) / A
        dq = (M2 - (A - C) * r * p) / B
        dr = (M3 - (B - A) * p * q) / C
        Sd = np.cross(S, x[:3] - np.array([p0, q0, r0]))
        return np.concatenate([[dp, dq, dr], Sd])

    w00 = w0f(0.0)[0]
    x0 = np.concatenate([w00 + lam * beta + np.asarray(P["dw0"]), _unit(P["S0"])])
    return f, x0
