"""Every array a chunk store holds is checksummed: a deleted, truncated or flipped chunk file of any of them
is refused by name by ``export`` and repaired by a resumed ``sweep`` -- never read as the fill value, never
read as something else (issue 29, "a damaged store gives a wrong result with exit 0").

The reference for every value is the undamaged store's own result (the clean run's netCDF file: that a
store's result equals the run without a store is test_store_integrity.py's). The stores are the
pendulum example's (samples, a grid axis, named outcomes, observables, basin statistics), with rules and
with attractor discovery (a classification over the whole sweep, added when the sweep finishes). The full
grid of arrays x damages is ``slow``; one case of each kind of array runs in CI.
"""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr

from stabjax.errors import ValidationError
from stabjax.present.kit import open_result as show_result
from stabjax.run import store as S
from stabjax.run.sweep import open_result, run_spec

from clirun import captured, status

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "examples" / "pendulum" / "model.py"

SPEC = f"""system = "{MODEL}:Pendulum"
name = "damage"
[grid]
alpha = [0.1, 0.12]
[sample]
n = 30
seed = 1
theta0 = {{dist = "uniform", low = -2.6, high = 3.6}}
omega0 = {{dist = "uniform", low = -10.0, high = 10.0}}
[integrate]
t1 = 150.0
n_checkpoints = 300
"""
DISCOVER = SPEC.replace('name = "damage"', 'name = "damage_discovery"\n[outcomes]\ndiscover = true')
BATCH = 30  # one chunk per grid point: two chunks

# (array, kind): static = written when the store is created, derived = when it finishes, chunk = per chunk
RULES = [("alpha", "static"), ("sample", "static"), ("theta0_sample", "static"), ("outcome_name", "static"),
         ("observable", "static"), ("basin_fraction", "derived"), ("basin_count", "derived"),
         ("outcome", "chunk"), ("feat_mean", "chunk")]
FOUND = [("outcome", "derived"), ("attractor_type", "derived"), ("attractor_state", "derived"),
         ("observable_range", "derived"), ("basin_count", "derived")]
DAMAGES = ("delete", "truncate", "flip")
FAST = {("rules", "theta0_sample", "delete"), ("rules", "basin_fraction", "flip"), ("rules", "outcome", "truncate"),
        ("discovery", "outcome", "delete"), ("interrupted", "alpha", "delete")}


def cases(store, arrays, damages=DAMAGES):
    return [pytest.param(store, a, kind, d, id=f"{store}-{a}-{d}",
                         marks=() if (store, a, d) in FAST else pytest.mark.slow)
            for a, kind in arrays for d in damages]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """The kept stores of a clean run of each spec, their results, and an interrupted rules store (one of
    its two chunks finished)."""
    d = tmp_path_factory.mktemp("damage")
    out = {}
    for key, text in (("rules", SPEC), ("discovery", DISCOVER)):
        spec = d / f"{key}.toml"
        spec.write_text(text)
        res = d / f"{key}.nc"
        run_spec(spec, res, batch_size=BATCH, keep_partial=True)
        out[key] = (spec, d / f"{key}.nc.zarr", open_result(res))
    spec = out["rules"][0]

    def stop(i, n):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_spec(spec, d / "interrupted.nc", batch_size=BATCH, on_chunk=stop)
    assert len(S.read_manifest(d / "interrupted.nc.zarr")["chunks"]) == 1
    out["interrupted"] = (spec, d / "interrupted.nc.zarr", out["rules"][2])
    return out


def chunk_files(store: Path, name: str) -> list[Path]:
    return sorted(p for p in (store / name / "c").rglob("*") if p.is_file())


def read(store: Path, name: str):
    try:
        return zarr.open_group(store, mode="r")[name][...]
    except Exception as exc:  # noqa: BLE001 - what a damaged chunk gives
        return exc


