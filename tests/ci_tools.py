"""In CI a missing tool fails the run (issue 29): the hooks tests/conftest.py takes in.

Where a tool the suite needs is missing (the native engine's C compiler, the browser test's Chromium, a package
of the test extra), its tests skip on a developer's machine, saying why. In CI (``$CI`` set, as every CI service
sets it) such a skip is a failure: a green run must mean that every test ran. A module of its own (not the
conftest) so that tests/app/test_ci.py can load it alone into a probe run (``-p ci_tools``).
"""
import os

import pytest

MISSING_TOOL = ("no working C compiler", "no Chromium found", "could not import", "pip install")


def _missing_tool(report) -> str | None:
    if not os.environ.get("CI") or not report.skipped or getattr(report, "wasxfail", None) is not None:
        return None
    reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr or "")
    return reason if any(m in reason for m in MISSING_TOOL) else None


def _fail(report, reason: str) -> None:
    report.outcome = "failed"
    report.longrepr = (f"CI is set and a tool the tests need is missing, so this fails instead of skipping: {reason}. "
                       "Install it (.ci/run installs Chromium with apt; the C compiler is the system's cc/gcc)")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    report = (yield).get_result()
    reason = _missing_tool(report)
    if reason is not None:
        _fail(report, reason)


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    report = (yield).get_result()  # a module that skips itself at import (pytest.importorskip)
    reason = _missing_tool(report)
    if reason is not None:
        _fail(report, reason)
