"""Importing the plotting modules leaves matplotlib's backend to the user (Jupyter keeps inline figures);
only the CLI, which writes figures to files, picks the non-interactive Agg backend."""
import os
import subprocess
import sys

import pytest


def test_importing_the_plotting_modules_keeps_the_configured_backend():
    """With MPLBACKEND=svg (a non-default backend that needs no display), importing every module that draws
    leaves ``matplotlib.get_backend()`` at svg. Fails if any of them calls ``matplotlib.use`` on import."""
    code = ("import matplotlib; before = matplotlib.get_backend()\n"
            "import stabjax.present.maps, stabjax.present.basins, stabjax.explore.refine, stabjax.reproduce.at2019, "
            "stabjax.reproduce.saakyan, stabjax.reproduce.twobody, stabjax.reproduce.gyrodyne\n"
            "print(before, matplotlib.get_backend())")
    env = {**os.environ, "MPLBACKEND": "svg"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["svg", "svg"]


def test_the_cli_chooses_agg(monkeypatch):
    """The CLI never shows a window: whatever the environment configures, it draws with Agg."""
    import matplotlib

    from stabjax.app.cli import main

    matplotlib.use("svg")
    try:
        with pytest.raises(SystemExit) as exc:
            main(["systems", "--bogus-option"])  # a usage error: the backend is chosen before parsing
        assert exc.value.code == 2
        assert matplotlib.get_backend().lower() == "agg"
    finally:
        matplotlib.use("Agg")
