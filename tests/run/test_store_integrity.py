"""The store never destroys what it did not write, and never reads lost data as values (issue 22,
items 1 and 5; issue 25: the store is a zarr store a user can open while the sweep runs).

The reference for every value is the uninterrupted in-memory run of the same spec (no store at all).
"""
import json
import os
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from stabjax.run import store as S
from stabjax.plan.spec import make_plan
from stabjax.run.sweep import open_result, run_plan, run_spec

from test_store import TINY, cli, interrupt_after  # the same tiny sweep and in-process CLI as the store tests


@pytest.fixture(scope="module")
def reference():
    return run_plan(make_plan(tomllib.loads(TINY)), None, batch_size=4)


@pytest.fixture
def spec(tmp_path):
    p = tmp_path / "tiny.toml"
    p.write_text(TINY)
    return p


def snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every path under ``folder`` with its bytes (None for a directory)."""
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes()) for p in sorted(folder.rglob("*"))}


def assert_same(ds, ref):
    assert set(ds.data_vars) == set(ref.data_vars)
    for k in ref.data_vars:
        np.testing.assert_array_equal(ds[k].values, ref[k].values, err_msg=k)


def sweep(spec, out, *extra):
    return cli("sweep", spec, "--out", out, "--batch-size", 4, "--no-progress", "--no-plot", *extra)


# ---- item 1: a directory that is not this sweep's store ------------------------------------------


def test_store_directory_holding_user_files_is_refused_untouched(spec, tmp_path, capsys):
    """Before the fix, every file in DIR was deleted and the sweep exited 0. Fails if any file in DIR
    changes, disappears or appears, or if the exit status is not 2 with DIR named."""
    home = tmp_path / "project"
    (home / "results").mkdir(parents=True)
    shutil.copy(spec, home / "spec.toml")
    (home / "notes.md").write_text("three weeks of notes\n")
    (home / "results" / "old.nc").write_bytes(b"\x89HDF earlier result")
    before = snapshot(home)
    for extra in ((), ("--restart",)):
        assert sweep(spec, tmp_path / "r.nc", "--store", home, *extra) == 2
        err = " ".join(capsys.readouterr().err.split())
        assert f"{home} exists and is not a stabjax store" in err and "notes.md" in err, err
        assert snapshot(home) == before
    assert not (tmp_path / "r.nc").exists()
    # a file given as the store: refused, unchanged
    f = tmp_path / "file.txt"
    f.write_text("mine")
    assert sweep(spec, tmp_path / "r.nc", "--store", f) == 2
    assert "is not a directory" in " ".join(capsys.readouterr().err.split()) and f.read_text() == "mine"
    # another tool's .lock is not the store's lock: refused, not taken over
    locked = tmp_path / "locked"
    locked.mkdir()
    (locked / ".lock").write_text("held by my editor\n")
    assert sweep(spec, tmp_path / "r.nc", "--store", locked) == 2
    assert "holds .lock" in " ".join(capsys.readouterr().err.split())
    assert (locked / ".lock").read_text() == "held by my editor\n"
    # a directory with someone else's manifest.json: not removed by --restart either
    other = tmp_path / "other"
    other.mkdir()
    (other / "manifest.json").write_text(json.dumps({"format": "another-tool/3", "files": ["a"]}))
    before = snapshot(other)
    assert sweep(spec, tmp_path / "r.nc", "--store", other, "--restart") == 2
    assert "not a stabjax store manifest" in " ".join(capsys.readouterr().err.split())
    assert snapshot(other) == before


def test_empty_directory_is_used_and_left_empty(spec, tmp_path, reference):
    """The folder the user made for --store (as the refusal of a used one advises) is theirs: the store
    removes what it wrote and leaves the folder. Before the fix the folder was removed too. A store's own
    folder (the default <out>.zarr) goes, also when the run that made it was interrupted and resumed."""
    d = tmp_path / "empty"
    d.mkdir()
    with pytest.raises(KeyboardInterrupt):
        run_spec(spec, tmp_path / "r.nc", store=d, batch_size=4, on_chunk=interrupt_after(1))
    assert sweep(spec, tmp_path / "r.nc", "--store", d) == 0
    assert_same(open_result(tmp_path / "r.nc"), reference)
    assert d.is_dir() and not any(d.iterdir())
    assert sweep(spec, tmp_path / "r.nc", "--store", d, "--restart") == 0  # --restart: the folder stays the user's
    assert d.is_dir() and not any(d.iterdir())
    with pytest.raises(KeyboardInterrupt):
        run_spec(spec, tmp_path / "s.nc", batch_size=4, on_chunk=interrupt_after(1))
    assert (tmp_path / "s.nc.zarr").is_dir()
    assert sweep(spec, tmp_path / "s.nc") == 0
    assert not (tmp_path / "s.nc.zarr").exists()


def test_a_chunk_that_reads_as_the_fill_value_is_no_damage(tmp_path):
    """zarr writes no file for a chunk equal to the array's fill value: here the last row of a verdict map, all
    converged (outcome code 0), rewritten when the sweep finishes. Before the fix ``export`` refused the finished
    store ("chunk 4: outcome/c/4/0 is missing"), and so did :func:`stabjax.open_result`; a resume recomputed
    the chunk, warning of damage. Such a chunk is damaged only when what it reads as differs from its checksum."""
    from see_results import VERDICT_MAP
    from stabjax.present.kit import open_result as show_result

    out, store = tmp_path / "r.nc", tmp_path / "r.nc.zarr"
    ref = run_spec(VERDICT_MAP, out, batch_size=5, keep_partial=True)
    m = S.read_manifest(store)
    without = [i for i in range(m["n_chunks"]) if not (store / "outcome" / "c" / str(i) / "0").is_file()]
    assert without and (ref["outcome"].values[without[0]] == 0).all()  # the case this test is about
    assert S.damage(store, m) is None and S.verify(store, m) == {}
    assert cli("export", store, "--out", tmp_path / "x.nc") == 0
    assert_same(open_result(tmp_path / "x.nc"), ref)
    shown = show_result(store)
    assert not shown["pending"].any()
    assert_same(shown.drop_vars("pending"), ref)
    ds = run_spec(VERDICT_MAP, out, batch_size=5, keep_partial=True)  # a resume: nothing recomputed
    assert ds.attrs["chunks_resumed"] == m["n_chunks"]
    assert_same(ds, ref)


def test_a_refused_sweep_does_not_say_it_replaces_the_result(spec, tmp_path, capsys):
    """Before the fix "r.nc exists: it will be replaced" came first, then the refusal (exit 2, nothing replaced)."""
    out, store = tmp_path / "r.nc", tmp_path / "r.nc.zarr"
    assert sweep(spec, out, "--keep-store") == 0
    capsys.readouterr()
    before = out.read_bytes()
    (store / "manifest.json").write_text('{"format": "stabjax-sto')
    assert sweep(spec, out) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "manifest.json is unreadable" in err and "replaced" not in err, err
    assert out.read_bytes() == before
    assert sweep(spec, out, "--restart") == 0  # going ahead: said
    assert "r.nc exists: it will be replaced (a previous result of this spec)" in " ".join(capsys.readouterr().err.split())


def test_restart_and_cleanup_remove_only_what_the_store_wrote(spec, tmp_path, reference):
    """A user's file put into a kept store survives --restart and the store's removal; only the
    entries the manifest lists are deleted, and of an array's folder only what zarr wrote there (a file put
    inside an array's folder was deleted with the array)."""
    out, store = tmp_path / "r.nc", tmp_path / "r.nc.zarr"
    assert sweep(spec, out, "--keep-store") == 0
    written = set(S.read_manifest(store)["entries"])
    assert {"manifest.json", "zarr.json", "verdict", "outcome", "alpha"} <= written
    assert {p.name for p in store.iterdir()} == written | {"manifest.json"}
    (store / "my_notes.txt").write_text("keep me")
    (store / "plots").mkdir()
    (store / "plots" / "a.png").write_bytes(b"png")
    (store / "verdict" / "mine").mkdir()
    (store / "verdict" / "mine" / "f.txt").write_text("mine")
    (store / "outcome" / "c" / "README").write_text("also mine")
    assert sweep(spec, out, "--keep-store", "--restart", "--t1", 50, "--force") == 0
    assert (store / "my_notes.txt").read_text() == "keep me" and (store / "plots" / "a.png").read_bytes() == b"png"
    assert (store / "verdict" / "mine" / "f.txt").read_text() == "mine"
    assert (store / "outcome" / "c" / "README").read_text() == "also mine"
    assert json.loads(xr.open_zarr(store).attrs["integrate_json"])["t1"] == 50.0
    assert sweep(spec, out, "--t1", 50) == 0  # finished: the store's own entries go, the user's stay
    assert sorted(p.name for p in store.iterdir()) == ["my_notes.txt", "outcome", "plots", "verdict"]
    assert sorted(str(p.relative_to(store)) for p in store.rglob("*") if p.is_file()) == [
        "my_notes.txt", "outcome/c/README", "plots/a.png", "verdict/mine/f.txt"]


