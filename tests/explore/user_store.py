"""A check the refinement's and the shock search's tests share: their round stores under ``--store``."""
from __future__ import annotations


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
