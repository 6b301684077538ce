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
        k, v = item.split("=", 1)
        out[k.strip()] = v.strip()
    return out


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
):
    """Integrate one trajectory; save the state and observables at the requested times."""
    from .engine import simulate as sim
    from .errors import ValidationError
    from .registry import get_system

    sysm = get_system(system)
    times = None
    if ts:
        try:
            times = np.array([float(x) for x in ts.split(",") if x.strip()])
        except ValueError:
            raise ValidationError("--ts", f"expected a comma list of numbers, got {ts!r}") from None
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
            console.print(f"wrote {out}")
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
):
    """Run a sweep spec: integrate, classify, evaluate the theory, write a labelled dataset."""
    from .plotting import format_confusion, plot_sweep
    from .spec import load_spec
    from .sweep import run_spec

    s = load_spec(spec)
    out = out or Path("results") / f"{s['name']}.nc"
    try:
        ds = run_spec(s, out, batch_size=batch_size, progress=progress, restart=restart, t1=t1)
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
    out: Optional[Path] = typer.Option(None, help="PNG (default: FILE with .png)"),
):
    """Draw the verdict map with the theoretical boundary; print theory x simulation counts."""
    from .plotting import format_confusion, plot_sweep
    from .sweep import open_result

    ds = open_result(file)
    if "verdict" not in ds:
        from .errors import ValidationError

        raise ValidationError("file", f"{file} is not a sweep result (no 'verdict' variable)")
    out = out or file.with_suffix(".png")
    plot_sweep(ds, out)
    console.print(format_confusion(ds), highlight=False)
    console.print(f"wrote {out}")


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
    from . import verdict as V
    from .sweep import horizon_check, open_result

    ds = open_result(file)
    if "horizon" in ds.dims and not as_json:
        for j, T in enumerate(ds["horizon"].values):
            c = V.counts(ds["verdict"].isel(horizon=j).values)
            console.print(f"dataset, T = {T:<9.3g}" + " ".join(f"{k[:4]} {v:<6d}" for k, v in c.items()))
    hc = horizon_check(ds, factor=factor, n=n, seed=seed)
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
):
    """Benchmark the sweep engine against named baselines in one process."""
    from .bench import main as bench_main

    bench_main(sizes=[int(s) for s in sizes.split(",")], t1=t1, out=out, quick=quick, with_fused=fused)


def main(argv: list[str] | None = None):
    from .errors import StabjaxError

    try:
        app(args=argv, standalone_mode=False)
    except StabjaxError as exc:
        err_console.print(f"[bold red]error:[/bold red] {exc}", highlight=False)
        sys.exit(2)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except SystemExit:
        raise
    except Exception as exc:  # click usage errors
        import click

        if isinstance(exc, click.exceptions.ClickException):
            exc.show()
            sys.exit(exc.exit_code)
        if isinstance(exc, click.exceptions.Abort):
            sys.exit(130)
        raise


if __name__ == "__main__":
    main()