# ---- item 5: a missing or damaged chunk is recomputed, or named by export ---------------------------


def _chunk_file(store: Path, var: str, row: int) -> Path:
    """The zarr chunk file of chunk ``row`` (a row of the 4 x 4 grid) of ``var``."""
    ndim = len(json.loads((store / var / "zarr.json").read_text())["shape"])
    return store / var / "c" / str(row) / "/".join(["0"] * (ndim - 1))


def test_missing_truncated_or_swapped_chunks_are_named_by_export_and_recomputed_on_resume(spec, tmp_path, reference,
                                                                                          capsys):
    """Three kinds of damage after a finished run: chunk 1's verdict file deleted (zarr would read the
    fill value 0, "converged"), chunk 2's outcome file truncated, chunk 3's n_steps file replaced by
    chunk 0's (a valid file with the wrong numbers). Export must refuse naming chunks 1-3 and write
    nothing; a rerun must recompute exactly those three and give the reference values bitwise."""
    out, store = tmp_path / "r.nc", tmp_path / "r.nc.zarr"
    assert sweep(spec, out, "--keep-store") == 0
    _chunk_file(store, "verdict", 1).unlink()
    f = _chunk_file(store, "outcome", 2)
    f.write_bytes(f.read_bytes()[:5])
    shutil.copy(_chunk_file(store, "n_steps", 0), _chunk_file(store, "n_steps", 3))
    capsys.readouterr()
    assert cli("export", store, "--out", tmp_path / "x.nc") == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "3 chunk(s) are missing or damaged" in err, err
    assert "chunk 1: verdict/c/1/0/0 is missing" in err
    assert "chunk 2: outcome/c/2/0 is unreadable" in err
    assert "chunk 3: n_steps/c/3/0 differs from its checksum" in err
    assert not (tmp_path / "x.nc").exists()
    out.unlink()
    with pytest.warns(S.StoreWarning, match="3 finished chunk"):
        ds = run_spec(spec, out, batch_size=4)
    assert ds.attrs["chunks_resumed"] == 1
    assert_same(ds, reference)
    assert_same(open_result(out), reference)


