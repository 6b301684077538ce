"""The version and the help text come without the numerical stack (issue 32: `stabjax --version` took ~3 s,
importing JAX, NumPy, matplotlib and Dask's array module at import time). A fresh interpreter asks the CLI for
each and lists what it imported."""
import subprocess
import sys

import pytest

HEAVY = ("jax", "numpy", "matplotlib", "xarray", "dask", "scipy", "zarr")


@pytest.mark.parametrize("args", [["--version"], ["--help"], ["sweep", "--help"], []])
def test_version_and_help_import_nothing_numerical(args):
    code = ("import sys\nfrom stabjax.app import cli\ntry:\n    cli.main(%r)\nexcept SystemExit:\n    pass\n"
            "print('HEAVY', sorted(m for m in %r if m in sys.modules))" % (args, HEAVY))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "HEAVY []", out
