"""The Python API writes no more than the command line does: ``run_spec``/``run_plan``, ``refine_spec`` and
``plot``/``write_report`` never write over the spec, the model or the starts file they read (even with
``force=True``), replace an existing file only when it is their own previous output of the same spec, and
otherwise refuse naming ``out`` and the way to allow it (``force=True``). Before, each of them wrote over any
path it was given, its own inputs among them."""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import stabjax
from stabjax import ValidationError

MODEL = Path(__file__).parents[1] / "models" / "oscillator.py"
SPEC = f"""system = "{MODEL}:Oscillator"
name = "api_out"
[grid]
k = [0.0, 1.0]
[integrate]
t1 = 40.0
n_checkpoints = 64
"""


def digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "s.toml").write_text(SPEC)
    xr.Dataset({"x0": ("n", np.array([1.0, 0.5])), "v0": ("n", np.array([0.0, 0.1]))}).to_netcdf(tmp_path / "starts.nc")
    (tmp_path / "starts.toml").write_text(SPEC.replace("[grid]\nk = [0.0, 1.0]", '[sample]\nfrom = "starts.nc"'))
    return tmp_path


def test_a_run_never_writes_over_its_spec_model_or_starts_even_with_force(folder):
    before = {p: digest(p) for p in (folder / "s.toml", folder / "starts.nc", MODEL)}
    for spec, out in (("s.toml", "s.toml"), ("s.toml", MODEL), ("starts.toml", "starts.nc")):
        for force in (False, True):
            with pytest.raises(ValidationError) as e:
                stabjax.run_spec(folder / spec, folder / out, force=force)
            assert e.value.field == "out"
    # the spec file itself under a result's suffix: a link to it, named .nc
    (folder / "link.nc").symlink_to(folder / "s.toml")
    with pytest.raises(ValidationError, match="input"):
        stabjax.run_spec(folder / "s.toml", folder / "link.nc", force=True)
    assert before == {p: digest(p) for p in before}


def test_an_existing_file_is_replaced_only_when_it_is_a_result_of_this_spec_or_with_force(folder):
    foreign = folder / "r.nc"
    foreign.write_text("a user's file")
    with pytest.raises(ValidationError, match=r"force=True") as e:
        stabjax.run_spec(folder / "s.toml", foreign)
    assert e.value.field == "out" and foreign.read_text() == "a user's file"
    ds = stabjax.run_spec(folder / "s.toml", foreign, force=True)
    assert ds.sizes["k"] == 2 and stabjax.open_result(foreign).sizes["k"] == 2
    again = stabjax.run_spec(folder / "s.toml", foreign)  # a re-run of the same spec replaces its own result
    np.testing.assert_array_equal(again["outcome"].values, ds["outcome"].values)
    other = stabjax.load_spec(folder / "s.toml")
    other["grid"] = {"k": [0.0, 0.5]}
    with pytest.raises(ValidationError, match="not a result of this spec"):
        stabjax.run_spec(other, foreign)
    with pytest.raises(ValidationError, match="not a result of this spec"):
        stabjax.refine_spec({**other, "refine": {"tol": {"k": 0.1}}}, foreign)
    with pytest.raises(ValidationError, match="not a result of this spec"):
        stabjax.shock_spec({**other, "shock": {"components": ["x0"], "max_radius": 1.0}}, foreign)

    # figures and pages: a user's file is refused, our own drawing of the same result is replaced
    png, page = folder / "notes.png", folder / "notes.html"
    png.write_text("a user's figure")
    page.write_text("<p>a user's notes</p>")
    for call in (lambda: stabjax.plot(ds, png), lambda: stabjax.write_report(ds, page),
                 lambda: stabjax.write_report(foreign, page)):
        with pytest.raises(ValidationError, match=r"force=True"):
            call()
    assert png.read_text() == "a user's figure" and page.read_text() == "<p>a user's notes</p>"
    with pytest.raises(ValidationError, match=r"\.png or \.pdf or \.svg"):
        stabjax.plot(ds, folder / "x.nc")
    fig = folder / "fig.png"
    stabjax.plot(foreign, fig)
    stabjax.plot(foreign, fig)  # its own figure of this result: drawn again
    stabjax.write_report(foreign, folder / "rep.html")  # a result's path is accepted as the dataset is
    stabjax.write_report(ds, folder / "rep.html")
    stabjax.plot(ds, png, force=True)
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_api_calls_on_the_wrong_kind_of_argument_are_refused_by_name(folder):
    """``horizon_check`` of a result without attitude verdicts and ``simulate`` with a list for its parameters were
    a KeyError and an AttributeError; both are a ValidationError naming the argument."""
    ds = stabjax.run_spec(folder / "s.toml")  # named outcomes
    for arg in (ds, 3.0):
        with pytest.raises(ValidationError) as e:
            stabjax.horizon_check(arg)
        assert e.value.field == "ds"
    with pytest.raises(ValidationError, match="outcomes"):
        stabjax.horizon_check(ds)
    with pytest.raises(ValidationError) as e:
        stabjax.simulate(f"{MODEL}:Oscillator", [0.3], t1=1.0)
    assert e.value.field == "params"
    # solve_batch: a parameter missing (was KeyError: 'x0'), lengths that differ (was JAX's vmap error)
    from stabjax.config import IntegrateConfig

    system = stabjax.get_system(f"{MODEL}:Oscillator")
    full = {"c": np.full(2, 0.5), "k": np.zeros(2), "x0": np.ones(2), "v0": np.zeros(2)}
    icfg = IntegrateConfig(t1=1.0)
    for params, said in (({k: v for k, v in full.items() if k != "x0"}, "no 'x0'"),
                         ({**full, "k": np.zeros(3)}, "k: 3"), ({**full, "c": 0.5}, "c: a scalar")):
        with pytest.raises(ValidationError, match=said):
            stabjax.solve_batch(system, params, icfg)