# ---- issue 25: the store is a zarr dataset -------------------------------------------------------------


def test_open_zarr_on_a_running_sweep_gives_the_datasets_variables(spec, tmp_path, reference):
    """Stopped after two of four chunks: xr.open_zarr gives every variable of the finished dataset; the
    finished rows and the parameter-only variables (theory) hold the reference values."""
    out, store = tmp_path / "r.nc", tmp_path / "r.nc.zarr"

    def stop(i, n):
        if i == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_spec(spec, out, batch_size=4, on_chunk=stop)
    z = xr.open_zarr(store)
    assert set(z.data_vars) == set(reference.data_vars)
    assert z.attrs["stabjax_complete"] == 0 and z.attrs["fingerprint"] == reference.attrs["fingerprint"]
    for k in reference.data_vars:
        if "alpha" in reference[k].dims and not k.startswith(("theory_", "margin_", "derived_", "basin_")):
            np.testing.assert_array_equal(z[k].values[:2], reference[k].values[:2], err_msg=k)
        elif k.startswith(("theory_", "margin_", "derived_")):
            np.testing.assert_array_equal(z[k].values, reference[k].values, err_msg=k)


SAMPLED = TINY.replace("sigma = [1.2, 1.3, 1.4, 1.5]\n", "").replace(
    "[integrate]", "[sample]\nn = 5\nseed = 0\ns0 = {dist = \"cap\", center = \"r\", half_angle = 0.5}\n[integrate]")


