"""Command-line interface: ``stabjax systems | simulate | theory | sweep | plot | horizon-check | reproduce | bench``.

Every user error (:class:`stabjax.errors.StabjaxError`) is printed as ``error: <field>: <message>``
and exits with status 2; finished sweep chunks are kept on disk, so the same command resumes.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Optional

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="stabjax: batch stability explorer for rigid-body attitude control.")
console = Console()
err_console = Console(stderr=True)

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
    for inp in inputs:
        if inp.exists() and out.exists() and out.resolve() == inp.resolve():
            raise ValidationError(field, f"{out} is this command's input; it is never overwritten")
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
    try:
        return open_result(file)
    except ValidationError:
        raise
    except Exception as exc:  # noqa: BLE001 - netCDF/HDF5 raise several types for a foreign file
        raise ValidationError("file", f"{file} is not a netCDF sweep result ({type(exc).__name__})") from None


def _jsonable(x: Any):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return None if not np.isfinite(x) else float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


@app.command()
def systems(as_json: bool = typer.Option(False, "--json", help="machine-readable output")):
    """List registered systems with their parameters, defaults and meaning."""
    from .registry import SYSTEMS, get_system

    everything = {}
    for name in SYSTEMS:
        try:
            sysm = get_system(name)
        except ImportError as exc:
            everything[name] = {"available": False, "reason": str(exc)}
            continue
        everything[name] = {"available": True, "title": sysm.title, "paper": sysm.paper,
                            "state": [[n, list(s)] for n, s in sysm.state],
                            "observables": dict(zip(sysm.observables, sysm.observable_doc)),
                            "params": sysm.describe()}
    if as_json:
        console.print_json(json.dumps(_jsonable(everything)))
        return
    for name, info in everything.items():
        if not info["available"]:
            console.print(f"[bold]{name}[/bold]  [dim](not available: {info['reason']})[/dim]")
            continue
        t = Table(title=f"[bold]{name}[/bold] — {info['title']}\n[dim]{info['paper']}[/dim]", title_justify="left")
        for col in ("name", "kind", "shape", "default", "unit", "meaning"):
            t.add_column(col, overflow="fold")
        for r in info["params"]:
            d = r["default"]
            dtxt = ", ".join(f"{x:.6g}" for x in np.ravel(d)) if np.ndim(d) else f"{d:.6g}"
            t.add_row(r["name"], r["kind"], "x".join(map(str, r["shape"])) or "scalar", dtxt, r["unit"], r["doc"])
        console.print(t)


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
    from .registry import get_system

    sysm = get_system(system)
    replacing = False
    if out is not None:
        replacing = _check_output(out, "--out", RESULT_SUFFIXES, force=force,
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
        console.print_json(json.dumps(_jsonable(final)))
    else:
        t = Table(title=f"{system}: final state at t = {final['t']:g}")
        t.add_column("quantity")
        t.add_column("value")
        for k, v in final.items():
            t.add_row(k, np.array2string(np.asarray(v), precision=8) if not isinstance(v, bool) else str(v))
        console.print(t)
        if out is not None:
            console.print(f"wrote {out}" + (" (replaced the previous file)" if replacing else ""))
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
    from .registry import get_system

    sysm = get_system(system)
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
        console.print_json(json.dumps(_jsonable(res)))
        return
    t = Table(title=f"{system}: theorems at the given parameters")
    for col in ("predicate", "holds", "margin", "statement"):
        t.add_column(col, overflow="fold")
    for k, v in res["predicates"].items():
        mark = "[green]yes[/green]" if v["ok"] else "[red]no[/red]"
        t.add_row(k + (" (main)" if k == th.main else ""), mark, np.array2string(v["margin"], precision=6), v["statement"])
    console.print(t)
    if res["derived"]:
        d = Table(title="derived quantities")
        for col in ("name", "value", "meaning"):
            d.add_column(col, overflow="fold")
        for k, v in res["derived"].items():
            d.add_row(k, np.array2string(v["value"], precision=6), v["meaning"])
        console.print(d)


@app.command()
def sweep(
    spec: Path = typer.Argument(..., help="sweep spec (TOML), e.g. sweeps/at2019_alpha_sigma.toml"),
    out: Optional[Path] = typer.Option(None, help="netCDF output (default results/<name>.nc)"),
    batch_size: Optional[int] = typer.Option(None, "--batch-size", help="trajectories per compiled chunk"),
    t1: Optional[float] = typer.Option(None, help="override [integrate].t1"),
    plot: bool = typer.Option(True, "--plot/--no-plot", help="also write <out>.png"),
    restart: bool = typer.Option(False, help="discard finished chunks of an earlier run of this output"),
    progress: bool = typer.Option(True, "--progress/--no-progress"),
    force: bool = ForceOpt,
):
    """Run a sweep spec: integrate, classify, evaluate the theory, write a labelled dataset."""
    from .plotting import format_confusion, plot_sweep
    from .spec import load_spec, make_plan, spec_json
    from .sweep import run_plan

    s = load_spec(spec)
    plan = make_plan(s, t1=t1)  # every field checked before any output path is looked at
    out = out or Path("results") / f"{plan.name}.nc"
    this_spec = json.loads(spec_json(plan.spec))
    replacing = _check_output(out, "--out", RESULT_SUFFIXES, inputs=(spec,), force=force,
                              same=lambda p: _result_spec(p) == this_spec,
                              what="a result of this spec (with this --t1)")
    if plot:  # the map follows its result: replaced with it, else only with --force
        png = out.with_suffix(".png")
        _check_output(png, "--out", IMAGE_SUFFIXES, inputs=(spec,), force=force or replacing,
                      what="the map of a previous result of this spec")
    if replacing:
        err_console.print(f"{out} exists: it will be replaced" + ("" if force else " (a previous result of this spec)"))
    try:
        ds = run_plan(plan, out, batch_size=batch_size, progress=progress, restart=restart)
    except KeyboardInterrupt:
        err_console.print(f"[yellow]interrupted: finished chunks are kept in {out}.partial; "
                          "run the same command to resume[/yellow]")
        raise typer.Exit(130)
    console.print(f"wrote {out}  ({ds.attrs['n_trajectories']} trajectories, {ds.attrs['total_steps']:,} steps, "
                  f"{ds.attrs['wall_time_s']:.1f} s)")
    console.print(format_confusion(ds), highlight=False)
    if plot:
        png = out.with_suffix(".png")
        plot_sweep(ds, png)
        console.print(f"wrote {png}")


@app.command("plot")
def plot_cmd(
    file: Path = typer.Argument(..., help="sweep result (netCDF)"),
    out: Optional[Path] = typer.Option(None, help="PNG, PDF or SVG (default: FILE with .png)"),
    force: bool = ForceOpt,
):
    """Draw the verdict map with the theoretical boundary; print theory x simulation counts."""
    from .plotting import format_confusion, plot_sweep

    ds = _open_result_file(file)
    if "verdict" not in ds:
        from .errors import ValidationError

        raise ValidationError("file", f"{file} is not a sweep result (no 'verdict' variable)")
    out = out or file.with_suffix(".png")
    # the map of FILE (FILE with an image extension) is replaced when drawn again; any other image needs --force
    replacing = _check_output(out, "--out", IMAGE_SUFFIXES, inputs=(file,), force=force,
                              same=lambda p: p.resolve() == file.resolve().with_suffix(p.suffix),
                              what=f"the map of {file}")
    plot_sweep(ds, out)
    console.print(format_confusion(ds), highlight=False)
    console.print(f"wrote {out}" + (" (replaced the previous file)" if replacing else ""))


@app.command("horizon-check")
def horizon_check_cmd(
    file: Path = typer.Argument(..., help="sweep result (netCDF)"),
    factor: float = typer.Option(4.0, help="re-run with t1 * factor"),
    n: int = typer.Option(64, help="number of trajectories re-run"),
    seed: int = typer.Option(0),
    as_json: bool = typer.Option(False, "--json"),
):
    """Re-run a random subset at a longer horizon and report how many verdicts change."""
    from . import validate
    from . import verdict as V
    from .sweep import horizon_check

    validate.number(factor, "--factor", lo=1.0, lo_open=True)
    validate.integer(n, "--n", lo=1)
    validate.integer(seed, "--seed", lo=0)
    hc = horizon_check(_open_result_file(file), factor=factor, n=n, seed=seed)
    if as_json:
        console.print_json(json.dumps(_jsonable({"n_checked": hc.attrs["n_checked"], "n_changed": hc.attrs["n_changed"],
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
    name: str = typer.Argument(..., help="at2019 | saakyan | two-body | gyrodyne"),
    out_dir: Optional[Path] = typer.Option(None, "--out-dir", help="default results/<name>"),
    quick: bool = typer.Option(False, help="short horizons and small grids (smoke test)"),
):
    """Reproduce a paper's figures/examples (and what longer horizons show)."""
    from .registry import get_reproducer

    fn = get_reproducer(name)
    out_dir = out_dir or Path("results") / name
    if out_dir.exists() and not out_dir.is_dir():
        from .errors import ValidationError

        raise ValidationError("--out-dir", f"{out_dir} exists and is not a directory")
    files = fn(out_dir, quick=quick)
    for f in files:
        console.print(f"wrote {f}")


