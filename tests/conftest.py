import os

os.environ.setdefault("MPLBACKEND", "Agg")

import stabjax  # noqa: E402

stabjax.setup_jax()  # float64, EQX_ON_ERROR=nan, one CPU device per core: before any test builds arrays


# in CI ($CI set) a test skipped for a missing tool (C compiler, Chromium, a test-extra package) fails instead
from ci_tools import pytest_make_collect_report, pytest_runtest_makereport  # noqa: E402,F401