def test_a_running_sampled_sweep_shows_the_basin_statistics_of_its_finished_grid_points(tmp_path):
    """Each chunk holds every sample of its grid point (4 alphas x 5 samples, chunks of one alpha): after
    two chunks the store's basin statistics at those alphas equal the finished reference run's, and the
    others read as not computed (NaN), not as a fraction of zero."""
    ref = run_plan(make_plan(tomllib.loads(SAMPLED)), None, batch_size=5)
    spec = tmp_path / "s.toml"
    spec.write_text(SAMPLED)
    out = tmp_path / "s.nc"

    def stop(i, n):
        if i == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_spec(spec, out, batch_size=5, on_chunk=stop)
    z = xr.open_zarr(tmp_path / "s.nc.zarr")
    for k in ("basin_count", "basin_fraction", "basin_ci_low", "basin_ci_high", "outcome"):
        np.testing.assert_array_equal(z[k].values[:2], ref[k].values[:2], err_msg=k)
    assert np.isnan(z["basin_fraction"].values[2:]).all()
    ds = run_spec(spec, out, batch_size=5)
    assert ds.attrs["chunks_resumed"] == 2
    assert_same(ds, ref)


def test_outcomes_over_the_whole_sweep_are_added_when_it_finishes(tmp_path, monkeypatch):
    """A classification that needs every trajectory (attractor discovery) cannot be stored chunk by
    chunk: the store then holds the engines' records only, and finishing adds the outcome and basin
    variables from the derive step over all of them. The dataset must equal the one whose outcomes
    were computed per chunk (the reference, run before the switch), in memory and from the store."""
    from stabjax.mapping.mapper import Mapper

    ref = run_plan(make_plan(tomllib.loads(SAMPLED)), None, batch_size=5)
    monkeypatch.setattr(Mapper, "whole_set", True)  # a per-trajectory mapper taken down the whole-set path
    spec = tmp_path / "s.toml"
    spec.write_text(SAMPLED)
    out = tmp_path / "w.nc"
    ds = run_spec(spec, out, batch_size=5, keep_partial=True)
    assert_same(ds, ref)
    assert_same(open_result(out), ref)
    mem = run_plan(make_plan(tomllib.loads(SAMPLED)), None, batch_size=5)  # in memory too
    assert_same(mem, ref)
    assert list(open_result(out).data_vars) == list(mem.data_vars)
    m = S.read_manifest(tmp_path / "w.nc.zarr")
    assert "outcome" not in m["arrays"] and {"outcome", "basin_fraction", "outcome_name"} <= set(m["entries"])
    z = xr.open_zarr(tmp_path / "w.nc.zarr")
    assert set(z.data_vars) == set(ref.data_vars)
    assert z.attrs["n_trajectories"] == 20 and z.attrs["fingerprint"] == ref.attrs["fingerprint"]  # attrs kept
    np.testing.assert_array_equal(z["basin_fraction"].values, ref["basin_fraction"].values)
    assert z["outcome"].attrs["units"] == "1" and z["outcome"].attrs["flag_meanings"] == ref["outcome"].attrs["flag_meanings"]


