import pytest


@pytest.fixture(scope="session")
def results(tmp_path_factory):
    """One small result of each kind (see_results.py), built once for the report, view and plot tests."""
    from see_results import build

    return build(tmp_path_factory.mktemp("results"), along=True)


@pytest.fixture(scope="session")
def discovery(results):
    """The pendulum's basin result dressed as a discovery that found two fixed points, the rest point
    theta* = asin(T/K) = pi/6 in two wells of the cylinder (theta* and theta* + 2 pi): what only their
    locations tell apart. The codes are the result's own (0, 1: the two attractors)."""
    import numpy as np

    from stabjax.present.kit import open_result

    ds = open_result(results["basin"])
    names = "fixed_point_1 fixed_point_2 unclassified failed"
    ds["outcome"].attrs["flag_meanings"] = names
    codes = np.asarray(ds["outcome"].values)
    counts = [int((codes == k).sum()) for k in range(2)]
    star = np.arcsin(0.5)
    feats = [f"{s}({o})" for o in ("omega", "sin_theta") for s in ("mean", "std", "min", "max")]
    ds = ds.assign_coords(attractor=["fixed_point_1", "fixed_point_2"], attractor_feature=feats,
                          state_component=["theta", "omega"])
    ds["attractor_type"] = ("attractor", np.array(["fixed_point", "fixed_point"], dtype=object))
    ds["attractor_count"] = ("attractor", np.array(counts))
    ds["attractor_lyapunov"] = ("attractor", np.array([np.nan, np.nan]))
    ds["attractor_state"] = (("attractor", "state_component"), np.array([[star, 0.0], [star + 2 * np.pi, 1e-14]]))
    ds["attractor_features"] = (("attractor", "attractor_feature"),
                                np.array([[0.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.5, 0.5]] * 2))
    return ds
