import os

os.environ.setdefault("MPLBACKEND", "Agg")


def _compilation_cache() -> str | None:
    """One JAX persistent compilation cache for the whole test run, shared by pytest-xdist's workers and the
    command lines the tests start (both inherit it through the environment from the process that made it):
    many tests build the same compiled loop (the same model, batch and settings) in new plans, and XLA would
    compile the same program again for each. A fresh directory per run, removed when the run ends (nothing is
    reused from another checkout or another JAX); a cache the user set is used as it is and left alone."""
    import tempfile

    if "JAX_COMPILATION_CACHE_DIR" in os.environ:
        return None
    d = tempfile.mkdtemp(prefix="stabjax-tests-jax-cache-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = d
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
    return d


_OWN_CACHE = _compilation_cache()


def pytest_unconfigure(config):
    if _OWN_CACHE is not None:
        import shutil

        shutil.rmtree(_OWN_CACHE, ignore_errors=True)

import stabjax  # noqa: E402

stabjax.setup_jax()  # float64, EQX_ON_ERROR=nan, one CPU device per core: before any test builds arrays


# in CI ($CI set) a test skipped for a missing tool (C compiler, Chromium, a test-extra package) fails instead
from ci_tools import pytest_make_collect_report, pytest_runtest_makereport  # noqa: E402,F401
