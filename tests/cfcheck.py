"""CF-1.10 checks of a dataset through cf_xarray's decoding (shared by the sweep's and the refinement's CF tests)."""
import cf_xarray  # noqa: F401 - registers the .cf accessor
import numpy as np
import xarray as xr

CATEGORICAL = ("verdict", "outcome", "solver_status", "decay_reason")


def check_cf(ds: xr.Dataset, categorical=CATEGORICAL, theory_flags=True, system="monoaxial"):
    """``categorical``: the variables that must decode through flags (besides the theory predicates of a
    sweep, ``theory_flags``; a refinement's ``theory_*`` are distances and margins, numbers with units)."""
    assert ds.attrs["Conventions"] == "CF-1.10"
    for key in ("title", "history", "source"):
        assert ds.attrs[key], key
    assert system in ds.attrs["source"] and "tsit5" in ds.attrs["source"]
    for name, var in ds.variables.items():
        assert var.attrs.get("long_name"), name
        if var.dtype.kind in "biuf":
            assert var.attrs.get("units"), name
    flagged = [k for k in ds.data_vars if ds[k].cf.is_flag_variable]
    assert set(categorical) | {k for k in ds.data_vars if theory_flags and k.startswith("theory_")} <= set(flagged)
    for k in flagged:
        values = np.atleast_1d(ds[k].attrs["flag_values"])  # netCDF reads a one-element list back as a scalar
        meanings = ds[k].attrs["flag_meanings"].split()
        assert len(values) == len(meanings) == len(set(meanings)), k
        codes = ds[k].values
        assert np.isin(codes, values).all(), (k, np.unique(codes))  # no code without a meaning
        covered = np.zeros(codes.shape, int)
        for v, m in zip(values, meanings):
            sel = (ds[k].cf == m).values  # cf_xarray's decoding of the flag
            np.testing.assert_array_equal(sel, codes == v, err_msg=f"{k} == {m}")
            covered += sel
        assert (covered == 1).all(), k


REFINE_CATEGORICAL = ("label_lo", "label_hi", "bracketed", "point_label")  # + segment_axis with two axes
