import os

os.environ.setdefault("MPLBACKEND", "Agg")

import stabjax  # noqa: E402

stabjax.setup_jax()  # float64, EQX_ON_ERROR=nan, one CPU device per core: before any test builds arrays


def kill_after_chunks(proc, store, n: int, timeout: float) -> None:
    """SIGKILL ``proc`` (a sweep writing ``store``) once ``n`` chunks are finished; fail after ``timeout`` s."""
    import signal
    import time

    import pytest

    from stabjax.run import store as S

    try:
        deadline = time.time() + timeout
        while time.time() < deadline:
            try:
                if len(S.read_manifest(store)["chunks"]) >= n:
                    break
            except (TypeError, S.StoreError):  # no manifest yet
                pass
            time.sleep(0.05)
        else:
            pytest.fail(f"fewer than {n} chunks finished in {timeout:g} s")
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(30)


# in CI ($CI set) a test skipped for a missing tool (C compiler, Chromium, a test-extra package) fails instead
from ci_tools import pytest_make_collect_report, pytest_runtest_makereport  # noqa: E402,F401
