"""Command-line interface: ``stabjax systems | simulate | theory | sweep | export | plot | horizon-check | reproduce | bench``.

Every user error (:class:`stabjax.errors.StabjaxError`) is printed as ``error: <field>: <message>``
and exits with status 2 (a failed write of the chunk store or the output, e.g. a full disk: status 1);
finished sweep chunks are kept on disk, so the same command resumes.

Size (~600 lines): one function per command of the typer app plus the checks they share (usage
errors, output paths, exit statuses); split by command, those checks would be imported back by each.
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


PNG_KEY = "stabjax-spec"  # PNG text chunk: digest of the spec a map was drawn from


def _spec_digest(spec_dict) -> str:
    import hashlib

    return hashlib.sha256(json.dumps(spec_dict, sort_keys=True).encode()).hexdigest()[:16]


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


@app.command()
def systems(
    name: Optional[str] = typer.Argument(None, help="describe one system: a name, 'file.py:Class' or 'module:Class'"),
    as_json: bool = typer.Option(False, "--json", help="machine-readable output"),
):
    """List the systems (built in, registered, installed by packages), or describe one."""
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
    for nm, info in everything.items():
        if not info["available"]:
            console.print(f"[bold]{nm}[/bold]  [dim]({info['source']}; not available: {info['reason']})[/dim]")
            continue
        src = "" if info["source"] == "builtin" else f"  [dim]({info['source']})[/dim]"
        t = Table(title=f"[bold]{nm}[/bold] — {info['title']}{src}\n[dim]{info['paper']}[/dim]", title_justify="left")
        for col in ("name", "kind", "shape", "default", "unit", "meaning"):
            t.add_column(col, overflow="fold")
        for r in info["params"]:
            d = r["default"]
            dtxt = ", ".join(f"{x:.6g}" for x in np.ravel(np.asarray(d, float))) if np.ndim(d) else f"{float(d):.6g}"
            t.add_row(r["name"], r["kind"], "x".join(map(str, r["shape"])) or "scalar", dtxt, r["unit"], r["doc"])
        console.print(t)
        if name is not None:
            console.print("[bold]state[/bold]: " + ", ".join(f"{n}{tuple(sh) if sh else ''}" for n, sh in info["state"]))
            o = Table(title="observables", title_justify="left")
            o.add_column("name")
            o.add_column("meaning")
            for k, v in info["observables"].items():
                o.add_row(k, v)
            console.print(o)
            oc = Table(title="outcomes (code = row, first match wins)", title_justify="left")
            oc.add_column("outcome")
            oc.add_column("assigned by", overflow="fold")
            for k, v in info["outcomes"].items():
                oc.add_row(k, v)
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
        console.print_json(json.dumps(jsonable(final)))
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
    restart: bool = typer.Option(False, help="discard the finished chunks of an earlier run of this output"),
    progress: bool = typer.Option(True, "--progress/--no-progress"),
    store: Optional[Path] = typer.Option(None, help="chunk store (zarr directory; default <out>.zarr)"),
    keep_store: bool = typer.Option(False, "--keep-store", help="keep the chunk store after writing <out>"),
    scheduler: Optional[str] = typer.Option(None, help="run the chunks on an existing Dask scheduler "
                                            "(tcp://HOST:8786 or a scheduler file)"),
    workers: Optional[int] = typer.Option(None, help="run the chunks on a local Dask cluster of N worker processes"),
    threads: Optional[int] = typer.Option(None, help="native engine threads per Dask worker "
                                          "(default: cores // workers locally)"),
    oversubscribe: bool = typer.Option(False, "--oversubscribe", help="allow workers x threads > cores "
                                       "(or more local workers than GPUs)"),
    force: bool = ForceOpt,
):
    """Run a sweep spec: integrate, classify, evaluate the theory, write a labelled dataset.

    A spec with a [refine] section brackets the boundary between outcomes adaptively instead."""
    from .spec import load_spec, make_plan, spec_json
    from .sweep import default_store, run_plan

    if threads is not None and scheduler is None and workers is None:
        from .errors import ValidationError

        raise ValidationError("--threads", "applies to Dask workers: give --workers N or --scheduler ADDRESS "
                              "(a local run uses $STABJAX_THREADS)")
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
                      same=lambda p: _png_spec(p) == _spec_digest(this_spec),
                      what="the map of a previous result of this spec")
    if replacing:
        err_console.print(f"{out} exists: it will be replaced" + ("" if force else " (a previous result of this spec)"))
    store = store or default_store(out)
    executor = None
    if scheduler is not None or workers is not None:
        import os

        from .distributed import DaskExecutor

        # this process only collects results: keep a GPU's memory for the workers
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
        executor = DaskExecutor(scheduler=scheduler, workers=workers, threads=threads, oversubscribe=oversubscribe)
    try:
        if executor is not None:
            executor.start()
        if "refine" in s:  # adaptive boundary refinement from the [grid] as coarse grid (stabjax.refine)
            from .refine import run_cli

            return run_cli(plan, out, plot=plot, console=console, batch_size=batch_size, progress=progress,
                           restart=restart, store=store, keep_store=keep_store, executor=executor, overrides={"t1": t1})
        ds = run_plan(plan, out, batch_size=batch_size, progress=progress, restart=restart, store=store,
                      keep_partial=keep_store, executor=executor, overrides={"t1": t1})
    except KeyboardInterrupt:
        err_console.print(f"[yellow]interrupted: finished chunks are kept in {store}; "
                          "run the same command to resume[/yellow]")
        raise typer.Exit(130)
    finally:
        if executor is not None:
            executor.close()
    console.print(f"wrote {out}  ({ds.attrs['n_trajectories']} trajectories, {ds.attrs['total_steps']:,} steps, "
                  f"{ds.attrs['wall_time_s']:.1f} s, engine {ds.attrs['engine']})")
    _report(ds, out.with_suffix(".png") if plot else None)


def _report(ds, png: Optional[Path], replaced: bool = False):
    """The CLI summary and plot of a result: named outcomes with basin fractions, or verdicts vs theory."""
    from .plotting import format_confusion, plot_sweep

    if "outcome" in ds and not int(ds.attrs.get("outcomes_from_verdicts", 1)):
        from .basin_plot import format_summary, plot_basin

        console.print(format_summary(ds), highlight=False)
        if png is not None:
            plot_basin(ds, png)
    else:
        console.print(format_confusion(ds), highlight=False)
        if "basin_fraction" in ds:
            from .basin_plot import format_summary

            console.print(format_summary(ds), highlight=False)
        if png is not None:
            plot_sweep(ds, png)
    if png is not None:
        _stamp_png(png, ds)
        console.print(f"wrote {png}" + (" (replaced the previous file)" if replaced else ""))


@app.command()
def export(
    store: Path = typer.Argument(..., help="a finished chunk store (the zarr directory of a sweep)"),
    out: Path = typer.Option(..., help="netCDF file to write"),
):
    """Write the netCDF file of a finished chunk store (e.g. one kept with --keep-store)."""
    from .sweep import export_store

    ds = export_store(store, out)
    console.print(f"wrote {out}  ({ds.attrs['n_trajectories']} trajectories, engine {ds.attrs['engine']})")


@app.command("plot")
def plot_cmd(
    file: Path = typer.Argument(..., help="sweep result (netCDF)"),
    out: Optional[Path] = typer.Option(None, help="PNG, PDF or SVG (default: FILE with .png)"),
    force: bool = ForceOpt,
):
    """Draw the verdict map with the theoretical boundary (or the named outcomes and basin fractions); print counts."""
    ds = _open_result_file(file)
    if "verdict" not in ds:
        from .errors import ValidationError

        raise ValidationError("file", f"{file} is not a sweep result (no 'verdict' variable)")
    _warn_changed_model(ds)
    out = out or file.with_suffix(".png")
    # the map of FILE (FILE with an image extension) is replaced when drawn again; any other image needs --force
    replacing = _check_output(out, "--out", IMAGE_SUFFIXES, inputs=(file,), force=force,
                              same=lambda p: p.resolve() == file.resolve().with_suffix(p.suffix),
                              what=f"the map of {file}")
    _report(ds, out, replaced=replacing)


def _warn_changed_model(ds):
    """A result records its model file's hash; say so when the file on disk has changed since."""
    import hashlib

    f, sha = ds.attrs.get("model_file", ""), ds.attrs.get("model_sha256", "")
    if f and sha and sha != "unknown" and Path(f).exists():
        now = hashlib.sha256(Path(f).read_bytes()).hexdigest()
        if now != sha:
            err_console.print(f"[yellow]warning: the model file {f} has changed since this result was computed "
                              f"(sha256 {sha[:12]} then, {now[:12]} now)[/yellow]")


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
    suite: str = typer.Option("engines", help="engines: the sweep engine vs diffrax, SciPy, numba (paper A); "
                              "models: a user model (examples/duffing) vs the same baselines, and a built-in "
                              "through the user-model door; refine: boundary refinement vs the full grid; "
                              "dask: 1 and 2 local workers and the per-chunk overhead"),
    force: bool = ForceOpt,
):
    """Benchmark against named baselines in one process (figures in the README and docs/performance.md).

    The benchmarks are research code kept beside the tests in a source checkout (``benchmarks/``), not
    in the installed package: run this from the top of a clone."""
    from . import validate
    from .errors import ValidationError

    if suite not in ("engines", "models", "refine", "dask"):
        raise ValidationError("--suite", f"unknown suite {suite!r}; choose engines, models, refine, dask")
    if suite == "engines":  # every input checked before the checkout is looked for
        n = _int_list(sizes, "--sizes")
        validate.number(t1, "--t1", lo=0.0, lo_open=True)
        _check_output(out, "--out", (".json",), force=force, same=_is_bench_record, what="a previous benchmark record")
        _benchmark("bench").main(sizes=n, t1=t1, out=out, quick=quick, with_fused=fused)
    elif suite == "models":
        _benchmark("bench_models").main(["--n", "256", "--t1", "200", "--rounds", "1"] if quick else [])
    elif suite == "refine":
        raise typer.Exit(_benchmark("refine_bench").main(["--t1", "200", "--full-rows", "8"] if quick else []))
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
    import matplotlib

    from .config import setup_jax
    from .errors import StabjaxError

    # the CLI only writes figures to files: a non-interactive backend, chosen here and not on import of the
    # plotting modules (a user importing stabjax.plotting in Jupyter keeps inline figures)
    matplotlib.use("Agg")
    setup_jax()
    click_exception = _click_exception()
    try:
        # standalone_mode=False: errors come back to this function instead of exiting inside typer;
        # typer then *returns* the status of a ``typer.Exit`` (and 130 for Ctrl-C) instead of raising it
        rv = app(args=argv, standalone_mode=False)
    except StabjaxError as exc:
        err_console.print(f"[bold red]error:[/bold red] {exc}", highlight=False)
        sys.exit(getattr(exc, "exit_code", 2))  # 2: bad input / refused; 1: I/O failure (store.StoreIOError)
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