def test_a_lattice_of_trajectories_is_not_presented_as_random_draws(folder):
    """One trajectory per grid point: the pooled S is the lattice's share; its SE and Wilson interval, computed
    as for random draws, are said to bound no error (in the printed table and on the report's page)."""
    from stabjax.present.basins import format_summary
    from stabjax.present.report import render

    ds = stabjax.run_spec(folder / "s.toml")
    assert "sample" not in ds["outcome"].dims
    assert "not random draws" in format_summary(ds) and "not random draws" in render(ds)


@pytest.mark.parametrize("fn, section", [("refine_spec", "refine"), ("shock_spec", "shock")])
def test_a_spec_without_its_section_is_refused_before_anything_is_written(folder, fn, section):
    from stabjax.explore.refine import refine_spec
    from stabjax.explore.shock import shock_spec

    before = sorted(p.name for p in folder.iterdir())
    with pytest.raises(ValidationError) as exc:
        {"refine_spec": refine_spec, "shock_spec": shock_spec}[fn](folder / "s.toml", folder / "r.nc")
    assert exc.value.field == section and f"no [{section}] section" in exc.value.message
    assert sorted(p.name for p in folder.iterdir()) == before


@pytest.mark.parametrize("table", ["refine", "shock"])
def test_run_spec_refuses_a_table_it_would_not_run(folder, table):
    """run_spec of a spec with a [shock] table ran the plain sweep and returned its outcomes as if searched."""
    import tomllib

    spec = tomllib.loads((folder / "s.toml").read_text())
    spec[table] = {"tol": {"x0": 0.1}} if table == "refine" else {"components": ["x0"], "max_radius": 1.0}
    before = sorted(p.name for p in folder.iterdir())
    with pytest.raises(ValidationError) as exc:
        stabjax.run_spec(spec, folder / "r.nc")
    assert exc.value.field == table and f"use stabjax.{table}_spec(spec)" in exc.value.message
    assert sorted(p.name for p in folder.iterdir()) == before


@pytest.mark.parametrize("fn", ["run_spec", "refine_spec", "shock_spec"])
def test_the_api_names_its_own_arguments(folder, fn):
    """A bad t1 is the argument t1 (it was the command line's --t1), and a keyword the call does not take is
    refused in the call's name before anything runs (it was a TypeError from the internal run_plan)."""
    from stabjax.explore.refine import refine_spec
    from stabjax.explore.shock import shock_spec

    call = {"run_spec": stabjax.run_spec, "refine_spec": refine_spec, "shock_spec": shock_spec}[fn]
    before = sorted(p.name for p in folder.iterdir())
    with pytest.raises(TypeError, match=rf"^{fn}\(\) got an unexpected keyword argument 'bogus'"):
        call(folder / "s.toml", folder / "r.nc", bogus=1)
    if fn == "run_spec":
        with pytest.raises(ValidationError) as exc:
            call(folder / "s.toml", t1=-1.0)
        assert exc.value.field == "t1"
    assert sorted(p.name for p in folder.iterdir()) == before