@app.command()
def bench(
    sizes: str = typer.Option("256,4096,65536", help="comma list of batch sizes N"),
    t1: float = typer.Option(1e4),
    out: Path = typer.Option(Path("results/bench.json")),
    quick: bool = typer.Option(False, help="tiny sizes (smoke test)"),
    fused: bool = typer.Option(True, help="also run the fused (XLA) engine as a named contender"),
    force: bool = ForceOpt,
):
    """Benchmark the sweep engine against named baselines in one process."""
    from . import validate
    from .bench import main as bench_main

    n = _int_list(sizes, "--sizes")
    validate.number(t1, "--t1", lo=0.0, lo_open=True)
    _check_output(out, "--out", (".json",), force=force, same=_is_bench_record, what="a previous benchmark record")
    bench_main(sizes=n, t1=t1, out=out, quick=quick, with_fused=fused)


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


def main(argv: list[str] | None = None):
    """Entry point: runs the app and turns every outcome into an exit status that tells the truth.

    0 success; 1 a run that failed (a solver failure reported by ``simulate``, an I/O error);
    2 bad input (a usage error -- unknown option or command, extra argument, a value of the wrong
    type -- printed with the usage, or a :class:`~stabjax.errors.StabjaxError` naming the field);
    130 interrupted (Ctrl-C).
    """
    from .errors import StabjaxError

    click_exception = _click_exception()
    try:
        # standalone_mode=False: errors come back to this function instead of exiting inside typer;
        # typer then *returns* the status of a ``typer.Exit`` (and 130 for Ctrl-C) instead of raising it
        rv = app(args=argv, standalone_mode=False)
    except StabjaxError as exc:
        err_console.print(f"[bold red]error:[/bold red] {exc}", highlight=False)
        sys.exit(2)
    except KeyboardInterrupt:
        err_console.print("[yellow]interrupted[/yellow]")
        sys.exit(130)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort:  # Ctrl-C or end of input at a prompt
        err_console.print("[yellow]aborted[/yellow]")
        sys.exit(130)
    except click_exception as exc:  # usage errors: the usage line, the error, status 2
        exc.show()
        sys.exit(exc.exit_code)
    except (PermissionError, FileNotFoundError, IsADirectoryError, NotADirectoryError) as exc:
        err_console.print(f"[bold red]error:[/bold red] {exc.filename}: {exc.strerror}", highlight=False)
        sys.exit(1)
    if isinstance(rv, int) and not isinstance(rv, bool) and rv != 0:
        sys.exit(rv)


if __name__ == "__main__":
    main()
