"""``stabjax sweep | export``: run a spec (or a refinement) into a dataset, the summary printed after it, the exit
status it deserves; write the netCDF file of a finished chunk store."""
from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Optional

import typer

from ..run.outputs import check_store_path, input_files, is_own_output
from .result_cmds import print_result
from .common import ForceOpt, IMAGE_SUFFIXES, RESULT_SUFFIXES, check_output, result_spec, console, err_console


def sweep(
    spec: Path = typer.Argument(..., help="sweep spec (TOML), e.g. sweeps/at2019_alpha_sigma.toml"),
    out: Optional[Path] = typer.Option(None, help="netCDF output (default results/<name>.nc)"),
    batch_size: Optional[int] = typer.Option(None, "--batch-size", help="trajectories per compiled chunk"),
    t1: Optional[float] = typer.Option(None, help="override [integrate].t1"),
    plot: bool = typer.Option(True, "--plot/--no-plot", help="also write <out>.png"),
    restart: bool = typer.Option(False, help="discard the finished chunks of an earlier run of this output"),
    progress: bool = typer.Option(True, "--progress/--no-progress"),
    store: Optional[Path] = typer.Option(None, help="chunk store (zarr directory; default <out>.zarr)"),
    keep_store: bool = typer.Option(False, "--keep-store", help="keep the chunk store after writing <out>"),
    scheduler: Optional[str] = typer.Option(None, help="run the chunks on an existing Dask scheduler "
                                            "(tcp://HOST:8786 or a scheduler file)"),
    workers: Optional[int] = typer.Option(None, help="run the chunks on a local Dask cluster of N worker processes"),
    threads: Optional[int] = typer.Option(None, help="engine threads per Dask worker "
                                          "(default: cores // workers locally)"),
    oversubscribe: bool = typer.Option(False, "--oversubscribe", help="allow workers x threads > cores "
                                       "(or more local workers than GPUs)"),
    connect_timeout: float = typer.Option(10.0, "--connect-timeout", help="seconds to wait for the Dask scheduler "
                                          "(--scheduler) before giving up with an error"),
    force: bool = ForceOpt,
):
    """Run a sweep spec: integrate, classify, evaluate the theory, write a labelled dataset.

    A spec with a [refine] section brackets the boundary between outcomes adaptively instead; one with a
    [shock] section searches the minimal fatal shock of its start at every grid point.
    Exit status: 0 every trajectory has an outcome (a share of unclassified or undecided ones over 5 % is
    warned about), 1 some failed (the result is written and says which),
    2 bad input, 130/143/129 interrupted (finished chunks kept: the same command resumes)."""
    from .. import validate
    from ..errors import ValidationError
    from ..plan.identity import spec_digest
    from ..plan.spec import load_spec, make_plan, spec_json
    from ..run.sweep import default_store, run_plan

    if threads is not None and scheduler is None and workers is None:
        raise ValidationError("--threads", "applies to Dask workers: give --workers N or --scheduler ADDRESS "
                              "(a local run uses $STABJAX_THREADS)")
    validate.number(connect_timeout, "--connect-timeout", lo=0.0, lo_open=True, hi=3600.0)
    s = load_spec(spec)
    plan = make_plan(s, t1=t1)  # every field checked before any output path is looked at
    out = out or Path("results") / f"{plan.name}.nc"
    inputs = input_files(spec, plan.starts_file, system=plan.system)  # never written over, even with --force
    this_spec = json.loads(spec_json(plan.spec))
    replacing = check_output(out, "--out", RESULT_SUFFIXES, inputs=inputs, force=force,
                              same=lambda p: result_spec(p) == this_spec,
                              what="a result of this spec (with this --t1)")
    if plot:  # the map is replaced when its content says it is the map of this spec, else only with --force
        # (replacing the result does not make the image beside it ours: a user's own file of that name stays)
        png = out.with_suffix(".png")
        check_output(png, "--out", IMAGE_SUFFIXES, inputs=inputs, force=force,
                      same=lambda p: is_own_output(p, spec=spec_digest(this_spec)),
                      what="the map of a previous result of this spec")
    store = store or default_store(out)
    check_store_path(store, inputs, outputs=(out, out.with_suffix(".png") if plot else None))

    def say_replacing():
        if replacing:
            why = "" if force else " (a previous result of this spec)"
            err_console.print(f"{out} exists: it will be replaced{why}", markup=False)

    note = plan.scheme.decl.default_distance_note() if plan.scheme.decl is not None else ""
    if note:
        err_console.print(f"note: {note}", markup=False)
    executor = None
    stack = contextlib.ExitStack()
    if scheduler is not None or workers is not None:
        import os

        from ..run.distributed import DaskExecutor

        # this process only collects results: keep a GPU's memory for the workers
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
        executor = DaskExecutor(scheduler=scheduler, workers=workers, threads=threads, oversubscribe=oversubscribe,
                                timeout=connect_timeout)
    try:
        if executor is not None:
            _start_executor(executor, scheduler, connect_timeout)
        stack.enter_context(_warnings_in_one_line())
        if "shock" in s:  # minimal fatal shocks at every grid point (stabjax.explore.shock)
            raise typer.Exit(_shock(plan, out, plot, batch_size=batch_size, progress=progress, restart=restart,
                                    store=store, keep_store=keep_store, executor=executor, overrides={"t1": t1},
                                    on_open=say_replacing))
        if "refine" in s:  # adaptive boundary refinement from the [grid] as coarse grid (stabjax.explore.refine)
            raise typer.Exit(_refine(plan, out, plot, batch_size=batch_size, progress=progress, restart=restart,
                                     store=store, keep_store=keep_store, executor=executor, overrides={"t1": t1},
                                     on_open=say_replacing))
        ds = run_plan(plan, out, batch_size=batch_size, progress=progress, restart=restart, store=store,
                      keep_partial=keep_store, executor=executor, overrides={"t1": t1}, on_open=say_replacing,
                      force=True)  # --out checked above, with the spec file and --force
    except KeyboardInterrupt as exc:
        status = getattr(exc, "status", 130)
        by = f" by {exc.name}" if hasattr(exc, "name") else ""
        err_console.print(f"interrupted{by}: finished chunks are kept in {store}; run the same command to resume",
                          style="yellow", markup=False)
        raise typer.Exit(status)
    finally:
        stack.close()
        if executor is not None:
            executor.close()
    console.print(f"wrote {out}  ({ds.attrs['n_trajectories']} trajectories, {ds.attrs['total_steps']:,} steps, "
                  f"{ds.attrs['wall_time_s']:.1f} s, engine {ds.attrs['engine']})", markup=False)
    stops = _stops_line(ds)
    if stops:
        console.print(stops, markup=False)
    print_result(ds, out.with_suffix(".png") if plot else None, result=out)
    _say_undecided(ds)
    status = run_status(ds, out)  # the last line: how many failed, when any did
    if status:
        raise typer.Exit(status)


