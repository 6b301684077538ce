"""Error types. Every user-facing error names the offending field (or file).

Exit statuses (the command line, :func:`stabjax.app.cli.main`): 0 every trajectory has an outcome; 1 a run
that finished with failures (failed trajectories, a solver failure, a write that failed, e.g. a
full disk); 2 bad input or a refused command; 128 + N interrupted by signal N (130 Ctrl-C,
143 SIGTERM, 129 SIGHUP).
"""


class StabjaxError(Exception):
    """Base class for errors reported to the user with a non-zero exit (``exit_code``, default 2)."""

    exit_code = 2


class ValidationError(StabjaxError, ValueError):
    """Bad input: carries the name of the field (parameter, spec key, option, file) at fault."""

    def __init__(self, field: str, message: str):
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}")


class OutputError(StabjaxError, OSError):
    """An output file could not be written (full disk, no permission): exit 1.

    Raised instead of the writer's own exception (netCDF's ``RuntimeError: NetCDF: HDF error``,
    matplotlib's ``OSError``) so that the user reads which file failed and why, not a traceback;
    an ``OSError`` so that callers that keep finished work on an I/O failure (the sweep keeps its
    chunk store) catch it like any other.
    """

    exit_code = 1

    def __init__(self, path, reason: str, hint: str = ""):
        self.path, self.reason, self.hint = str(path), reason, hint
        self.field = self.path
        Exception.__init__(self, f"{path}: could not write it ({reason})" + (f"; {hint}" if hint else ""))

    def __str__(self) -> str:
        return self.args[0]


class Interrupted(KeyboardInterrupt):
    """SIGTERM or SIGHUP, handled like Ctrl-C (a ``KeyboardInterrupt``, so every cleanup path that keeps
    finished chunks on Ctrl-C keeps them here too); ``status`` is the exit status, 128 + signal."""

    def __init__(self, signum: int):
        import signal

        self.signum = int(signum)
        self.status = 128 + self.signum
        try:
            self.name = signal.Signals(self.signum).name
        except ValueError:
            self.name = f"signal {self.signum}"
        super().__init__(self.name)
