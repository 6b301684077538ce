"""Command-line interface: ``stabjax systems | simulate | theory | sweep | export | plot | report | view |
horizon-check | reproduce | bench | examples`` (and ``stabjax --version``).

Every user error (:class:`stabjax.errors.StabjaxError`) is printed as ``error: <field>: <message>``
and exits with status 2 (a failed write of the chunk store or the output, e.g. a full disk: status 1);
finished sweep chunks are kept on disk, so the same command resumes. Exit statuses: 0 every trajectory
classified, 1 some failed (or a write failed), 2 usage or input error, 128 + N interrupted by signal N
(130 Ctrl-C, 143 SIGTERM, 129 SIGHUP). Text that is not ours (messages, names, paths, docs) is printed
without Rich markup, so brackets such as ``[refine]`` or ``grid.J[0]`` survive.

Size (~900 lines): one function per command of the typer app plus the checks they share (usage
errors, output paths, exit statuses); split by command, those checks would be imported back by each.
What a command may write over (inputs, stores, reproductions, atomic maps) is :mod:`stabjax.outputs`.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Optional

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from .outputs import check_store_path, input_files, same_file_as_any, write_image

# rich_markup_mode=None: the help is plain text, so "[refine]" in a docstring is shown, not eaten as a tag
app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False, rich_markup_mode=None,
                  help="stabjax: batch stability explorer for rigid-body attitude control.")
console = Console()
err_console = Console(stderr=True, soft_wrap=True)  # messages stay one line: greppable

SetOpt = typer.Option(None, "--set", "-s", help="parameter override NAME=VALUE (vectors as comma lists); repeatable")


def _parse_sets(sets: Optional[list[str]]) -> dict[str, str]:
    from .errors import ValidationError

    out = {}
    for item in sets or []:
        if "=" not in item:
            raise ValidationError("--set", f"expected NAME=VALUE, got {item!r}")
        k, v = (x.strip() for x in item.split("=", 1))
        if not k:
            raise ValidationError("--set", f"expected NAME=VALUE, got {item!r} (no name)")
        if k in out:
            raise ValidationError("--set", f"{k} is given twice ({out[k]!r} and {v!r})")
        out[k] = v
    return out


def _int_list(text: str, field: str, lo: int = 1) -> list[int]:
    """A comma list of integers >= lo (``--sizes``)."""
    from . import validate
    from .errors import ValidationError

    items = [x.strip() for x in text.split(",") if x.strip()]
    if not items:
        raise ValidationError(field, f"expected a comma list of integers, got {text!r}")
    try:
        values = [int(x) for x in items]
    except ValueError:
        raise ValidationError(field, f"expected a comma list of integers, got {text!r}") from None
    return [validate.integer(v, field, lo=lo) for v in values]


ForceOpt = typer.Option(False, "--force", help="replace an existing output file that is not a previous result of "
                                                 "the same command (a result of the same spec is replaced anyway)")
RESULT_SUFFIXES = (".nc",)
IMAGE_SUFFIXES = (".png", ".pdf", ".svg")


def _check_output(out: Path, field: str, suffixes: tuple[str, ...], *, inputs: tuple[Path, ...] = (),
                  force: bool = False, same=None, what: str = "a previous result of this command") -> bool:
    """Refuse an output path that would lose something; True when an existing file will be replaced.

    Never the command's input (a spec, a result being plotted), never a directory, only the
    extensions the command writes. An existing file is replaced when ``same(out)`` says it is a
    previous result of the same computation (re-running a command is normal) or with ``--force``;
    anything else is refused with the way to allow it.
    """
    from .errors import ValidationError

    if out.is_dir():
        raise ValidationError(field, f"{out} is a directory; give a file name ending in {suffixes[0]}")
    if out.suffix.lower() not in suffixes:
        raise ValidationError(field, f"{out}: this command writes {' or '.join(suffixes)} files; "
                                     f"got {out.suffix or 'no extension'!r}")
    if out.parent.exists() and not out.parent.is_dir():
        raise ValidationError(field, f"{out.parent} is not a directory")
    if out.exists() and same_file_as_any(out, inputs):
        raise ValidationError(field, f"{out} is this command's input (the spec, the model or a module it imports, "
                                     "or the file read); it is never overwritten")
    if not out.exists():
        return False
    if force or (same is not None and same(out)):
        return True
    raise ValidationError(field, f"{out} exists and is not {what}; pass --force to replace it, "
                                 "or choose another --out")


def _result_spec(path: Path):
    """The spec (parsed ``spec_json``) stored in a stabjax sweep result, or None for any other file."""
    try:
        import xarray as xr

        with xr.open_dataset(path, engine="netcdf4") as ds:
            return json.loads(ds.attrs["spec_json"]) if "spec_json" in ds.attrs else None
    except Exception:  # noqa: BLE001 - not a readable netCDF file: not a result
        return None


PNG_KEY = "stabjax-spec"  # PNG text chunk: digest of the spec a map was drawn from


def _spec_digest(spec_dict) -> str:
    from .identity import spec_digest

    return spec_digest(spec_dict)


def _png_spec(path: Path) -> str | None:
    """The spec digest stamped into a map by :func:`_stamp_png` (None for any other image)."""
    try:
        from PIL import Image

        with Image.open(path) as im:
            return im.info.get(PNG_KEY)
    except Exception:  # noqa: BLE001 - not a readable PNG: not a map of ours
        return None


def _stamp_png(path: Path, ds) -> None:
    """Record in the map which spec it shows, so a re-run of the same sweep may replace it (a shipped
    map of the same spec too) while any other image at that path needs --force."""
    if path.suffix.lower() != ".png" or "spec_json" not in ds.attrs:
        return
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    info.add_text(PNG_KEY, _spec_digest(json.loads(ds.attrs["spec_json"])))
    with Image.open(path) as im:
        im.load()
        im.save(path, pnginfo=info)


def _trajectory_system(path: Path) -> str | None:
    """The system of a trajectory written by ``stabjax simulate``, or None for any other file."""
    try:
        import xarray as xr

        with xr.open_dataset(path, engine="netcdf4") as ds:
            return str(ds.attrs["system"]) if "solver_ok" in ds.attrs and "system" in ds.attrs else None
    except Exception:  # noqa: BLE001
        return None


def _open_result_file(file: Path):
    from .errors import ValidationError
    from .sweep import open_result

    if file.is_dir():
        raise ValidationError("file", f"{file} is a directory, not a sweep result")
    if file.exists() and not file.is_file():  # a FIFO would block the open forever
        raise ValidationError("file", f"{file} is not a regular file (a pipe, device or socket)")
    try:
        return open_result(file)
    except ValidationError:
        raise
    except Exception as exc:  # noqa: BLE001 - netCDF/HDF5 raise several types for a foreign file
        raise ValidationError("file", f"{file} is not a netCDF sweep result ({type(exc).__name__})") from None


def jsonable(x: Any):
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return None if not np.isfinite(x) else float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _describe_system(sysm, source: str) -> dict:
    return {"available": True, "source": source, "title": sysm.title, "paper": sysm.paper,
            "state": [[n, list(sh)] for n, sh in sysm.state],
            "observables": dict(zip(sysm.observables, sysm.observable_doc)),
            "outcomes": dict(sysm.describe_outcomes()),
            "params": sysm.describe()}


def _version_callback(value: bool):
    if value:
        from . import __version__

        console.print(f"stabjax {__version__}", highlight=False)
        raise typer.Exit(0)


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_version_callback, is_eager=True,
                                       help="print the version and exit")):
    """stabjax: batch stability explorer for rigid-body attitude control."""


def _system_line(nm: str, info: dict) -> str:
    """One line of ``stabjax systems``: name, title, source (a system that does not load says why)."""
    if not info["available"]:
        return f"{nm}  -  not available: {info['reason']}  ({info['source']})"
    return f"{nm}  -  {info['title']}  ({info['source']})"


@app.command()
def systems(
    name: Optional[str] = typer.Argument(None, help="describe one system: a name, 'file.py:Class' or 'module:Class'"),
    as_json: bool = typer.Option(False, "--json", help="machine-readable output"),
):
    """List the systems (built in, registered, installed by packages), one line each; describe one with NAME.

    The list stays one line per system so it fits a screen and greps well; the parameters,
    state, observables and outcomes of one system are shown with ``stabjax systems NAME``
    (``--json`` gives everything for all of them)."""
    from .errors import ValidationError
    from .models import resolve
    from .registry import all_names, lookup

    everything = {}
    if name is not None:
        sysm = resolve(name, base_dir=Path.cwd())
        everything[name] = _describe_system(sysm, lookup(name) or "file/module")
    else:
        for nm in all_names():
            try:
                sysm = resolve(nm)
            except (ImportError, ValidationError) as exc:
                everything[nm] = {"available": False, "source": lookup(nm), "reason": str(exc)}
                continue
            everything[nm] = _describe_system(sysm, lookup(nm))
    if as_json:
        console.print_json(json.dumps(jsonable(everything)))
        return
    if name is None:
        for nm, info in everything.items():
            console.print(_system_line(nm, info), highlight=False, markup=False, soft_wrap=True)
        console.print(f"({len(everything)} systems; details: stabjax systems NAME)", highlight=False)
        return
    for nm, info in everything.items():
        if not info["available"]:
            console.print(f"[bold]{escape(nm)}[/bold]  [dim]({escape(str(info['source']))}; not available: "
                          f"{escape(str(info['reason']))})[/dim]")
            continue
        src = "" if info["source"] == "builtin" else f"  [dim]({escape(str(info['source']))})[/dim]"
        t = Table(title=f"[bold]{escape(nm)}[/bold] — {escape(str(info['title']))}{src}\n[dim]{escape(str(info['paper']))}[/dim]",
                  title_justify="left")
        for col in ("name", "kind", "shape", "default", "unit", "meaning"):
            t.add_column(col, overflow="fold")
        for r in info["params"]:
            d = r["default"]
            dtxt = ", ".join(f"{x:.6g}" for x in np.ravel(np.asarray(d, float))) if np.ndim(d) else f"{float(d):.6g}"
            t.add_row(*(escape(str(x)) for x in (r["name"], r["kind"], "x".join(map(str, r["shape"])) or "scalar", dtxt,
                                                   r["unit"], r["doc"])))
        console.print(t)
        if name is not None:
            console.print("[bold]state[/bold]: " + escape(", ".join(f"{n}{tuple(sh) if sh else ''}" for n, sh in info["state"])))
            o = Table(title="observables", title_justify="left")
            o.add_column("name")
            o.add_column("meaning")
            for k, v in info["observables"].items():
                o.add_row(escape(str(k)), escape(str(v)))
            console.print(o)
            oc = Table(title="outcomes (code = row, first match wins)", title_justify="left")
            oc.add_column("outcome")
            oc.add_column("assigned by", overflow="fold")
            for k, v in info["outcomes"].items():
                oc.add_row(escape(str(k)), escape(str(v)))
            console.print(oc)


@app.command()
def simulate(
    system: str = typer.Argument(..., help="registered system name"),
    sets: Optional[list[str]] = SetOpt,
    t1: Optional[float] = typer.Option(None, help="final time (default: the system's)"),
    ts: Optional[str] = typer.Option(None, help="comma list of save times (t1 is always included)"),
    out: Optional[Path] = typer.Option(None, help="netCDF file for the trajectory"),
    solver: str = typer.Option("tsit5"),
    rtol: float = typer.Option(1e-10),
    atol: float = typer.Option(1e-12),
    as_json: bool = typer.Option(False, "--json", help="print the final state as JSON"),
    force: bool = ForceOpt,
):
    """Integrate one trajectory; save the state and observables at the requested times."""
    from .engine import simulate as sim
    from .errors import ValidationError
    from .models import resolve

    sysm = resolve(system, base_dir=Path.cwd())
    replacing = False
    if out is not None:
        replacing = _check_output(out, "--out", RESULT_SUFFIXES, inputs=input_files(system=sysm), force=force,
                                  same=lambda p: _trajectory_system(p) == sysm.name,
                                  what=f"a trajectory of {sysm.name} written by stabjax simulate")
    times = None
    if ts is not None:
        from . import validate

        items = [x for x in ts.split(",") if x.strip()]
        if not items:
            raise ValidationError("--ts", f"expected a comma list of numbers, got {ts!r}")
        times = np.array([validate.number(x, "--ts") for x in items])
    ds = sim(sysm, _parse_sets(sets), t1=t1, ts=times, solver=solver, rtol=rtol, atol=atol)
    if out is not None:
        from .sweep import write

        write(ds, out)
    final = {"t": float(ds.t[-1])}
    for name, _ in sysm.state:
        final[name] = ds[name].isel(t=-1).values
    for name in sysm.observables:
        final[name] = float(ds[name].isel(t=-1))
    final["solver_ok"] = bool(ds.attrs["solver_ok"])
    final["n_steps"] = int(ds.attrs["n_steps"])
    if as_json:
        console.print_json(json.dumps(jsonable(final)))
    else:
        t = Table(title=f"{escape(system)}: final state at t = {final['t']:g}")
        t.add_column("quantity")
        t.add_column("value")
        for k, v in final.items():
            t.add_row(escape(k), escape(np.array2string(np.asarray(v), precision=8)) if not isinstance(v, bool) else str(v))
        console.print(t)
        if out is not None:
            console.print(f"wrote {out}" + (" (replaced the previous file)" if replacing else ""), markup=False)
    if not final["solver_ok"]:
        err_console.print(f"[red]solver failed (diffrax status {ds.attrs['solver_status']})[/red]")
        raise typer.Exit(1)


@app.command()
def theory(
    system: str = typer.Argument(...),
    sets: Optional[list[str]] = SetOpt,
    as_json: bool = typer.Option(False, "--json"),
):
    """Evaluate every theorem/corollary of the system's paper at the given parameters."""
    from .models import resolve

    sysm = resolve(system, base_dir=Path.cwd())
    p = sysm.check(sysm.params.resolve(_parse_sets(sets)))
    th = sysm.theory(p)
    res = {
        "system": system,
        "main": th.main,
        "predicates": {k: {"ok": bool(np.all(v.ok)), "margin": np.asarray(v.margin), "statement": v.doc}
                       for k, v in th.predicates.items()},
        "derived": {k: {"value": np.asarray(v), "meaning": th.derived_doc.get(k, "")} for k, v in th.derived.items()},
    }
    if as_json:
        console.print_json(json.dumps(jsonable(res)))
        return
    t = Table(title=f"{escape(system)}: theorems at the given parameters")
    for col in ("predicate", "holds", "margin", "statement"):
        t.add_column(col, overflow="fold")
    for k, v in res["predicates"].items():
        mark = "[green]yes[/green]" if v["ok"] else "[red]no[/red]"
        t.add_row(escape(k + (" (main)" if k == th.main else "")), mark, escape(np.array2string(v["margin"], precision=6)),
                  escape(str(v["statement"])))
    console.print(t)
    if res["derived"]:
        d = Table(title="derived quantities")
        for col in ("name", "value", "meaning"):
            d.add_column(col, overflow="fold")
        for k, v in res["derived"].items():
            d.add_row(escape(k), escape(np.array2string(v["value"], precision=6)), escape(str(v["meaning"])))
        console.print(d)