def _say_undecided(ds) -> None:
    """The report's warnings on 'unclassified' and 'undecided' shares (over 5 %, per grid point), one line each:
    the run exits 0 (every trajectory has an outcome) but its other fractions are lower bounds there."""
    from ..present.report import undecided_warnings

    for w in undecided_warnings(ds):
        err_console.print(f"warning: {w}", style="yellow", markup=False)


@contextlib.contextmanager
def _warnings_in_one_line():
    """A warning of stabjax's while a sweep runs (a store repaired on resume:
    :class:`stabjax.run.store.StoreWarning`) is one line of stderr, ``warning: ...``, not Python's
    ``FILE:LINE: Category: ...`` followed by a line of our source code. Other libraries' warnings are
    shown as Python shows them."""
    import warnings

    import stabjax

    ours = str(Path(stabjax.__file__).resolve().parent)
    previous = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if str(Path(filename).resolve()).startswith(ours):
            err_console.print(f"warning: {message}", style="yellow", markup=False, highlight=False)
        else:
            previous(message, category, filename, lineno, file, line)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = previous


def _refine(plan, out: Path, plot: bool, **run) -> int:
    """``stabjax sweep SPEC`` for a spec with a [refine] section: refine, write ``out`` (and its map), print a
    summary; the exit status. ``run``: the sweep runner's options, as for any sweep."""
    from ..explore.refine import refine_plan
    from ..explore.refine_config import refine_config

    refine_config(plan)  # every field checked before anything is integrated or written
    ds = refine_plan(plan, out, force=True, **run)  # --out checked by the command, with the spec file and --force
    console.print(f"wrote {out}  ({ds.attrs['wall_time_s']:.1f} s)", markup=False)
    print_result(ds, out.with_suffix(".png") if plot else None, result=out)
    return run_status(ds, out)


