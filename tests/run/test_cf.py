"""The sweep's dataset follows CF-1.10 (issue 25), checked with cf_xarray's decoding rather than by
reading attributes back: every categorical variable decodes through its flags (``ds.v.cf == name``
selects exactly the trajectories whose code is that name's), every numeric variable and coordinate
has units and a long name, and the globals CF asks for are there. Run on the netCDF file written
through the chunk store and on the in-memory dataset, which must agree."""
import tomllib

import numpy as np
import pytest
import xarray as xr

from cfcheck import CATEGORICAL, REFINE_CATEGORICAL, check_cf  # noqa: F401
from stabjax.app.cli import main
from stabjax.plan.spec import make_plan
from stabjax.run.sweep import run_plan

SAMPLED = """
system = "monoaxial"
name = "cf"
[params]
mu = 1.5
sigma = 1.3333333333333333
[grid]
alpha = [0.35, 0.7, 0.95]
[sample]
n = 6
seed = 0
s0 = {dist = "cap", center = "r", half_angle = 0.5}
[integrate]
t1 = 100.0
n_checkpoints = 32
"""
@pytest.fixture(scope="module")
def in_memory():
    return run_plan(make_plan(tomllib.loads(SAMPLED)), None, batch_size=8)


def test_sweep_dataset_is_cf(in_memory, tmp_path):
    check_cf(in_memory)
    spec = tmp_path / "cf.toml"
    spec.write_text(SAMPLED)
    out = tmp_path / "cf.nc"
    try:
        main(["sweep", str(spec), "--out", str(out), "--batch-size", "8", "--no-progress", "--no-plot", "--keep-store"])
    except SystemExit as exc:
        assert not exc.code
    with xr.open_dataset(out) as ds:
        check_cf(ds.load())
        assert list(ds.data_vars) == list(in_memory.data_vars)  # the store keeps the dataset's order
        for k in in_memory.data_vars:
            np.testing.assert_array_equal(ds[k].values, in_memory[k].values, err_msg=k)
            for a in ("units", "long_name", "flag_meanings"):
                assert ds[k].attrs.get(a) == in_memory[k].attrs.get(a), (k, a)
    check_cf(xr.open_zarr(tmp_path / "cf.nc.zarr").load())  # the kept store is the same dataset


def test_solver_status_flags_cover_the_engines_codes():
    from stabjax.run.dataset import status_flags
    from stabjax.fold.status import ESCAPED as STATUS_ESCAPED

    values, meanings = status_flags()
    names = meanings.split()
    assert names[0] == "successful" and names[1] == "max_steps_reached"
    assert values[names.index("escaped")] == STATUS_ESCAPED
    # the names written without importing diffrax are diffrax's own, in its code order
    import diffrax

    assert names[:-1] == list(diffrax.RESULTS._name_to_item)


# t1 = 1000: long enough for the converged region (alpha >= 0.45 here) to be told from flipped (alpha <= 0.4)
REFINE = SAMPLED.replace("alpha = [0.35, 0.7, 0.95]", "alpha = [0.3, 0.5, 0.7]").replace(
    "t1 = 100.0\nn_checkpoints = 32", "t1 = 1000.0\nn_checkpoints = 200") + """
[refine]
rel_tol = 0.125
"""


def test_refinement_dataset_is_cf(tmp_path):
    """A refinement's dataset (stabjax.explore.refine) follows the same conventions as a sweep's: the checker above
    on the in-memory dataset and on the netCDF file `stabjax sweep` writes for a spec with [refine]. Fails
    if a refinement variable lacks units or a long name, or a label variable's codes do not decode."""
    from stabjax.explore.refine import refine_spec

    ds = refine_spec(tomllib.loads(REFINE))
    assert ds.attrs["kind"] == "refine" and ds.attrs["n_segments"] >= 1  # something to check on every variable
    assert "theory_margin" in ds and np.isfinite(ds["theory_distance_alpha"].values).any()
    check_cf(ds, REFINE_CATEGORICAL, theory_flags=False)
    assert ds.attrs["title"].startswith("stabjax refinement cf")
    assert f"({ds.attrs['n_trajectories']} trajectories)" in ds.attrs["history"]
    assert ds["point_label"].attrs["flag_meanings"].split() == ds.attrs["label_names"].split()
    assert "flag_values" not in ds["segment_axis"].attrs  # one axis: always 0 (see stabjax.explore.refine.assemble)
    spec = tmp_path / "cfr.toml"
    spec.write_text(REFINE)
    out = tmp_path / "cfr.nc"
    try:
        main(["sweep", str(spec), "--out", str(out), "--no-progress", "--no-plot"])
    except SystemExit as exc:
        assert not exc.code
    with xr.open_dataset(out) as written:
        check_cf(written.load(), REFINE_CATEGORICAL, theory_flags=False)
        for k in REFINE_CATEGORICAL:
            np.testing.assert_array_equal(written[k].values, ds[k].values, err_msg=k)


def test_sampled_parameters_keep_their_units():
    """A sampled start is in its parameter's declared units (the pendulum's theta0 in rad, omega0 in rad/s), as a
    grid axis is; the sampled variables were all "1"."""
    from pathlib import Path

    import stabjax

    model = Path(stabjax.__file__).parent / "examples" / "pendulum" / "model.py"
    spec = {"system": f"{model}:Pendulum", "sample": {"n": 4, "seed": 0, "theta0": {"dist": "uniform", "low": -1.0, "high": 1.0},
                                                             "omega0": {"dist": "uniform", "low": -1.0, "high": 1.0}},
            "integrate": {"t1": 1.0, "n_checkpoints": 8}}
    plan = make_plan(spec)
    ds = run_plan(plan, None, batch_size=4)
    assert {k: ds[f"{k}_sample"].attrs["units"] for k in plan.sample} == {"theta0": "rad", "omega0": "rad/s"}


def test_fixed_parameters_are_those_held_fixed(in_memory):
    """fixed_params_json listed the swept alpha and the sampled s0 beside mu, as if fixed (the API pass)."""
    import json

    fixed = json.loads(in_memory.attrs["fixed_params_json"])
    assert "alpha" not in fixed and "s0" not in fixed
    assert fixed["mu"] == 1.5 and fixed["sigma"] == pytest.approx(4 / 3, rel=1e-15)
