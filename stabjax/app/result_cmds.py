"""``stabjax plot | report | view | horizon-check``: what a finished result (or a running store) shows."""
from __future__ import annotations

import errno
import json
from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ..run.outputs import input_files, write_image
from .common import ForceOpt, IMAGE_SUFFIXES, check_output, console, err_console, jsonable, open_result_file, warn_changed_model


def _default_out(file: Path, suffix: str) -> Path:
    """FILE with another extension; for a store ``R.nc.zarr``, that of the result file it is written to."""
    from ..present.kit import finished_file

    return (finished_file(file) if file.is_dir() and finished_file(file) else file).with_suffix(suffix)


def _ours(ds, file: Path):
    """Whether an existing output is a figure or page of ours showing this result (its stamp, not its name)."""
    from ..run.outputs import is_own_output, spec_digest_of

    spec = spec_digest_of(ds)
    return lambda p: is_own_output(p, file, spec=spec)


def plot_cmd(
    file: Path = typer.Argument(..., help="a result (netCDF, or a finished sweep's store): a sweep, an example's "
                                          "basin result, a discovery or a refinement"),
    out: Optional[Path] = typer.Option(None, help="PNG, PDF or SVG (default: FILE with the --format extension)"),
    fmt: Optional[str] = typer.Option(None, "--format", help="png | svg | pdf: vector output (svg, pdf) for a paper, "
                                                            "beside the PNG (default: from --out, else png)"),
    force: bool = ForceOpt,
):
    """Draw any result and print its summary: a verdict map with the theoretical boundary and its counts, named
    outcomes or discovered attractors with basin fractions (along an axis, per cell), or a refinement's points
    and bracketed boundary. An existing image is replaced only when it is a figure stabjax drew of this result
    (or of one of the same spec), else with --force."""
    if fmt is not None:
        from ..errors import ValidationError

        if fmt.lower().lstrip(".") not in ("png", "svg", "pdf"):
            raise ValidationError("--format", f"choose png, svg or pdf; got {fmt!r}")
        fmt = fmt.lower().lstrip(".")
        if out is not None and out.suffix.lower() != f".{fmt}":
            raise ValidationError("--format", f"--out {out} does not end in .{fmt}")
        out = out or _default_out(file, f".{fmt}")
    ds = open_result_file(file)
    warn_changed_model(ds)
    out = out or _default_out(file, ".png")
    # a figure of ours of this result (its stamp says so) is replaced when drawn again; any other file needs --force
    replacing = check_output(out, "--out", IMAGE_SUFFIXES, inputs=input_files(file), force=force,
                              same=_ours(ds, file), what=f"a figure stabjax drew of {file} (or of a result of its spec)")
    print_result(ds, out, replaced=replacing, result=file)


def report_cmd(
    file: Path = typer.Argument(..., help="a result (netCDF, or a finished sweep's store): a sweep, an example's "
                                          "basin result, a discovery or a refinement"),
    out: Optional[Path] = typer.Option(None, help="HTML page to write (default: FILE with .html)"),
    force: bool = ForceOpt,
):
    """Write one self-contained HTML page of a result: what was run, outcomes with S ± SE and Wilson
    intervals, figures, the theory's agreement and the warnings (for a lab notebook). An existing page is
    replaced only when it is a report stabjax wrote of this result (or of one of the same spec), else with --force."""
    from ..present.report import write_report

    ds = open_result_file(file)
    out = out or _default_out(file, ".html")
    replacing = check_output(out, "--out", (".html",), inputs=input_files(file), force=force,
                              same=_ours(ds, file), what=f"a report stabjax wrote of {file} (or of a result of its spec)")
    write_report(ds, out, source=str(file), force=True)  # --out checked above, with --force
    console.print(f"wrote {out}" + (" (replaced the previous file)" if replacing else ""), markup=False,
                  soft_wrap=True)


def view_cmd(
    result: Path = typer.Argument(..., help="a result (netCDF), or a running sweep's chunk store (RESULT.nc.zarr)"),
    port: int = typer.Option(0, help="port on 127.0.0.1 (default: a free one)"),
    browser: bool = typer.Option(True, "--browser/--no-browser", help="open the page in the default browser"),
    quit_after: Optional[float] = typer.Option(None, "--quit-after", help="stop the server after this many seconds "
                                                                          "(scripts, tests)"),
):
    """Explore a result in the browser: its map, a click re-simulates that trajectory (time series with the late
    window, phase portrait, why it got its outcome), feature space, fractions with Wilson bands. Serves on
    127.0.0.1 only; a running sweep's store refreshes as chunks land, and the page turns to the result file
    when its sweep finishes. Needs: pip install 'stabjax[view]'."""
    from .. import validate
    from ..present.view import serve

    validate.integer(port, "--port", lo=0, hi=65535)
    if quit_after is not None:
        validate.number(quit_after, "--quit-after", lo=0.0, lo_open=True)
    if port:
        _check_port(port)  # before the result is read and the server built: a usage error, exit 2
    try:
        serve(result, port=port, show=browser, quit_after=quit_after,
              announce=lambda text: console.print(text, markup=False, highlight=False, soft_wrap=True))
    except OSError as exc:
        if port and exc.errno in (errno.EADDRINUSE, errno.EACCES):  # taken between the check and the server
            raise _port_error(port, exc) from None
        raise
    except KeyboardInterrupt as exc:  # Ctrl-C (130), SIGTERM (143), SIGHUP (129): the README's exit statuses
        status = getattr(exc, "status", 130)
        by = f" by {exc.name}" if hasattr(exc, "name") else ""
        err_console.print(f"stopped{by}: the viewer is closed", style="yellow", markup=False)
        raise typer.Exit(status)