def _shock(plan, out: Path, plot: bool, **run) -> int:
    """``stabjax sweep SPEC`` for a spec with a [shock] section: search, write ``out`` (and its figure), print the
    summary (red flags with the command replaying their witness); the exit status of :func:`shock_status` (a red
    flag is a finding, not an error; a failed shocked start is a fatal shock, not a failure)."""
    from ..explore.shock import shock_plan
    from ..explore.shock_config import shock_config

    shock_config(plan)  # every field checked before anything is integrated or written
    ds = shock_plan(plan, out, force=True, **run)  # --out checked by the command, with the spec file and --force
    console.print(f"wrote {out}  ({ds.attrs['n_trajectories']:,} trajectories, {ds.attrs['wall_time_s']:.1f} s)",
                  markup=False)
    print_result(ds, out.with_suffix(".png") if plot else None, result=out)
    return shock_status(ds, out)


def shock_status(ds, out: Optional[Path] = None) -> int:
    """The exit status a finished shock search deserves: 0, or 1 (said in one line) when the unshocked start
    failed at some grid point -- the solver did not reach t1, or an observable the outcome reads was not finite --
    so that no attractor was there to shock and no search ran (a shocked start that fails is a fatal shock, a
    finding)."""
    import numpy as np

    if ds is None or "base_outcome" not in ds:
        return 0
    names = str(ds.attrs.get("outcome_names", "")).split()
    if "failed" not in names:
        return 0
    failed = np.asarray(ds["base_outcome"].values).ravel() == names.index("failed")
    if not failed.any():
        return 0
    see = f" (see base_solver_status in {out})" if out is not None else ""
    solver = "the solver did not reach t1" + see
    obs = "it reached t1 but an observable the outcome reads was NaN or infinite"
    if "base_solver_status" in ds:
        stopped = int((failed & (np.asarray(ds["base_solver_status"].values).ravel() != 0)).sum())
        n = int(failed.sum())
        why = (solver if stopped == n else obs if stopped == 0
               else f"{stopped} where {solver}, {n - stopped} where {obs}")
    else:  # a result written before the status was kept
        why = "the solver did not reach t1, or an observable the outcome reads was not finite"
    where = "" if failed.size == 1 else f" at {int(failed.sum())} of {failed.size} grid points"
    err_console.print(f"the unshocked start failed{where}: {why}; no attractor to shock, no search there; "
                      "exit status 1", style="red", markup=False)
    return 1


def _stops_line(ds) -> str:
    """How many trajectories ended before t1 because their fate was decided (stabjax.fold.stops), or ""."""
    if "stop_reason" not in ds:
        return ""
    from ..fold.stops import STOP_ATTRACTOR, STOP_FIXED_POINT

    codes = ds["stop_reason"].values
    parts = [f"{int((codes == c).sum()):,} {what}" for c, what in
             ((STOP_FIXED_POINT, "at a stable fixed point"), (STOP_ATTRACTOR, "near an attractor found earlier"))
             if (codes == c).any()]
    return f"stopped early, fate decided: {', '.join(parts)}" if parts else ""


def _start_executor(executor, scheduler: str | None, timeout: float) -> None:
    """Connect to the Dask scheduler (or start the local cluster) within ``timeout`` seconds; any failure
    is one line naming the option, never a traceback (a port that answers but is not a Dask scheduler
    made distributed allocate exabytes)."""
    from ..errors import StabjaxError, ValidationError

    try:
        executor.start()
    except StabjaxError:
        raise
    except Exception as exc:  # noqa: BLE001 - distributed raises many types for a bad address
        field = "--scheduler" if scheduler is not None else "--workers"
        what = f"cannot reach a Dask scheduler at {scheduler}" if scheduler is not None else "cannot start the local cluster"
        msg = str(exc).splitlines()[0][:200] if str(exc) else ""
        raise ValidationError(field, f"{what} within {timeout:g} s ({type(exc).__name__}{': ' + msg if msg else ''}); "
                                     "check the address, or raise --connect-timeout") from None


