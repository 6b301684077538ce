"""Command-line interface: ``stabjax systems | simulate | theory | sweep | export | plot | report | view |
horizon-check | reproduce | bench | examples`` (and ``stabjax --version``).

Every user error (:class:`stabjax.errors.StabjaxError`) is printed as ``error: <field>: <message>``
and exits with status 2 (a failed write of the chunk store or the output, e.g. a full disk: status 1);
finished sweep chunks are kept on disk, so the same command resumes. Exit statuses: 0 every trajectory
classified, 1 some failed (or a write failed), 2 usage or input error, 128 + N interrupted by signal N
(130 Ctrl-C, 143 SIGTERM, 129 SIGHUP). Text that is not ours (messages, names, paths, docs) is printed
without Rich markup, so brackets such as ``[refine]`` or ``grid.J[0]`` survive.

The commands live beside this module, one module per group (:mod:`.model_cmds`, :mod:`.sweep_cmds`,
:mod:`.result_cmds`, :mod:`.paper_cmds`), with the checks they share in :mod:`.common`; this module holds the app,
the exit statuses and the one entry point. What a command may write over (inputs, stores, reproductions, atomic
maps) is :mod:`stabjax.run.outputs`.
"""
from __future__ import annotations

import sys

import typer
from rich.markup import escape

from . import model_cmds, paper_cmds, result_cmds, sweep_cmds
from .common import console, err_console

HELP = ("stabjax: batch stability explorer. Sweeps an ODE model (the four built-in papers' or your own) over "
        "parameters and starts, gives every trajectory an outcome, and maps basins against theorems' bounds.")

# rich_markup_mode=None: the help is plain text, so "[refine]" in a docstring is shown, not eaten as a tag
app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False, rich_markup_mode=None,
                  help=HELP)
for _name, _fn in (("systems", model_cmds.systems), ("simulate", model_cmds.simulate), ("theory", model_cmds.theory),
                   ("sweep", sweep_cmds.sweep), ("export", sweep_cmds.export), ("plot", result_cmds.plot_cmd),
                   ("report", result_cmds.report_cmd), ("view", result_cmds.view_cmd),
                   ("horizon-check", result_cmds.horizon_check_cmd), ("reproduce", paper_cmds.reproduce),
                   ("bench", paper_cmds.bench), ("examples", paper_cmds.examples_cmd)):
    app.command(_name)(_fn)


def _version_callback(value: bool):
    if value:
        from ..version import __version__

        console.print(f"stabjax {__version__}", highlight=False)
        raise typer.Exit(0)


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_version_callback, is_eager=True,
                                       help="print the version and exit")):
    """stabjax: batch stability explorer."""


