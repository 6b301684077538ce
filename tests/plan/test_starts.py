"""Starts from a file ([sample] from = ...) and the per-start comparison with the file's labels."""
from pathlib import Path

import numpy as np
import pytest

from stabjax.errors import ValidationError
from stabjax.plan.starts import compare
from stabjax.run.sweep import run_spec

PENDULUM = "examples/pendulum/model.py:Pendulum"


def test_compare_majority_mapping_and_mcc():
    """Outcome names differ from the labels: mapped by majority; MCC by its definition (two classes:
    (TP TN - FP FN) / sqrt(...), computed here by hand)."""
    names = ["a", "b"]
    codes = np.array([0, 0, 0, 1, 1, 1, 1, 0])
    labels = np.array(["x", "x", "x", "y", "y", "y", "x", "y"])
    r = compare(names, codes, labels)
    assert r["mapping"] == {"a": "x", "b": "y"} and r["one_to_one"]
    assert r["agreement"] == pytest.approx(6 / 8)
    tp, tn, fp, fn = 3, 3, 1, 1  # x as positive
    mcc = (tp * tn - fp * fn) / np.sqrt((tp + fp) * (tp + fn) * (tn + fp) * (tn + fn))
    assert r["mcc"] == pytest.approx(mcc, rel=1e-12)


def _write(tmp_path, fmt, theta, omega, label):
    if fmt == ".csv":
        p = tmp_path / "starts.csv"
        p.write_text("theta0,omega0,label\n" + "".join(f"{float(a)!r},{float(b)!r},{c}\n" for a, b, c in zip(theta, omega, label)))
    elif fmt == ".npy":
        p = tmp_path / "starts.npy"
        arr = np.zeros(len(theta), dtype=[("theta0", float), ("omega0", float), ("label", "U16")])
        arr["theta0"], arr["omega0"], arr["label"] = theta, omega, label
        np.save(p, arr)
    else:
        import xarray as xr

        p = tmp_path / "starts.nc"
        xr.Dataset({"theta0": ("start", theta), "omega0": ("start", omega), "label": ("start", np.asarray(label))}
                   ).to_netcdf(p)
    return p


@pytest.mark.parametrize("fmt", [".csv", ".npy", ".nc"])
def test_file_starts_run_exactly_and_agree_with_their_labels(tmp_path, fmt):
    """The pendulum's own declared run gives the labels of its starts; the same starts from a file, run
    again, are those starts exactly and agree with the labels completely (MCC 1)."""
    ref = run_spec({"system": PENDULUM, "sample": {"n": 60, "seed": 3,
                                                   "theta0": {"dist": "uniform", "low": -2.6, "high": 3.6},
                                                   "omega0": {"dist": "uniform", "low": -6.0, "high": 6.0}},
                    "integrate": {"t1": 300.0, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 300}})
    names = ref["outcome"].attrs["flag_meanings"].split()
    label = [names[c] for c in ref["outcome"].values]
    p = _write(tmp_path, fmt, ref["theta0_sample"].values, ref["omega0_sample"].values, label)
    ds = run_spec({"system": PENDULUM, "sample": {"from": str(p)},
                   "integrate": {"t1": 300.0, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 300}})
    np.testing.assert_array_equal(ds["theta0_sample"].values, ref["theta0_sample"].values)
    np.testing.assert_array_equal(ds["outcome"].values, ref["outcome"].values)
    assert float(ds["start_label_agreement"]) == 1.0 and float(ds["start_label_mcc"]) == pytest.approx(1.0)
    assert list(ds["start_label"].values) == label


def test_bad_starts_files(tmp_path):
    spec = {"system": PENDULUM, "integrate": {"t1": 10.0}}
    bad = tmp_path / "b.csv"
    bad.write_text("theta0,nope\n1,2\n")
    with pytest.raises(ValidationError, match="'nope' is not a parameter"):
        run_spec({**spec, "sample": {"from": str(bad)}})
    bad.write_text("theta0,omega0\n1,x\n")
    with pytest.raises(ValidationError, match="finite numbers; line 2 holds 'x'"):
        run_spec({**spec, "sample": {"from": str(bad)}})
    # the row and the value named: a blank, a NaN, an infinity (lines counted as in the file, blank lines too)
    for body, said in (("1,0\n\n2,\n", "line 4 holds a blank"), ("1,0\n2,nan\n", "line 3 holds nan"),
                       ("1,-inf\n", "line 2 holds -inf")):
        bad.write_text("theta0,omega0\n" + body)
        with pytest.raises(ValidationError, match=f"column 'omega0' must hold finite numbers; {said}"):
            run_spec({**spec, "sample": {"from": str(bad)}})
    with pytest.raises(ValidationError, match="no distributions"):
        run_spec({**spec, "sample": {"from": str(bad), "omega0": {"dist": "uniform", "low": 0, "high": 1}}})
    with pytest.raises(ValidationError, match="file not found"):
        run_spec({**spec, "sample": {"from": str(tmp_path / "none.csv")}})


