"""Where a discovered attractor is said to be (stabjax.present.kit.attractors), on small datasets built here."""
import numpy as np
import xarray as xr

from stabjax.present import kit


def _result(mins, maxs, outcome):
    """A discovery result of one untyped attractor: per trajectory window minima and maxima of x, the outcome codes
    (0: attractor_1, 1: unclassified), the median features as discovery stores them."""
    mins, maxs = np.asarray(mins, float), np.asarray(maxs, float)
    mine = np.asarray(outcome) == 0
    feats = ["mean(x)", "std(x)", "min(x)", "max(x)"]
    med = [np.median((mins[mine] + maxs[mine]) / 2), 0.0, np.median(mins[mine]), np.median(maxs[mine])]
    return xr.Dataset(
        {"outcome": ("sample", np.asarray(outcome, np.int8), {"flag_meanings": "attractor_1 unclassified failed"}),
         "feat_min": (("sample", "observable"), mins[:, None]), "feat_max": (("sample", "observable"), maxs[:, None]),
         "observable_range": ("observable", [4.0]),
         "attractor_type": ("attractor", np.array(["attractor"], object)),
         "attractor_features": (("attractor", "attractor_feature"), np.array([med]))},
        coords={"attractor": ["attractor_1"], "attractor_feature": feats, "observable": ["x"]})


def test_members_resting_all_over_a_line_are_said_to_cover_it():
    """x' = 0, y' = -y: every start rests where it began, one untyped group; its median window was printed
    "x in [0.1647, 0.1647]" as if the group were at one point. Its members' windows together cover [-1.97, 1.99]:
    said. A cycle's members, each covering about the median window, get nothing added; nor does a trajectory of
    another outcome widen an attractor's cover."""
    rest = np.linspace(-1.97, 1.99, 41)
    line = kit.attractors(_result(rest, rest, np.zeros(41, int)))[0]["where"]
    assert line.startswith("x in [") and line.endswith("its trajectories' windows cover x in [-1.97, 1.99]"), line
    rng = np.random.default_rng(0)
    lo, hi = -2.0 + rng.normal(0, 0.01, 41), 2.0 + rng.normal(0, 0.01, 41)
    cycle = kit.attractors(_result(lo, hi, np.zeros(41, int)))[0]["where"]
    assert "cover" not in cycle and cycle.startswith("x in [-2"), cycle
    other = np.r_[np.zeros(40, int), 1]
    hi2 = hi.copy()
    hi2[-1] = 9.0  # an unclassified trajectory far away
    assert "cover" not in kit.attractors(_result(lo, hi2, other))[0]["where"]