def _check_port(port: int) -> None:
    """Refuse a ``--port`` that the server could not listen on (another program holds it; a privileged
    port) with the option named. The socket is bound as the server binds its own (SO_REUSEADDR), so a
    port in TIME_WAIT after an earlier viewer is not refused."""
    import socket

    from ..present.view import LOOPBACK

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((LOOPBACK, port))
        except OSError as exc:
            raise _port_error(port, exc) from None


def _port_error(port: int, exc: OSError):
    from ..errors import ValidationError

    why = "is in use by another program" if exc.errno == errno.EADDRINUSE else f"cannot be used ({exc.strerror or exc})"
    return ValidationError("--port", f"port {port} on 127.0.0.1 {why}; choose another --port, or leave it out "
                                     "for a free one")


def horizon_check_cmd(
    file: Path = typer.Argument(..., help="sweep result (netCDF)"),
    factor: float = typer.Option(4.0, help="re-run with t1 * factor (1: the same horizon)"),
    n: int = typer.Option(64, help="number of trajectories re-run"),
    seed: int = typer.Option(0),
    tighten: float = typer.Option(1.0, help="re-run with rtol and atol divided by this (10: a tenfold tighter "
                                            "tolerance)"),
    as_json: bool = typer.Option(False, "--json"),
):
    """Re-run a random subset at a longer horizon, or a tighter tolerance, and report how many verdicts change.

    The sweep's dataset already holds the verdicts at t1 and the decades below it (dimension 'horizon',
    from the same runs; shown first); this extends a subset beyond t1 in one run per trajectory. With
    --factor 1 --tighten 10 it checks the tolerance instead: a verdict that changes was decided by the
    solver's error."""
    from .. import validate
    from ..fold import verdict as V
    from ..run.horizon import horizon_check

    validate.number(factor, "--factor", lo=1.0)
    validate.number(tighten, "--tighten", lo=1.0)
    if factor == 1 and tighten == 1:
        from ..errors import ValidationError

        raise ValidationError("--factor", "give a longer horizon (--factor > 1), a tighter tolerance (--tighten > 1) "
                                          "or both: with neither the re-run is the sweep's own")
    validate.integer(n, "--n", lo=1)
    validate.integer(seed, "--seed", lo=0)
    ds = open_result_file(file)
    if "verdict" not in ds:
        from ..errors import ValidationError

        raise ValidationError("file", f"{file} holds named outcomes, not attitude verdicts: horizon-check compares "
                                      "verdicts (rerun the sweep with a longer --t1 to compare outcomes)")
    if "horizon" in ds.dims and not as_json:
        for j, T in enumerate(ds["horizon"].values):
            c = V.counts(ds["verdict"].isel(horizon=j).values)
            console.print(f"dataset, T = {T:<9.3g}" + " ".join(f"{k[:4]} {v:<6d}" for k, v in c.items()))
    hc = horizon_check(ds, factor=factor, n=n, seed=seed, tighten=tighten)
    if as_json:
        keys = ("n_checked", "n_changed", "t1_short", "t1_long", "rtol_short", "rtol_long", "atol_short", "atol_long")
        console.print_json(json.dumps(jsonable({**{k: hc.attrs[k] for k in keys},
                                                  "transition": hc["transition"].values})))
        return
    a = hc.attrs

    def run_of(which: str) -> str:
        return f"t1 = {a['t1_' + which]:g}" + (f", rtol = {a['rtol_' + which]:g}" if tighten != 1 else "")

    t = Table(title=f"verdicts at {run_of('short')} (rows) vs {run_of('long')} (columns)")
    t.add_column("")
    for name in V.NAMES:
        t.add_column(name)
    for i, name in enumerate(V.NAMES):
        t.add_row(name, *[str(int(x)) for x in hc["transition"].values[i]])
    console.print(t)
    console.print(f"{hc.attrs['n_changed']} of {hc.attrs['n_checked']} verdicts changed")


def print_result(ds, png: Optional[Path], replaced: bool = False, result: Optional[Path] = None):
    """The CLI summary and figure of a result of any kind (:func:`stabjax.present.show.summary`, ``plot``).

    The figure is drawn into a temporary file beside ``png`` and renamed over it, so a full disk leaves the
    previous one (or nothing), never half an image, and is reported in one line (exit 1) with the way
    to draw it again; ``result``: the file the figure is drawn from, for that message and the figure's stamp."""
    from ..present.show import plot, summary

    console.print(summary(ds), highlight=False, markup=False, soft_wrap=True)
    if png is None:
        return
    from ..run.outputs import spec_digest_of

    write_image(png, lambda tmp: plot(ds, tmp, stamp=False, force=True), result, spec=spec_digest_of(ds))  # png checked by the command
    console.print(f"wrote {png}" + (" (replaced the previous file)" if replaced else ""), markup=False)