def _failed_why(ds, failed, out: Optional[Path] = None) -> str:
    """Why the ``failed`` trajectories failed, in words, and where to look: a failure the solver reported
    and one it did not (it reached t1, but an observable the outcome reads was NaN or infinite) need
    different fixes."""
    import numpy as np

    solver = "the solver did not reach t1" + (f" (see solver_status in {out})" if out is not None else "")
    status = np.asarray(ds["solver_status"].values).ravel() if "solver_status" in ds else None
    if status is None or status.shape != failed.shape or not (failed & (status == 0)).any():
        return solver
    nonfinite = int((failed & (status == 0)).sum())
    obs = ("an observable the outcome reads was NaN or infinite in the late window although the solver reached t1"
           + (f" (see feat_final in {out})" if out is not None else ""))
    if nonfinite == int(failed.sum()):
        return obs
    return f"{int(failed.sum()) - nonfinite} where {solver}, {nonfinite} where {obs}"


def run_status(ds, out: Optional[Path] = None) -> int:
    """The exit status a finished sweep deserves: 0 when every trajectory is classified, 1 (said in one
    line) when some failed (the solver did not reach t1, or an observable the outcome reads was not
    finite), or when named outcomes classified none."""
    import numpy as np

    from ..fold import verdict as V

    if ds is None:
        return 0
    n = int(ds.attrs.get("n_trajectories", 0)) or None
    where = f" (see solver_status in {out})" if out is not None else ""
    if "outcome" in ds and not int(ds.attrs.get("outcomes_from_verdicts", 1)):
        names = str(ds["outcome"].attrs.get("flag_meanings", "")).split()
        codes = np.asarray(ds["outcome"].values).ravel()
        n = n or codes.size
        failed = int((codes == names.index("failed")).sum()) if "failed" in names else 0
        unclassified = int((codes == names.index("unclassified")).sum()) if "unclassified" in names else 0
        if failed:
            why = _failed_why(ds, codes == names.index("failed"), out)
            err_console.print(f"{failed} of {n} trajectories failed: {why}; exit status 1", style="red", markup=False)
            return 1
        if n and unclassified == n:
            why = ("no attractor was found: no min_samples trajectories lie within eps of one another"
                   if "attractor_type" in ds else "no rule holds and no template is near")
            err_console.print(f"no trajectory was classified: all {n} are unclassified ({why}); exit status 1",
                              style="red", markup=False)
            return 1
        return 0
    if "verdict" not in ds:
        return 0
    v = np.asarray(V.at_t1(ds["verdict"]).values).ravel()
    n = n or v.size
    failed = int((v == V.NAMES.index("failed")).sum())
    if failed:
        err_console.print(f"{failed} of {n} trajectories failed: the solver did not reach t1{where}; exit status 1",
                          style="red", markup=False)
        return 1
    return 0


def export(
    store: Path = typer.Argument(..., help="a finished chunk store (the zarr directory of a sweep)"),
    out: Path = typer.Option(..., help="netCDF file to write"),
    force: bool = ForceOpt,
):
    """Write the netCDF file of a finished chunk store (e.g. one kept with --keep-store).

    An existing OUT is replaced only when it is a result of the same spec (an earlier export of this
    store, or the sweep's own output); any other file needs --force."""
    from ..plan.spec import spec_json
    from ..run.store import finished_store
    from ..run.sweep import export_store

    _, plan = finished_store(store)
    this_spec = json.loads(spec_json(plan.spec))
    replacing = check_output(out, "--out", RESULT_SUFFIXES, inputs=input_files(system=plan.system), force=force,
                              same=lambda p: result_spec(p) == this_spec,
                              what="a result of the spec of this store")
    if out.resolve().is_relative_to(Path(store).resolve()):
        from ..errors import ValidationError

        raise ValidationError("--out", f"{out} is inside the store {store}; write the file outside it")
    ds = export_store(store, out)
    console.print(f"wrote {out}  ({ds.attrs['n_trajectories']} trajectories, engine {ds.attrs['engine']})"
                  + (" (replaced the previous file)" if replacing else ""), markup=False)