def test_discovery_against_labels_in_the_file(tmp_path):
    """Discovered names (fixed_point_1, limit_cycle_1) are mapped to the file's names; the pendulum's
    partition is recovered (pyBasin's integration tests ask MCC >= 0.95)."""
    ref = run_spec({"system": PENDULUM, "sample": {"n": 120, "seed": 4,
                                                   "theta0": {"dist": "uniform", "low": -2.6, "high": 3.6},
                                                   "omega0": {"dist": "uniform", "low": -6.0, "high": 6.0}},
                    "integrate": {"t1": 300.0, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 300}})
    names = ref["outcome"].attrs["flag_meanings"].split()
    p = _write(tmp_path, ".csv", ref["theta0_sample"].values, ref["omega0_sample"].values,
               [names[c] for c in ref["outcome"].values])
    ds = run_spec({"system": PENDULUM, "sample": {"from": str(p)}, "outcomes": {"discover": True},
                   "integrate": {"t1": 300.0, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 300}})
    assert float(ds["start_label_agreement"]) >= 0.98 and float(ds["start_label_mcc"]) >= 0.95
    assert "fixed_point_1" in ds["start_label_mcc"].attrs["mapping"]
    from stabjax.present.basins import format_summary

    assert "Matthews correlation" in format_summary(ds)


def _plan(tmp_path, starts, **over):
    from stabjax.plan.spec import make_plan

    return make_plan({"system": PENDULUM, "sample": {"from": str(starts)}, "integrate": {"t1": 10.0}, **over})


def test_a_column_named_twice_in_a_csv_header_is_refused(tmp_path):
    """Before: the second theta0 column was used and omega0 left at its default, without a word."""
    p = tmp_path / "s.csv"
    p.write_text("theta0,theta0\n0.1,0.2\n0.3,0.4\n")
    with pytest.raises(ValidationError, match="column 'theta0' appears 2 times in the header") as e:
        _plan(tmp_path, p)
    assert e.value.field == "sample.from"


def test_a_netcdf_variable_not_1d_along_the_starts_is_refused(tmp_path):
    """Before: a 2-D omega0 was dropped and every start ran with omega0 = 0."""
    import xarray as xr

    p = tmp_path / "s.nc"
    xr.Dataset({"theta0": ("start", [0.1, 0.2, 0.3]), "omega0": (("start", "k"), np.ones((3, 2)))}).to_netcdf(p)
    with pytest.raises(ValidationError, match=r"variable 'omega0' has dimensions \('start', 'k'\)"):
        _plan(tmp_path, p)
    xr.Dataset({"theta0": ("start", [0.1, 0.2, 0.3]), "omega0": ("other", [1.0, 2.0])}).to_netcdf(p, mode="w")
    with pytest.raises(ValidationError, match="variable 'omega0' has dimensions \\('other',\\)"):
        _plan(tmp_path, p)
    xr.Dataset({"theta0": ("start", [0.1, 0.2, 0.3]), "omega0": ((), 1.0)}).to_netcdf(p, mode="w")
    with pytest.raises(ValidationError, match="variable 'omega0' has dimensions \\(\\)"):
        _plan(tmp_path, p)
    xr.Dataset({"theta0": ("start", [0.1, 0.2, 0.3]), "omega0": ("start", [1.0, 2.0, 3.0])}).to_netcdf(p, mode="w")
    plan = _plan(tmp_path, p)  # both along the starts: read, each column whole
    np.testing.assert_array_equal(plan.sample["omega0"], [1.0, 2.0, 3.0])


def test_a_npy_field_with_several_numbers_per_start_is_refused(tmp_path):
    p = tmp_path / "s.npy"
    arr = np.zeros(3, dtype=[("theta0", float), ("omega0", float, (2,))])
    np.save(p, arr)
    with pytest.raises(ValidationError, match="field 'omega0' has shape \\(2,\\) per start"):
        _plan(tmp_path, p)
    np.save(p, np.zeros((3, 2), dtype=[("theta0", float), ("omega0", float)]))
    with pytest.raises(ValidationError, match="needs a 1-D structured array"):
        _plan(tmp_path, p)


def test_a_fixed_parameter_that_is_also_a_column_of_the_file_is_refused(tmp_path):
    """Before: the file won and fixed_params_json recorded the unused 1.0 (the same clash with [sample] NAME
    is refused)."""
    p = tmp_path / "s.csv"
    p.write_text("theta0,omega0\n0.1,0.2\n0.3,0.4\n")
    with pytest.raises(ValidationError, match="is also a column of the starts file s.csv") as e:
        _plan(tmp_path, p, params={"omega0": 1.0})
    assert e.value.field == "params.omega0"
    plan = _plan(tmp_path, p, params={"alpha": 0.2})  # another parameter fixed beside the file: fine
    assert plan.starts_file == p and float(plan.fixed["alpha"]) == 0.2


