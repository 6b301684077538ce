"""A check the refinement's and the shock search's tests share: their round stores under ``--store``."""
from __future__ import annotations

import pytest

from stabjax.errors import StabjaxError


def check_user_store_folder_kept(run, tmp_path) -> None:
    """``run(out, **kw)`` (a refinement or a shock search) with ``store`` naming a folder that holds a user's file:
    the rounds' stores are removed once the result is written, with ``restart`` too, and the user's file and
    folder stay; without ``store`` the default ``<out>.zarr`` is the run's own and is removed."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("my notes")
    for restart in (False, True):
        run(tmp_path / f"a{restart}.nc", store=mine, restart=restart)
        assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    run(tmp_path / "b.nc")
    assert not (tmp_path / "b.nc.zarr").exists()


def check_said_once_the_store_accepts(run, tmp_path) -> None:
    """``on_open`` (the CLI's "OUT exists: it will be replaced") is called once per run, however many rounds it
    has, and not at all when the first round's store refuses the run (before the fix the CLI said it first)."""
    out, store, said = tmp_path / "said.nc", tmp_path / "said.zarr", []
    run(out, store=store, keep_store=True, on_open=lambda: said.append("first"))
    assert said == ["first"] and len(list(store.iterdir())) > 1  # several rounds, said once
    (store / "round_0000" / "manifest.json").write_text('{"format": "stabjax-sto')
    with pytest.raises(StabjaxError, match="manifest.json is unreadable"):
        run(out, store=store, on_open=lambda: said.append("refused"))
    assert said == ["first"]
    run(out, store=store, restart=True, on_open=lambda: said.append("restart"))
    assert said == ["first", "restart"]