def damage(store: Path, name: str, how: str) -> str:
    """Damage the first chunk file of ``name``; its path inside the store."""
    f = chunk_files(store, name)[0]
    data = f.read_bytes()
    if how == "delete":
        f.unlink()
    elif how == "truncate":
        f.write_bytes(data[:len(data) // 2])
    else:  # one byte flipped: the first, from the middle on, that changes what the array reads
        before = read(store, name)
        for i in list(range(len(data) // 2, len(data))) + list(range(len(data) // 2)):
            f.write_bytes(data[:i] + bytes([data[i] ^ 0x10]) + data[i + 1:])
            now = read(store, name)
            if isinstance(now, Exception) or now.shape != before.shape or \
                    not np.array_equal(now, before, equal_nan=now.dtype.kind == "f"):
                break
        else:
            pytest.fail(f"no single byte of {f} changes what {name} reads")
    return str(f.relative_to(store))


def assert_same(ds, ref):
    assert set(ds.variables) == set(ref.variables)
    for k in ref.variables:
        np.testing.assert_array_equal(ds[k].values, ref[k].values, err_msg=k)


def check_shown_nowhere(capsys, store: Path, tmp_path, said: str) -> None:
    """What shows a store (:func:`stabjax.open_result`, and through it ``plot``, ``report`` and ``view``) refuses
    a damaged one as ``export`` does, finished or not, saying ``said``; ``plot`` (which shows finished stores
    only) exits 2 and draws nothing. Before the fix they read a damaged chunk as its fill value or its flipped
    value."""
    with pytest.raises(ValidationError) as exc:
        show_result(store)
    assert said in str(exc.value) and "nothing is shown from it" in str(exc.value), exc.value
    code, _, err = captured(capsys, "plot", store, "--out", tmp_path / "shown.png")
    finished = len(S.read_manifest(store)["chunks"]) == 2
    assert code == 2 and (said if finished else "1 of 2 chunks finished") in err, err
    assert not (tmp_path / "shown.png").exists()


def check(made, tmp_path, capsys, key, name, kind, how):
    spec, clean, ref = made[key]
    store = tmp_path / "r.nc.zarr"
    shutil.copytree(clean, store)
    where = damage(store, name, how)
    check_shown_nowhere(capsys, store, tmp_path, name)
    if key != "interrupted":  # a finished store: export refuses, naming the array, and writes nothing
        code, _, err = captured(capsys, "export", store, "--out", tmp_path / "x.nc")
        assert code == 2, err
        assert name in err and "nothing was exported" in err, err
        if how == "delete":
            assert f"{where} is missing" in err, err
        assert not (tmp_path / "x.nc").exists()
    # the sweep resumed on it: the damaged array recomputed (a chunk integrated again, a static array written
    # again, a derived one computed again at the end), said in a warning naming it, and the clean result
    with pytest.warns(S.StoreWarning, match=name):
        ds = run_spec(spec, tmp_path / "r.nc", batch_size=BATCH, keep_partial=True)
    assert_same(ds, ref)
    assert_same(open_result(tmp_path / "r.nc"), ref)
    if key != "interrupted" and kind == "chunk":
        assert ds.attrs["chunks_resumed"] == 1
    # and the repaired store exports the same result
    assert captured(capsys, "export", store, "--out", tmp_path / "y.nc")[0] == 0
    assert_same(open_result(tmp_path / "y.nc"), ref)


@pytest.mark.parametrize("key,name,kind,how", cases("rules", RULES) + cases("discovery", FOUND))
def test_a_damaged_array_of_a_kept_store_is_refused_by_export_and_recomputed_by_the_sweep(made, tmp_path, capsys,
                                                                                           key, name, kind, how):
    check(made, tmp_path, capsys, key, name, kind, how)


@pytest.mark.parametrize("key,name,kind,how", cases("interrupted", [a for a in RULES if a[1] != "derived"]))
def test_a_damaged_array_of_an_interrupted_store_is_recomputed_on_resume(made, tmp_path, capsys, key, name, kind, how):
    """Before the fix: a deleted sample chunk gave NaN starts in the finished result, exit 0."""
    check(made, tmp_path, capsys, key, name, kind, how)


# the metadata files (the group's zarr.json holds a copy of every array's in its consolidated metadata, which
# xarray reads): (store, file, damage)
META = [("rules", "zarr.json", "flip"), ("rules", "zarr.json", "swap"), ("rules", "outcome/zarr.json", "delete"),
        ("interrupted", "zarr.json", "flip"), ("rules", "zarr.json", "delete"), ("rules", "zarr.json", "truncate"),
        ("rules", "outcome/zarr.json", "swap"), ("rules", "feat_mean/zarr.json", "truncate"),
        ("rules", "sample/zarr.json", "delete"), ("rules", "basin_fraction/zarr.json", "delete"),
        ("discovery", "zarr.json", "swap"), ("interrupted", "outcome/zarr.json", "delete")]
FAST_META = set(META[:4])


def damage_metadata(store: Path, name: str, how: str) -> None:
    """Damage a zarr.json: deleted, cut in half, or its outcome names changed in place -- one bit of the first
    name flipped ("fixed_point" -> "fixed_poinu"), or the first two names swapped (the basins exchanged)."""
    f = store / name
    data = f.read_bytes()
    if how == "delete":
        f.unlink()
    elif how == "truncate":
        f.write_bytes(data[:len(data) // 2])
    else:
        key = b'"flag_meanings": "'
        at = data.index(key) + len(key)
        end = data.index(b'"', at)
        names = data[at:end].split(b" ")
        if how == "flip":
            names[0] = names[0][:-1] + bytes([names[0][-1] ^ 1])
        else:
            names[0], names[1] = names[1], names[0]
        f.write_bytes(data[:at] + b" ".join(names) + data[end:])


@pytest.mark.parametrize("key,name,how", [pytest.param(*c, id="-".join(c), marks=() if c in FAST_META
                                                       else pytest.mark.slow) for c in META])
def test_damaged_metadata_is_refused_by_export_and_written_again_by_the_sweep(made, tmp_path, capsys, key, name, how):
    """Before the fix: one flipped bit in an outcome name of the group's zarr.json was exported with exit 0
    as the outcome "fixed_poinu", two names swapped exchanged the basins, and the resumed sweep kept either;
    a deleted array's zarr.json was said four times as a FileNotFoundError."""
    spec, clean, ref = made[key]
    store = tmp_path / "r.nc.zarr"
    shutil.copytree(clean, store)
    damage_metadata(store, name, how)
    check_shown_nowhere(capsys, store, tmp_path, f"{name} {'is missing' if how == 'delete' else 'differs from its checksum'}")
    if key != "interrupted":
        code, _, err = captured(capsys, "export", store, "--out", tmp_path / "x.nc")
        err = " ".join(err.split())
        assert code == 2 and f"{name} {'is missing' if how == 'delete' else 'differs from its checksum'}" in err, err
        assert "nothing was exported" in err and not (tmp_path / "x.nc").exists()
    code = status("sweep", spec, "--out", tmp_path / "r.nc", "--batch-size", BATCH, "--no-progress", "--no-plot",
                  "--keep-store")
    err = capsys.readouterr().err
    assert code == 0, err
    said = [ln for ln in err.splitlines() if ln.strip()]
    # the store's warnings (the result's own, on its unclassified share, are about the result, not the store)
    warned = [ln for ln in said if ln.startswith("warning: ") and "lower bounds" not in ln]
    assert len(warned) == 1 and f"{store}: {name} " in warned[0] and "written again" in warned[0], err
    assert "Error" not in err and "Errno" not in err, err
    ds = open_result(tmp_path / "r.nc")
    assert_same(ds, ref)
    assert ds["outcome"].attrs["flag_meanings"] == ref["outcome"].attrs["flag_meanings"]
    np.testing.assert_array_equal(ds["outcome_name"].values, ref["outcome_name"].values)
    assert captured(capsys, "export", store, "--out", tmp_path / "y.nc")[0] == 0
    y = open_result(tmp_path / "y.nc")
    assert_same(y, ref)
    assert y["outcome"].attrs["flag_meanings"] == ref["outcome"].attrs["flag_meanings"]


def test_a_sweep_stopped_while_it_rewrites_the_groups_metadata_writes_the_store_again(made, tmp_path, monkeypatch):
    """The group's zarr.json is rewritten when the sweep finishes (its attributes): stopped before its new
    checksum is recorded, the manifest says so, and the next run trusts nothing read through it."""
    spec, clean, ref = made["interrupted"]
    store = tmp_path / "r.nc.zarr"
    shutil.copytree(clean, store)

    def stopped(path, attrs):
        raise KeyboardInterrupt

    monkeypatch.setattr(S, "_set_root_attrs", stopped)
    with pytest.raises(KeyboardInterrupt):
        run_spec(spec, tmp_path / "r.nc", batch_size=BATCH)
    monkeypatch.undo()
    m = S.read_manifest(store)
    assert m["metadata"]["zarr.json"] == S.REWRITING and not m["finished"]
    with pytest.warns(S.StoreWarning, match="zarr.json was being rewritten"):
        ds = run_spec(spec, tmp_path / "r.nc", batch_size=BATCH)
    assert_same(ds, ref)


def test_every_array_of_a_store_has_a_checksum(made):
    """Each zarr array of the finished stores is exactly one of: a per-chunk record (a checksum per chunk),
    a static array or a derived one (a checksum of the whole array), so none can be read unchecked."""
    for key in ("rules", "discovery"):
        _, store, ref = made[key]
        m = S.read_manifest(store)
        chunked, static, derived = set(m["arrays"]), set(m["static"]), set(m["derived"])
        assert not (chunked & static or chunked & derived or static & derived)
        held = set(zarr.open_group(store, mode="r").array_keys())
        assert held == chunked | static | derived
        assert held == set(ref.variables)  # every variable of the result comes from a checked array
        assert all(len(m["chunks"][c]["sha256"]) == len(chunked) for c in m["chunks"])
        metadata = {str(p.relative_to(store)) for p in store.rglob("zarr.json")}
        assert set(m["metadata"]) == metadata == {"zarr.json", *(f"{k}/zarr.json" for k in held)}


def test_a_truncated_chunk_is_named_not_a_zstd_traceback_nor_a_full_disk(made, tmp_path, capsys):
    """Before: "is unreadable (RuntimeError)"; the name of an exception is no help to a user."""
    _, clean, _ = made["rules"]
    store = tmp_path / "r.nc.zarr"
    shutil.copytree(clean, store)
    where = damage(store, "basin_count", "truncate")
    code, out, err = captured(capsys, "export", store, "--out", tmp_path / "x.nc")
    assert code == 2 and f"{where} is unreadable, cut short or overwritten" in " ".join(err.split()), err
    assert "Traceback" not in out + err and "disk" not in err and "Zstd" not in err and "Error" not in err


def test_export_of_an_unreadable_manifest_says_what_export_can_do(made, tmp_path, capsys):
    _, clean, _ = made["rules"]
    store = tmp_path / "r.nc.zarr"
    shutil.copytree(clean, store)
    (store / "manifest.json").write_text('{"format": "stabjax-sto')
    code, _, err = captured(capsys, "export", store, "--out", tmp_path / "x.nc")
    assert code == 2 and "unreadable" in err and "nothing can be exported" in err, err
    assert f"stabjax sweep SPEC --store {store} --restart" in err
    assert not (tmp_path / "x.nc").exists()


@pytest.mark.parametrize("old", ["stabjax-store/2", "stabjax-store/3"])
def test_a_store_of_the_previous_format_is_refused_and_restart_removes_only_its_entries(made, tmp_path, old):
    """Stores written before every array was checksummed (stabjax-store/2), or before their metadata was
    (/3), cannot be trusted: refused with --restart as the way on, which removes the entries that manifest
    lists and nothing else."""
    spec, clean, ref = made["rules"]
    store = tmp_path / "r.nc.zarr"
    shutil.copytree(clean, store)
    m = json.loads((store / "manifest.json").read_text())
    m["format"] = old
    m.pop("metadata")
    (store / "manifest.json").write_text(json.dumps(m))
    (store / "mine.txt").write_text("keep")
    with pytest.raises(S.StoreError, match="earlier stabjax version"):
        run_spec(spec, tmp_path / "r.nc", batch_size=BATCH)
    ds = run_spec(spec, tmp_path / "r.nc", batch_size=BATCH, restart=True)
    assert_same(ds, ref)
    assert sorted(p.name for p in store.iterdir()) == ["mine.txt"]


def test_the_sweep_says_a_repair_in_one_line_and_never_wraps_its_output(made, tmp_path, capsys):
    """A resume's warning is one line of stderr (not Python's FILE:LINE: StoreWarning and a line of our
    source), and stdout that is not a terminal is not cut at 80 columns."""
    spec, clean, ref = made["rules"]
    store = tmp_path / "r.nc.zarr"
    shutil.copytree(clean, store)
    damage(store, "alpha", "delete")
    assert status("sweep", spec, "--out", tmp_path / "r.nc", "--batch-size", BATCH, "--no-progress", "--no-plot") == 0
    cap = capsys.readouterr()
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    said = [ln for ln in lines if "alpha" in ln and "lower bounds" not in ln]  # the store's, not the result's
    assert len(said) == 1 and said[0].startswith("warning: ") and "alpha/c/0 is missing" in said[0], cap.err
    assert "StoreWarning" not in cap.err and "warnings.warn" not in cap.err and "sink = " not in cap.err
    wrote = [ln for ln in cap.out.splitlines() if ln.startswith("wrote ")]
    assert len(wrote) == 1 and wrote[0].rstrip().endswith(")") and "engine " in wrote[0], cap.out
    assert len(wrote[0]) > 80  # the temporary folder's path makes it long: it would have been cut
    table = [ln for ln in cap.out.splitlines() if ln.strip().startswith(("0.1 ", "0.12 "))]
    assert len(table) == 2 and all(ln.count("±") == 2 for ln in table), cap.out
    assert_same(open_result(tmp_path / "r.nc"), ref)


def test_a_viewer_checks_each_unchanged_chunk_file_once_and_a_changed_one_again(made, tmp_path, monkeypatch):
    """``stabjax view`` refreshes a running store every few seconds: with the cache ``verified`` each chunk
    file is decoded and checksummed once while it stays the same file, so a refresh reads the store once, not
    twice. A chunk file damaged after it was checked (a new modification time) is checked again and
    refused, naming it."""
    _, clean, _ = made["interrupted"]
    store = tmp_path / "i.nc.zarr"
    shutil.copytree(clean, store)
    calls = []
    real = S.checksum
    monkeypatch.setattr(S, "checksum", lambda b: calls.append(1) or real(b))
    verified: dict = {}
    first = show_result(store, verified=verified)
    n_first = len(calls)
    files = {k for k, _ in verified}
    assert {"outcome", "feat_mean"} <= files and len(verified) == len(files)  # one chunk finished: one file each
    del calls[:]
    again = show_result(store, verified=verified)
    assert len(calls) == n_first - len(verified)  # only the whole-array checks of the static arrays remain
    assert_same(again, first)
    damage(store, "feat_mean", "flip")
    with pytest.raises(ValidationError, match="feat_mean"):
        show_result(store, verified=verified)
