"""Running the command line in-process, for the tests (one definition; tests import it like references.py)."""
from __future__ import annotations

from stabjax.app.cli import main

# a sweep of two trajectories of a built-in model, for tests of what the command line refuses or writes
TINY = """system = "monoaxial"
name = "tiny"
[grid]
alpha = [0.5, 0.7]
[integrate]
t1 = 50.0
n_checkpoints = 16
"""


def status(*args) -> int:
    """The exit status of ``stabjax ARGS`` (0 when it returns normally)."""
    try:
        main([str(a) for a in args])
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    return 0


def captured(capsys, *args) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of ``stabjax ARGS``, with rich's line wrapping undone."""
    code = status(*args)
    cap = capsys.readouterr()
    return code, " ".join(cap.out.split()), " ".join(cap.err.split())