@pytest.mark.parametrize("force", [False, True])
def test_out_equal_to_the_starts_file_is_refused_even_with_force(tmp_path, capsys, force):
    import xarray as xr

    from clirun import captured

    starts = tmp_path / "starts.nc"
    xr.Dataset({"theta0": ("start", [0.1, 0.2]), "omega0": ("start", [0.0, 1.0])}).to_netcdf(starts)
    before = starts.read_bytes()
    spec = tmp_path / "spec.toml"
    spec.write_text(f'system = "{Path(PENDULUM.split(":")[0]).resolve()}:Pendulum"\n[sample]\nfrom = "starts.nc"\n'
                    "[integrate]\nt1 = 10.0\n")
    code, _, err = captured(capsys, "sweep", spec, "--out", starts, "--no-progress", *(["--force"] if force else []))
    assert code == 2 and "--out" in err and "is this command's input" in err, err
    assert starts.read_bytes() == before and not (tmp_path / "starts.nc.zarr").exists()


def test_complex_and_bool_columns_are_refused_not_cut_to_a_real_part(tmp_path):
    """Before: a complex theta0 ran with its real part (a raw NumPy ComplexWarning the only sign), a bool
    one as 0/1."""
    import xarray as xr

    p = tmp_path / "s.npy"
    for dtype, values in ((complex, [0.5 + 2j, -0.5, 1.0]), (bool, [True, False, True])):
        arr = np.zeros(3, dtype=[("theta0", dtype), ("omega0", float)])
        arr["theta0"] = values
        np.save(p, arr)
        with pytest.raises(ValidationError, match="s.npy: column 'theta0' must hold real numbers") as e:
            _plan(tmp_path, p)
        assert e.value.field == "sample.from"
    nc = tmp_path / "s.nc"
    xr.Dataset({"theta0": ("start", [0.1, 0.2]), "omega0": ("start", np.array([True, False]))}).to_netcdf(nc)
    with pytest.raises(ValidationError, match="s.nc: column 'omega0' must hold real numbers"):
        _plan(tmp_path, nc)
    # netCDF4's complex variable (a compound of r and i, as xarray reads it without auto_complex)
    xr.Dataset({"theta0": ("start", np.array([0.1 + 1j, 0.2])), "omega0": ("start", [0.0, 1.0])}
               ).to_netcdf(nc, mode="w", auto_complex=True)
    with pytest.raises(ValidationError, match="s.nc: column 'theta0' must hold real numbers"):
        _plan(tmp_path, nc)
    arr = np.zeros(2, dtype=[("theta0", np.int32), ("omega0", float), ("label", bool)])  # integers are real
    arr["theta0"], arr["label"] = [1, 2], [True, False]
    np.save(p, arr)
    plan = _plan(tmp_path, p)
    np.testing.assert_array_equal(plan.sample["theta0"], [1.0, 2.0])
    assert list(plan.start_labels) == ["True", "False"]  # a bool label is a class like any other


@pytest.mark.parametrize("fmt", [".csv", ".npy", ".nc"])
def test_a_blank_label_is_refused_naming_its_row(tmp_path, fmt):
    """Before: the blank was one more label class, mapped to an outcome ({"plus": "", ...}) and counted in
    the agreement."""
    p = _write(tmp_path, fmt, [0.5, -0.5, 0.7], [0.0, 0.0, 0.0], ["a", "b", ""])
    where = "line 4" if fmt == ".csv" else "start 2"
    with pytest.raises(ValidationError, match=f"{p.name}: column 'label' is blank at {where}: every start needs its "
                                              "label") as e:
        _plan(tmp_path, p)
    assert e.value.field == "sample.from"
    p = _write(tmp_path, fmt, [0.5, -0.5, 0.7], [0.0, 0.0, 0.0], ["a", "b", "a"])
    assert list(_plan(tmp_path, p).start_labels) == ["a", "b", "a"]


def test_a_csv_with_a_byte_order_mark_is_read(tmp_path):
    """Excel's "CSV UTF-8" starts with a BOM; before, the first column was named '\\ufefftheta0' and refused."""
    p = tmp_path / "s.csv"
    p.write_bytes("theta0,omega0,label\n0.1,0.2,a\n0.3,0.4,b\n".encode("utf-8-sig"))
    plan = _plan(tmp_path, p)
    np.testing.assert_array_equal(plan.sample["theta0"], [0.1, 0.3])
    assert list(plan.start_labels) == ["a", "b"]