def _click_exception() -> type[Exception]:
    """click's ClickException, from whichever click typer runs on (typer 0.29 vendors it as ``typer._click``
    and no longer installs ``click``): found through the public ``typer.BadParameter``."""
    return next((c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException"), typer.BadParameter)


def _interrupt_status(exc: BaseException) -> tuple[int, str]:
    """(exit status, what) of an interruption: 128 + the signal (SIGTERM 143, SIGHUP 129), Ctrl-C 130.
    click turns a KeyboardInterrupt into ``Abort``: the signal is found on the exception's chain."""
    from ..run import signals

    sig = signals.last_raised()
    if sig is not None:
        return sig.status, f" by {sig.name}"
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if hasattr(exc, "status") and hasattr(exc, "name"):
            return exc.status, f" by {exc.name}"
        exc = exc.__cause__ or exc.__context__
    return 130, ""


def _error(message: str) -> None:
    """``error: <message>`` on one line of stderr; the message is never read as Rich markup."""
    err_console.print("[bold red]error:[/bold red] " + escape(message), highlight=False)


# the Python API's names of what a command line gives as an option: the user reads the option they typed
_OPTION_NAMES = {"batch_size": "--batch-size", "ts": "--ts", "simulate.t1": "--t1", "simulate.t0": "--t0",
                 "simulate.rtol": "--rtol", "simulate.atol": "--atol", "simulate.solver": "--solver"}


def _as_option(exc, args: list[str]) -> str:
    """The error's text, its field named as the command-line option the user gave, where they gave one."""
    from ..errors import ValidationError

    option = _OPTION_NAMES.get(getattr(exc, "field", None)) if isinstance(exc, ValidationError) else None
    if option is not None and any(a == option or a.startswith(option + "=") for a in args):
        return f"{option}: {exc.message}"
    return str(exc)


def _answers_without_running(args: list[str]) -> bool:
    """Whether the command line only asks for the version or a help text (typer answers those before any
    command runs), or for nothing (the help): then neither JAX nor any numerical module is imported."""
    return not args or any(a in ("--version", "--help", "-h") for a in args)


def main(argv: list[str] | None = None):
    """Entry point: runs the app and turns every outcome into an exit status that tells the truth.

    0 success (a sweep: every trajectory has an outcome); 1 a run that failed (failed trajectories, a
    solver failure reported by ``simulate``, an I/O error such as a full disk); 2 bad input (a usage
    error -- unknown option or command, extra argument, a value of the wrong type -- printed with the
    usage, or a :class:`~stabjax.errors.StabjaxError` naming the field, an environment variable
    included); 128 + N interrupted by signal N: 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP (both handled like
    Ctrl-C, :mod:`stabjax.run.signals`).
    """
    import os

    from ..run import signals
    from ..errors import StabjaxError

    # the CLI only writes figures to files: a non-interactive backend, chosen here and not on import of the
    # plotting modules (a user importing stabjax.present.maps in Jupyter keeps inline figures); through the
    # environment, so that matplotlib is imported only by a command that draws (issue 32: --help in < 0.5 s)
    if "matplotlib" in sys.modules:
        sys.modules["matplotlib"].use("Agg")
    else:
        os.environ["MPLBACKEND"] = "Agg"
    previous = signals.install()
    click_exception = _click_exception()
    args = sys.argv[1:] if argv is None else list(argv)
    try:
        if not _answers_without_running(args):  # the version or a help text: no NumPy, no JAX (< 0.5 s)
            from ..config import setup_jax

            setup_jax()  # validates the environment (a bad variable is an error naming it, not a traceback),
            # then JAX's global options, before any command computes
        # standalone_mode=False: errors come back to this function instead of exiting inside typer;
        # typer then *returns* the status of a ``typer.Exit`` (and 130 for Ctrl-C) instead of raising it
        rv = app(args=argv, standalone_mode=False)
    except StabjaxError as exc:
        _error(_as_option(exc, args))
        sys.exit(getattr(exc, "exit_code", 2))  # 2: bad input / refused; 1: I/O failure (store.StoreIOError)
    except KeyboardInterrupt as exc:
        status, by = _interrupt_status(exc)
        err_console.print(f"interrupted{by}", style="yellow", markup=False)
        sys.exit(status)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort as exc:  # Ctrl-C (or a signal) in typer's hands, or end of input at a prompt
        status, by = _interrupt_status(exc)
        err_console.print(f"interrupted{by}" if by else "aborted", style="yellow", markup=False)
        sys.exit(status)
    except click_exception as exc:  # usage errors: the usage line, the error, status 2
        exc.show()
        sys.exit(exc.exit_code)
    except OSError as exc:  # a file we could not read or write (a full disk, no permission): status 1
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        _error(f"{where}{exc.strerror or exc}")
        sys.exit(1)
    finally:
        signals.restore(previous)
    if isinstance(rv, int) and not isinstance(rv, bool) and rv != 0:
        # typer returns 130 for any KeyboardInterrupt a command did not handle: a SIGTERM/SIGHUP gets its own
        # status back here (the sweep handles its interruptions itself and returns 128 + signal)
        sig = signals.last_raised() if rv == 130 else None
        if sig is not None:
            err_console.print(f"interrupted by {sig.name}", style="yellow", markup=False)
        sys.exit(sig.status if sig is not None else rv)


if __name__ == "__main__":
    main()
