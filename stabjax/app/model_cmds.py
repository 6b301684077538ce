"""``stabjax systems | simulate | theory``: a model on its own, before any sweep."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape
from rich.table import Table

from ..run.outputs import input_files
from .common import ForceOpt, RESULT_SUFFIXES, SetOpt, check_output, parse_sets, trajectory_system, console, err_console, jsonable


def _describe_system(sysm, source: str) -> dict:
    return {"available": True, "source": source, "title": sysm.title, "paper": sysm.paper,
            "state": [[n, list(sh)] for n, sh in sysm.state],
            "observables": dict(zip(sysm.observables, sysm.observable_doc)),
            "outcomes": dict(sysm.describe_outcomes()),
            "params": sysm.describe()}


def _system_line(nm: str, info: dict) -> str:
    """One line of ``stabjax systems``: name, title, source (a system that does not load says why)."""
    if not info["available"]:
        return f"{nm}  -  not available: {info['reason']}  ({info['source']})"
    return f"{nm}  -  {info['title']}  ({info['source']})"


def systems(
    name: Optional[str] = typer.Argument(None, help="describe one system: a name, 'file.py:Class' or 'module:Class'"),
    as_json: bool = typer.Option(False, "--json", help="machine-readable output"),
):
    """List the systems (built in, registered, installed by packages), one line each; describe one with NAME.

    The list stays one line per system so it fits a screen and greps well; the parameters,
    state, observables and outcomes of one system are shown with 'stabjax systems NAME'
    (--json gives everything for all of them)."""
    import numpy as np

    from ..errors import ValidationError
    from ..model.loading import resolve
    from ..model.registry import all_names, lookup

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
    import numpy as np

    from ..engines.simulate import simulate as sim
    from ..errors import ValidationError
    from ..model.loading import resolve

    sysm = resolve(system, base_dir=Path.cwd())
    replacing = False
    if out is not None:
        replacing = check_output(out, "--out", RESULT_SUFFIXES, inputs=input_files(system=sysm), force=force,
                                  same=lambda p: trajectory_system(p) == sysm.name,
                                  what=f"a trajectory of {sysm.name} written by stabjax simulate")
    times = None
    if ts is not None:
        from .. import validate

        items = [x for x in ts.split(",") if x.strip()]
        if not items:
            raise ValidationError("--ts", f"expected a comma list of numbers, got {ts!r}")
        times = np.array([validate.number(x, "--ts") for x in items])
    ds = sim(sysm, parse_sets(sets), t1=t1, ts=times, solver=solver, rtol=rtol, atol=atol)
    if out is not None:
        from ..run.sweep import write

        write(ds, out)
    ok = bool(ds.attrs["solver_ok"])
    k = len(ds.t) - 1
    if not ok:
        # past the failure the saved states are inf (the solver's fill): show the last state that is a state
        finite = np.ones(len(ds.t), bool)
        for name, _ in sysm.state:
            finite &= np.isfinite(ds[name].values.reshape(len(ds.t), -1)).all(axis=1)
        k = int(np.flatnonzero(finite)[-1]) if finite.any() else 0
    final = {"t": float(ds.t[k])}
    for name, _ in sysm.state:
        final[name] = ds[name].isel(t=k).values
    for name in sysm.observables:
        final[name] = float(ds[name].isel(t=k))
    final["solver_ok"] = ok
    final["n_steps"] = int(ds.attrs["n_steps"])
    if as_json:
        console.print_json(json.dumps(jsonable(final)))
    else:
        what = "final state" if ok else f"last finite saved state (t1 = {ds.attrs['t1']:g} not reached)"
        t = Table(title=f"{escape(system)}: {what} at t = {final['t']:g}")
        t.add_column("quantity")
        t.add_column("value")
        for k, v in final.items():
            t.add_row(escape(k), escape(np.array2string(np.asarray(v), precision=8)) if not isinstance(v, bool) else str(v))
        console.print(t)
        if out is not None:
            console.print(f"wrote {out}" + (" (replaced the previous file)" if replacing else ""), markup=False)
    if not final["solver_ok"]:
        from ..fold.status import describe

        err_console.print(f"did not reach t1 = {ds.attrs['t1']:g}: {describe(ds.attrs['solver_status'])}; the "
                          f"last saved state that is finite is at t = {final['t']:g} (--ts saves more times)",
                          markup=False)
        raise typer.Exit(1)


def theory(
    system: str = typer.Argument(...),
    sets: Optional[list[str]] = SetOpt,
    as_json: bool = typer.Option(False, "--json"),
):
    """Evaluate every theorem/corollary of the system's paper at the given parameters."""
    import numpy as np

    from ..model.loading import resolve
    from ..model.theory_eval import theory as evaluate

    sysm = resolve(system, base_dir=Path.cwd())
    th = evaluate(sysm, parse_sets(sets))
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
    if not res["predicates"] and not res["derived"]:
        # an empty table reads as "evaluated, nothing holds"; say that there is nothing to evaluate
        console.print(f"{sysm.name} states no theorem: its model defines no theory() (a Theory of predicates is "
                      "what a sweep draws its empirical region against)", markup=False)
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
