import pytest


@pytest.fixture(scope="session")
def results(tmp_path_factory):
    """One small result of each kind (see_results.py), built once for the report, view and plot tests: once per
    test run, also under pytest-xdist, whose workers share it (the first to need it builds it under a lock in
    the run's own temporary folder, the others read the same files; no test writes into that folder)."""
    import fcntl
    import json
    import os
    from pathlib import Path

    from see_results import build

    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return build(tmp_path_factory.mktemp("results"), along=True)
    root = tmp_path_factory.getbasetemp().parent  # this run's folder, shared by its workers (pytest-N)
    folder, index = root / "present-results", root / "present-results.json"
    with open(root / "present-results.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not index.exists():
            folder.mkdir(exist_ok=True)
            index.write_text(json.dumps({k: str(v) for k, v in build(folder, along=True).items()}))
    return {k: Path(v) for k, v in json.loads(index.read_text()).items()}


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