def test_a_store_whose_metadata_is_damaged_starts_over(spec, tmp_path, reference):
    """The zarr metadata of an array cut short (a disk error, an editor): nothing of the store can be
    trusted, so every chunk is computed again, with a warning, and the result is the reference."""
    out, store = tmp_path / "r.nc", tmp_path / "r.nc.zarr"
    assert sweep(spec, out, "--keep-store") == 0
    (store / "verdict" / "zarr.json").write_text('{"zarr_format": 3, "node_ty')
    out.unlink()
    with pytest.warns(S.StoreWarning, match="4 finished chunk"):
        ds = run_spec(spec, out, batch_size=4)
    assert ds.attrs["chunks_resumed"] == 0
    assert_same(ds, reference)


# ---- issue 32: the layout of a small store is made without Dask ----------------------------------------------


@pytest.mark.parametrize("text", [TINY, SAMPLED], ids=["grid", "sampled"])
def test_the_layout_made_without_dask_is_the_same_store(tmp_path, monkeypatch, text, reference):
    """Placeholders of zarr's fill value (numpy, small stores) and lazy Dask ones (large stores) lay out the same
    arrays -- every zarr.json and the consolidated metadata equal -- write no chunk of an unfinished block,
    and finish to the same result bitwise."""
    spec = tmp_path / "s.toml"
    spec.write_text(text)
    batch = 4 if text is TINY else 5
    made = {}
    for how, limit in (("numpy", S.PLACEHOLDER_BYTES), ("dask", 0)):
        monkeypatch.setattr(S, "PLACEHOLDER_BYTES", limit)
        out = tmp_path / f"{how}.nc"

        def stop(i, n):
            if i == 0:
                raise KeyboardInterrupt

        with pytest.raises(KeyboardInterrupt):
            run_spec(spec, out, batch_size=batch, on_chunk=stop)
        store = tmp_path / f"{how}.nc.zarr"
        meta = {str(p.relative_to(store)): json.loads(p.read_text()) for p in sorted(store.glob("*/zarr.json"))}
        root = json.loads((store / "zarr.json").read_text())["consolidated_metadata"]
        files = sorted(str(p.relative_to(store)) for p in store.rglob("*") if p.is_file() and "/c/" in str(p))
        chunked = S.read_manifest(store)["arrays"]
        assert not [f for f in files if f.split("/")[0] in chunked and f.split("/")[2] != "0"]  # only block 0 written
        made[how] = (meta, root, files, run_spec(spec, out, batch_size=batch))
    assert made["numpy"][:3] == made["dask"][:3]
    assert_same(made["numpy"][3], made["dask"][3])
    if text is TINY:
        assert_same(made["numpy"][3], reference)


def test_a_0d_arrays_chunk_is_removed_with_its_store(tmp_path):
    """A 0-d array's one chunk is the file ``c`` (zarr 3): the continuation's ``attractor_events`` kept its folder
    and that file behind every finished discovery sweep (the store folder left with them)."""
    store = tmp_path / "s.zarr"
    xr.Dataset({"events": ((), "[]"), "x": ("n", np.arange(3.0))}).to_zarr(store, zarr_format=3)
    assert (store / "events" / "c").is_file()
    (store / "x" / "mine.txt").write_text("mine")  # a user's file stays, as before
    S.remove_listed(store, {"entries": ["events", "x", "zarr.json"], "damaged": True})
    assert not (store / "events").exists() and (store / "x" / "mine.txt").read_text() == "mine"