@app.command()
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

    A spec with a [refine] section brackets the boundary between outcomes adaptively instead.
    Exit status: 0 every trajectory classified, 1 some failed (the result is written and says which),
    2 bad input, 130/143/129 interrupted (finished chunks kept: the same command resumes)."""
    from . import validate
    from .errors import ValidationError
    from .spec import load_spec, make_plan, spec_json
    from .sweep import default_store, run_plan

    if threads is not None and scheduler is None and workers is None:
        raise ValidationError("--threads", "applies to Dask workers: give --workers N or --scheduler ADDRESS "
                              "(a local run uses $STABJAX_THREADS)")
    validate.number(connect_timeout, "--connect-timeout", lo=0.0, lo_open=True, hi=3600.0)
    s = load_spec(spec)
    plan = make_plan(s, t1=t1)  # every field checked before any output path is looked at
    out = out or Path("results") / f"{plan.name}.nc"
    inputs = input_files(spec, system=plan.system)
    this_spec = json.loads(spec_json(plan.spec))
    replacing = _check_output(out, "--out", RESULT_SUFFIXES, inputs=inputs, force=force,
                              same=lambda p: _result_spec(p) == this_spec,
                              what="a result of this spec (with this --t1)")
    if plot:  # the map follows its result: replaced with it, else only with --force
        png = out.with_suffix(".png")
        _check_output(png, "--out", IMAGE_SUFFIXES, inputs=inputs, force=force or replacing,
                      same=lambda p: _png_spec(p) == _spec_digest(this_spec),
                      what="the map of a previous result of this spec")
    store = store or default_store(out)
    check_store_path(store, inputs, outputs=(out, out.with_suffix(".png") if plot else None))
    if replacing:
        err_console.print(f"{out} exists: it will be replaced" + ("" if force else " (a previous result of this spec)"),
                          markup=False)
    note = plan.outcomes.decl.default_distance_note() if plan.outcomes is not None and plan.outcomes.decl else ""
    if note:
        err_console.print(f"note: {note}", markup=False)
    executor = None
    if scheduler is not None or workers is not None:
        import os

        from .distributed import DaskExecutor

        # this process only collects results: keep a GPU's memory for the workers
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
        executor = DaskExecutor(scheduler=scheduler, workers=workers, threads=threads, oversubscribe=oversubscribe,
                                timeout=connect_timeout)
    try:
        if executor is not None:
            _start_executor(executor, scheduler, connect_timeout)
        if "refine" in s:  # adaptive boundary refinement from the [grid] as coarse grid (stabjax.refine)
            from .refine import run_cli

            ds = run_cli(plan, out, plot=plot, console=console, batch_size=batch_size, progress=progress,
                         restart=restart, store=store, keep_store=keep_store, executor=executor, overrides={"t1": t1})
            raise typer.Exit(_run_status(ds, out))
        ds = run_plan(plan, out, batch_size=batch_size, progress=progress, restart=restart, store=store,
                      keep_partial=keep_store, executor=executor, overrides={"t1": t1})
    except KeyboardInterrupt as exc:
        status = getattr(exc, "status", 130)
        by = f" by {exc.name}" if hasattr(exc, "name") else ""
        err_console.print(f"interrupted{by}: finished chunks are kept in {store}; run the same command to resume",
                          style="yellow", markup=False)
        raise typer.Exit(status)
    finally:
        if executor is not None:
            executor.close()
    console.print(f"wrote {out}  ({ds.attrs['n_trajectories']} trajectories, {ds.attrs['total_steps']:,} steps, "
                  f"{ds.attrs['wall_time_s']:.1f} s, engine {ds.attrs['engine']})", markup=False)
    stops = _stops_line(ds)
    if stops:
        console.print(stops, markup=False)
    _report(ds, out.with_suffix(".png") if plot else None, result=out)
    status = _run_status(ds, out)  # the last line: how many failed, when any did
    if status:
        raise typer.Exit(status)


def _stops_line(ds) -> str:
    """How many trajectories ended before t1 because their fate was decided (stabjax.early), or ""."""
    if "stop_reason" not in ds:
        return ""
    from .early import STOP_ATTRACTOR, STOP_FIXED_POINT

    codes = ds["stop_reason"].values
    parts = [f"{int((codes == c).sum()):,} {what}" for c, what in
             ((STOP_FIXED_POINT, "at a stable fixed point"), (STOP_ATTRACTOR, "near an attractor found earlier"))
             if (codes == c).any()]
    return f"stopped early, fate decided: {', '.join(parts)}" if parts else ""


def _start_executor(executor, scheduler: str | None, timeout: float) -> None:
    """Connect to the Dask scheduler (or start the local cluster) within ``timeout`` seconds; any failure
    is one line naming the option, never a traceback (a port that answers but is not a Dask scheduler
    made distributed allocate exabytes)."""
    from .errors import StabjaxError, ValidationError

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


def _run_status(ds, out: Optional[Path] = None) -> int:
    """The exit status a finished sweep deserves: 0 when every trajectory is classified, 1 (said in one
    line) when some failed (the solver did not reach t1), or when named outcomes classified none."""
    from . import verdict as V

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
            err_console.print(f"{failed} of {n} trajectories failed: the solver did not reach t1{where}; "
                              "exit status 1", style="red", markup=False)
            return 1
        if n and unclassified == n:
            err_console.print(f"no trajectory was classified: all {n} are unclassified (no rule holds and no "
                              "template is near); exit status 1", style="red", markup=False)
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


def _report(ds, png: Optional[Path], replaced: bool = False, result: Optional[Path] = None):
    """The CLI summary and plot of a result: named outcomes with basin fractions, or verdicts vs theory.

    The map is drawn into a temporary file beside ``png`` and renamed over it, so a full disk leaves the
    previous map (or nothing), never half an image, and is reported in one line (exit 1) with the way
    to draw it again; ``result``: the netCDF file the map is drawn from, for that message."""
    from .plotting import format_confusion, plot_sweep

    if "outcome" in ds and not int(ds.attrs.get("outcomes_from_verdicts", 1)):
        from .basin_plot import format_summary, plot_basin

        console.print(format_summary(ds), highlight=False, markup=False)
        draw = plot_basin
    else:
        console.print(format_confusion(ds), highlight=False, markup=False)
        if "basin_fraction" in ds:
            from .basin_plot import format_summary

            console.print(format_summary(ds), highlight=False, markup=False)
        draw = plot_sweep
    if png is None:
        return
    write_image(png, lambda tmp: (draw(ds, tmp), _stamp_png(tmp, ds)), result)
    console.print(f"wrote {png}" + (" (replaced the previous file)" if replaced else ""), markup=False)


@app.command()
def export(
    store: Path = typer.Argument(..., help="a finished chunk store (the zarr directory of a sweep)"),
    out: Path = typer.Option(..., help="netCDF file to write"),
    force: bool = ForceOpt,
):
    """Write the netCDF file of a finished chunk store (e.g. one kept with --keep-store).

    An existing OUT is replaced only when it is a result of the same spec (an earlier export of this
    store, or the sweep's own output); any other file needs --force."""
    from .spec import spec_json
    from .store import finished_store
    from .sweep import export_store

    _, plan = finished_store(store)
    this_spec = json.loads(spec_json(plan.spec))
    replacing = _check_output(out, "--out", RESULT_SUFFIXES, inputs=input_files(system=plan.system), force=force,
                              same=lambda p: _result_spec(p) == this_spec,
                              what="a result of the spec of this store")
    if out.resolve().is_relative_to(Path(store).resolve()):
        from .errors import ValidationError

        raise ValidationError("--out", f"{out} is inside the store {store}; write the file outside it")
    ds = export_store(store, out)
    console.print(f"wrote {out}  ({ds.attrs['n_trajectories']} trajectories, engine {ds.attrs['engine']})"
                  + (" (replaced the previous file)" if replacing else ""), markup=False)


@app.command("plot")
def plot_cmd(
    file: Path = typer.Argument(..., help="sweep result (netCDF)"),
    out: Optional[Path] = typer.Option(None, help="PNG, PDF or SVG (default: FILE with the --format extension)"),
    fmt: Optional[str] = typer.Option(None, "--format", help="png | svg | pdf: vector output (svg, pdf) for a paper, "
                                                            "beside the PNG (default: from --out, else png)"),
    force: bool = ForceOpt,
):
    """Draw the verdict map with the theoretical boundary (or the named outcomes and basin fractions); print counts."""
    if fmt is not None:
        from .errors import ValidationError

        if fmt.lower().lstrip(".") not in ("png", "svg", "pdf"):
            raise ValidationError("--format", f"choose png, svg or pdf; got {fmt!r}")
        fmt = fmt.lower().lstrip(".")
        if out is not None and out.suffix.lower() != f".{fmt}":
            raise ValidationError("--format", f"--out {out} does not end in .{fmt}")
        out = out or file.with_suffix(f".{fmt}")
    ds = _open_result_file(file)
    if "verdict" not in ds and "outcome" not in ds:  # a model's own outcomes carry no attitude verdicts
        from .errors import ValidationError

        raise ValidationError("file", f"{file} is not a sweep result (no 'outcome' or 'verdict' variable)")
    _warn_changed_model(ds)
    out = out or file.with_suffix(".png")
    # the map of FILE (FILE with an image extension) is replaced when drawn again; any other image needs --force
    replacing = _check_output(out, "--out", IMAGE_SUFFIXES, inputs=input_files(file), force=force,
                              same=lambda p: p.resolve() == file.resolve().with_suffix(p.suffix),
                              what=f"the map of {file}")
    _report(ds, out, replaced=replacing, result=file)


@app.command("report")
def report_cmd(
    file: Path = typer.Argument(..., help="a result (netCDF): a sweep, an example's basin result or a refinement"),
    out: Optional[Path] = typer.Option(None, help="HTML page to write (default: FILE with .html)"),
    force: bool = ForceOpt,
):
    """Write one self-contained HTML page of a result: what was run, outcomes with S ± SE and Wilson
    intervals, figures, the theory's agreement and the warnings (for a lab notebook)."""
    from .report import write_report

    ds = _open_result_file(file)
    if "verdict" not in ds and "outcome" not in ds and "point_label" not in ds:
        from .errors import ValidationError

        raise ValidationError("file", f"{file} is not a stabjax result (no verdict, outcome or refinement points)")
    out = out or file.with_suffix(".html")
    replacing = _check_output(out, "--out", (".html",), inputs=(file,), force=force,
                              same=lambda p: p.resolve() == file.resolve().with_suffix(".html"),
                              what=f"the report of {file}")
    write_report(ds, out, source=str(file))
    console.print(f"wrote {out}" + (" (replaced the previous file)" if replacing else ""), markup=False,
                  soft_wrap=True)


@app.command("view")
def view_cmd(
    result: Path = typer.Argument(..., help="a result (netCDF), or a running sweep's chunk store (RESULT.nc.zarr)"),
    port: int = typer.Option(0, help="port on 127.0.0.1 (default: a free one)"),
    browser: bool = typer.Option(True, "--browser/--no-browser", help="open the page in the default browser"),
    quit_after: Optional[float] = typer.Option(None, "--quit-after", help="stop the server after this many seconds "
                                                                          "(scripts, tests)"),
):
    """Explore a result in the browser: its map, a click re-simulates that trajectory (time series with the late
    window, phase portrait, why it got its outcome), feature space, fractions with Wilson bands. Serves on
    127.0.0.1 only; a running sweep's store refreshes as chunks land. Needs: pip install 'stabjax[view]'."""
    from . import validate
    from .view import serve

    validate.integer(port, "--port", lo=0, hi=65535)
    if quit_after is not None:
        validate.number(quit_after, "--quit-after", lo=0.0, lo_open=True)
    if not result.exists():
        from .errors import ValidationError

        raise ValidationError("result", f"not found: {result}")
    serve(result, port=port, show=browser, quit_after=quit_after,
          announce=lambda text: console.print(text, markup=False, highlight=False, soft_wrap=True))


def _warn_changed_model(ds):
    """A result records its model file and the local modules it imports, with their hashes
    (:mod:`stabjax.identity`); say so when one on disk has changed since."""
    from .identity import changed_sources

    for what in changed_sources(ds.attrs):
        err_console.print(f"warning: the model file {what} has changed since this result was computed",
                          style="yellow", markup=False)


@app.command("horizon-check")
def horizon_check_cmd(
    file: Path = typer.Argument(..., help="sweep result (netCDF)"),
    factor: float = typer.Option(4.0, help="re-run with t1 * factor"),
    n: int = typer.Option(64, help="number of trajectories re-run"),
    seed: int = typer.Option(0),
    as_json: bool = typer.Option(False, "--json"),
):
    """Re-run a random subset at a longer horizon and report how many verdicts change.

    The sweep's dataset already holds the verdicts at t1 and the decades below it (dim ``horizon``,
    from the same runs; shown first); this extends a subset beyond t1 in one run per trajectory."""
    from . import validate
    from . import verdict as V
    from .horizon import horizon_check

    validate.number(factor, "--factor", lo=1.0, lo_open=True)
    validate.integer(n, "--n", lo=1)
    validate.integer(seed, "--seed", lo=0)
    ds = _open_result_file(file)
    if "verdict" not in ds:
        from .errors import ValidationError

        raise ValidationError("file", f"{file} holds named outcomes, not attitude verdicts: horizon-check compares "
                                      "verdicts (rerun the sweep with a longer --t1 to compare outcomes)")
    if "horizon" in ds.dims and not as_json:
        for j, T in enumerate(ds["horizon"].values):
            c = V.counts(ds["verdict"].isel(horizon=j).values)
            console.print(f"dataset, T = {T:<9.3g}" + " ".join(f"{k[:4]} {v:<6d}" for k, v in c.items()))
    hc = horizon_check(ds, factor=factor, n=n, seed=seed)
    if as_json:
        console.print_json(json.dumps(jsonable({"n_checked": hc.attrs["n_checked"], "n_changed": hc.attrs["n_changed"],
                                                  "t1_short": hc.attrs["t1_short"], "t1_long": hc.attrs["t1_long"],
                                                  "transition": hc["transition"].values})))
        return
    t = Table(title=f"verdicts at t1 = {hc.attrs['t1_short']:g} (rows) vs t1 = {hc.attrs['t1_long']:g} (columns)")
    t.add_column("")
    for name in V.NAMES:
        t.add_column(name)
    for i, name in enumerate(V.NAMES):
        t.add_row(name, *[str(int(x)) for x in hc["transition"].values[i]])
    console.print(t)
    console.print(f"{hc.attrs['n_changed']} of {hc.attrs['n_checked']} verdicts changed")


@app.command()
def reproduce(
    name: str = typer.Argument(..., help="at2019 | saakyan | twobody | gyrodyne"),
    out_dir: Optional[Path] = typer.Option(None, "--out-dir", help="default results/<name>"),
    quick: bool = typer.Option(False, help="short horizons and small grids (smoke test)"),
    force: bool = typer.Option(False, "--force", help="replace existing files in --out-dir that this command did "
                                                      "not write there (e.g. the figures shipped in results/)"),
):
    """Reproduce a paper's figures/examples (and what longer horizons show).

    The files are made in a staging folder inside --out-dir and moved into it at the end. A file already
    there is replaced only when an earlier `stabjax reproduce NAME` wrote it and it is unchanged since
    (recorded in --out-dir/.stabjax-reproduce.json); any other figure, table or result there (the figures
    tracked in the repository, a file you edited) needs --force, and is refused before anything is
    computed. A conflict found only after the run leaves the new files in the staging folder."""
    from .outputs import reproduce_into
    from .registry import get_reproducer

    fn = get_reproducer(name)
    out_dir = out_dir or Path("results") / name
    for dest, replaced in reproduce_into(out_dir, name, fn, quick=quick, force=force):
        console.print(f"wrote {dest}" + (" (replaced)" if replaced else ""), markup=False)


@app.command()
def bench(
    sizes: str = typer.Option("256,4096,65536", help="comma list of batch sizes N"),
    t1: float = typer.Option(1e4),
    out: Path = typer.Option(Path("results/bench.json")),
    quick: bool = typer.Option(False, help="tiny sizes (smoke test)"),
    fused: bool = typer.Option(True, help="also run the fused (XLA) engine as a named contender"),
    suite: str = typer.Option("engines", help="engines: the sweep engine vs diffrax, SciPy, numba (paper A); "
                              "models: a user model (examples/duffing) vs the same baselines, and a built-in "
                              "through the user-model door; refine: boundary refinement vs the full grid; "
                              "dask: 1 and 2 local workers and the per-chunk overhead; peers: pyBasin's damped "
                              "pendulum case (N = 10^4, t = 1000), traj-steps/s per core"),
    force: bool = ForceOpt,
):
    """Benchmark against named baselines in one process (figures in the README and docs/performance.md).

    The benchmarks are research code kept beside the tests in a source checkout (``benchmarks/``), not
    in the installed package: run this from the top of a clone."""
    from . import validate
    from .errors import ValidationError

    if suite not in ("engines", "models", "refine", "dask", "peers"):
        raise ValidationError("--suite", f"unknown suite {suite!r}; choose engines, models, refine, dask, peers")
    if suite == "engines":  # every input checked before the checkout is looked for
        n = _int_list(sizes, "--sizes")
        validate.number(t1, "--t1", lo=0.0, lo_open=True)
        _check_output(out, "--out", (".json",), inputs=input_files(), force=force, same=_is_bench_record,
                      what="a previous benchmark record")
        _benchmark("bench").main(sizes=n, t1=t1, out=out, quick=quick, with_fused=fused)
    elif suite == "models":
        _benchmark("bench_models").main(["--n", "256", "--t1", "200", "--rounds", "1"] if quick else [])
    elif suite == "refine":
        raise typer.Exit(_benchmark("refine_bench").main(["--t1", "200", "--full-rows", "8"] if quick else []))
    elif suite == "peers":
        raise typer.Exit(_benchmark("peer_bench").main(["--n", "256", "--t1", "100", "--diffrax-n", "32"] if quick else []))
    else:
        _benchmark("dask_bench").main(["workers"])


def _benchmark(module: str):
    """``benchmarks.<module>`` of the source checkout in the current directory (the installed wheel holds
    no benchmark code), or a ValidationError saying how to run it."""
    import importlib

    from .errors import ValidationError

    root = Path.cwd()
    if not (root / "benchmarks" / f"{module}.py").is_file():
        raise ValidationError("bench", f"no benchmarks/{module}.py here: the benchmarks live in a source checkout, "
                              "not in the installed package; run `stabjax bench` (or `python -m benchmarks."
                              f"{module}`) from the top of a clone of the repository")
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    return importlib.import_module(f"benchmarks.{module}")


@app.command("examples")
def examples_cmd(
    dest: Path = typer.Argument(..., help="folder to copy the examples into (made if missing)"),
    force: bool = typer.Option(False, "--force", help="replace example files that already exist in DEST"),
):
    """Copy the shipped examples (user models outside attitude control: spec + model + figure) out of the
    installed package, so a wheel's user can run them: ``stabjax sweep DEST/duffing/spec.toml``."""
    from .errors import ValidationError
    from .reproduce import copy_examples

    if dest.exists() and not dest.is_dir():
        raise ValidationError("dest", f"{dest} exists and is not a directory")
    written = copy_examples(dest, force=force)
    for f in written:
        console.print(f"wrote {f}", markup=False, soft_wrap=True)
    names = sorted({f.parent.name for f in written})
    console.print(f"run one with: stabjax sweep {dest / names[0] / 'spec.toml'}" if names else "", markup=False,
                  soft_wrap=True)


def _is_bench_record(path: Path) -> bool:
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(rec, dict) and "machine" in rec and "versions" in rec


def _click_exception() -> type[Exception]:
    """click's ClickException, from whichever click typer runs on (typer 0.29 vendors it as ``typer._click``
    and no longer installs ``click``): found through the public ``typer.BadParameter``."""
    return next((c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException"), typer.BadParameter)


def _interrupt_status(exc: BaseException) -> tuple[int, str]:
    """(exit status, what) of an interruption: 128 + the signal (SIGTERM 143, SIGHUP 129), Ctrl-C 130.
    click turns a KeyboardInterrupt into ``Abort``: the signal is found on the exception's chain."""
    from . import signals

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


def main(argv: list[str] | None = None):
    """Entry point: runs the app and turns every outcome into an exit status that tells the truth.

    0 success (a sweep: every trajectory classified); 1 a run that failed (failed trajectories, a
    solver failure reported by ``simulate``, an I/O error such as a full disk); 2 bad input (a usage
    error -- unknown option or command, extra argument, a value of the wrong type -- printed with the
    usage, or a :class:`~stabjax.errors.StabjaxError` naming the field, an environment variable
    included); 128 + N interrupted by signal N: 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP (both handled like
    Ctrl-C, :mod:`stabjax.signals`).
    """
    import matplotlib

    from . import signals
    from .config import setup_jax
    from .errors import StabjaxError

    # the CLI only writes figures to files: a non-interactive backend, chosen here and not on import of the
    # plotting modules (a user importing stabjax.plotting in Jupyter keeps inline figures)
    matplotlib.use("Agg")
    previous = signals.install()
    click_exception = _click_exception()
    try:
        setup_jax()  # validates the environment: a bad variable is an error naming it, not a traceback
        # standalone_mode=False: errors come back to this function instead of exiting inside typer;
        # typer then *returns* the status of a ``typer.Exit`` (and 130 for Ctrl-C) instead of raising it
        rv = app(args=argv, standalone_mode=False)
    except StabjaxError as exc:
        _error(str(exc))
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
