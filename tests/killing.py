"""Killing a sweep mid-run, for the resume tests (a plain module: a name imported from ``conftest``
resolves to whichever conftest.py pytest imported first)."""

import os


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
