"""A fresh reliability pass (issue 22's closing line): what a careful but unlucky user tried that still
lost work or a file, or ended with a misleading status. Each test asserts the exit status, a one-line
message naming the field or file, and that every file present before the command is byte-identical."""
from __future__ import annotations

from pathlib import Path

from test_safety import TINY, clean, cli, files, spec_file


def test_store_equal_to_out_or_its_map_is_refused_before_the_run(tmp_path, capsys, monkeypatch):
    # --store r.nc --out r.nc: the store was made and filled, then the result could not be written
    # over it, and the message suggested `stabjax export r.nc --out r.nc`
    monkeypatch.chdir(tmp_path)
    spec = spec_file(tmp_path)
    before = files(tmp_path)
    for store in ("r.nc", "r.png", "./sub/../r.nc"):
        code, out, err = cli(capsys, "sweep", spec, "--out", "r.nc", "--store", store)
        clean(out, err)
        assert code == 2, (store, err)
        assert "--store" in err and ("r.nc" in err or "r.png" in err), err
        assert files(tmp_path) == before
        assert not (tmp_path / "r.nc").exists() and not (tmp_path / "r.png").exists()
