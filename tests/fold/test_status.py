"""The solver status codes and their consequences (stabjax.fold.status): the one definition every engine and
every reader uses."""
import numpy as np

from stabjax.fold import status
from stabjax.fold import verdict as V


def test_every_reader_uses_the_one_definition():
    """No module defines a status code of its own: and no source file outside stabjax/fold/status.py assigns ``STATUS_* =`` (the escape code was once 100 in two files)."""
    import re
    from pathlib import Path

    import stabjax

    root = Path(stabjax.__file__).parent
    assign = re.compile(r"^\s*(STATUS_[A-Z_]+|OK|MAX_STEPS|ESCAPED)\s*=\s*\d", re.M)
    owners = sorted(str(p.relative_to(root)) for p in root.rglob("*.py") if assign.search(p.read_text()))
    assert owners == ["fold/status.py"]


def test_escape_is_diverged_for_verdicts_and_the_escape_outcome_for_outcomes():
    st = np.array([status.OK, status.ESCAPED, status.MAX_STEPS, 7])  # 7: another diffrax failure
    v = np.array([[V.CONVERGED, V.CONVERGED], [V.UNDECIDED, V.FAILED], [V.CONVERGED, V.FAILED],
                  [V.FAILED, V.FAILED]], np.int8)
    got = status.verdicts(st, v)
    assert got.dtype == np.int8
    np.testing.assert_array_equal(got, [[0, 0], [V.DIVERGED, V.DIVERGED], [0, V.FAILED], [V.FAILED, V.FAILED]])
    np.testing.assert_array_equal(status.verdicts(st, v[:, -1]), [0, V.DIVERGED, V.FAILED, V.FAILED])
    code = np.array([3, 3, 3, 3])
    np.testing.assert_array_equal(status.outcomes(st, code, escape=5, failed=9), [3, 5, 9, 9])
    np.testing.assert_array_equal(status.outcomes(st, code, escape=None, failed=9), [3, 9, 9, 9])
