"""End to end against the kernel (issue 32, target 3): ``stabjax sweep SPEC`` from process start to the netCDF file.

``python -m benchmarks.e2e_bench SPEC [SPEC ...] [--set key=value ...] [--runs 2] [--json FILE]``: each spec is run
as a user runs it, ``stabjax sweep SPEC --out FILE --no-plot``, in a fresh Python process per run (the C kernels
come from the on-disk cache after the first run, as in a user's second run; ``--runs``: that many processes per
spec, the figures of the last). Inside the process the phases are timed by wrapping, not changing, the functions
that do them:

* ``process``: from the process's start (``/proc/self/stat``) to the end of the command;
* ``imports``: from the process's start to the command's call, the CLI's modules imported (``--help`` and
  ``--version`` end soon after; JAX is imported inside the command);
* ``kernel``: the native engine's compiled loop (``run_raw``), summed over chunks -- the integration itself;
* ``solve``: the engine's whole solve (kernel, host-side inputs and summaries);
* ``plan``, ``resolve`` (engine choice, C code generation or cache), ``store_create``, ``store_write``,
  ``assemble`` (the dataset read back), ``netcdf`` (the file written), ``summary`` (the printed table).

Printed per spec: the phases, ``process / kernel`` (target: <= 2) and ``process / solve``. ``--set`` edits the spec
(``sample.n=1000``; a JSON value). Also ``--cli``: ``stabjax --version`` and ``stabjax --help``, best of 5 processes.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_CHILD = "_STABJAX_E2E_CHILD"


def _process_age() -> float:
    """Seconds since this process started (Linux: /proc/self/stat's start time against the boot clock)."""
    with open("/proc/self/stat") as fh:
        start_ticks = float(fh.read().rsplit(")", 1)[1].split()[19])
    with open("/proc/uptime") as fh:
        uptime = float(fh.read().split()[0])
    return uptime - start_ticks / os.sysconf("SC_CLK_TCK")


def _child(spec_path: str, out: str) -> dict:
    phases: dict[str, float] = {}

    def timed(mod, name, key):
        fn = getattr(mod, name)

        def wrapper(*a, **k):
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                phases[key] = phases.get(key, 0.0) + time.perf_counter() - t

        setattr(mod, name, wrapper)

    import stabjax.app.sweep_cmds as SC
    import stabjax.engines as E
    import stabjax.engines.native as NV
    import stabjax.plan.spec as PS
    import stabjax.run.store as ST
    import stabjax.run.sweep as SW

    timed(NV, "run_raw", "kernel")
    timed(E, "solve", "solve")
    timed(E, "resolve_plan", "resolve")
    timed(PS, "make_plan", "plan")
    timed(ST.ChunkStore, "_create", "store_create")
    timed(ST.ChunkStore, "write", "store_write")
    timed(ST, "open_store", "assemble")
    timed(SW, "write", "netcdf")
    timed(SC, "print_result", "summary")
    from stabjax.app.cli import main

    t_imports = _process_age()
    t0 = time.perf_counter()
    try:
        main(["sweep", spec_path, "--out", out, "--no-plot", "--force"])
    except SystemExit as exc:
        if exc.code not in (0, None):
            raise
    phases["process"] = _process_age()
    phases["imports"] = t_imports
    phases["command"] = time.perf_counter() - t0
    return phases


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"no TOML for {type(v)}")


def to_toml(spec: dict) -> str:
    """A spec dict as TOML (top-level keys, then one table per section, nested tables inline)."""
    lines = [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in spec.items() if not isinstance(v, dict)]
    for k, v in spec.items():
        if isinstance(v, dict):
            lines.append(f"\n[{json.dumps(k)}]")
            lines += [f"{json.dumps(kk)} = {_toml_value(vv)}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


def measure(spec_path: str | Path, sets: dict | None = None, runs: int = 2) -> dict:
    """The phases of ``stabjax sweep`` on one spec, in fresh processes (the last of ``runs``)."""
    from stabjax.plan.spec import load_spec

    spec_path = Path(spec_path).resolve()
    with tempfile.TemporaryDirectory() as tmp:
        src = spec_path
        if sets:
            spec = load_spec(spec_path)
            for k, v in sets.items():
                d = spec
                keys = k.split(".")
                for kk in keys[:-1]:
                    d = d.setdefault(kk, {})
                d[keys[-1]] = v
            if isinstance(spec.get("system"), str) and ":" in spec["system"] and not Path(
                    spec["system"].split(":")[0]).is_absolute():
                spec["system"] = str(spec_path.parent / spec["system"])
            src = Path(tmp) / spec_path.name
            src.write_text(to_toml(spec))
        out = Path(tmp) / "result.nc"
        rec = None
        for _ in range(runs):
            out.unlink(missing_ok=True)
            env = {**os.environ, _CHILD: "1"}
            p = subprocess.run([sys.executable, "-m", "benchmarks.e2e_bench", "--child", str(src), str(out)],
                               capture_output=True, text=True, env=env, cwd=Path(__file__).resolve().parents[1])
            if p.returncode != 0:
                raise RuntimeError(f"{spec_path.name}: {p.stderr[-2000:]}")
            rec = json.loads(p.stdout.strip().splitlines()[-1])
    rec["spec"] = spec_path.name
    rec["sets"] = sets or {}
    k = rec.get("kernel", float("nan"))
    rec["process_over_kernel"] = rec["process"] / k if k else float("nan")
    rec["process_over_solve"] = rec["process"] / rec["solve"] if rec.get("solve") else float("nan")
    return rec


def cli_times(n: int = 5) -> dict:
    """Best of ``n`` processes of ``stabjax --version`` and ``stabjax --help`` (wall, from outside)."""
    out = {}
    for args in (["--version"], ["--help"]):
        best = float("inf")
        for _ in range(n):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "stabjax", *args], capture_output=True, check=True)
            best = min(best, time.perf_counter() - t)
        out[" ".join(args)] = round(best, 3)
    t = time.perf_counter()
    for _ in range(n):
        subprocess.run([sys.executable, "-c", "pass"], check=True)
    out["python -c pass"] = round((time.perf_counter() - t) / n, 3)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.e2e_bench", description=__doc__.split("\n")[0])
    ap.add_argument("specs", nargs="*")
    ap.add_argument("--set", action="append", default=[], help="spec key=value (JSON value), e.g. sample.n=1000")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--cli", action="store_true", help="also time stabjax --version and --help")
    ap.add_argument("--json", default=None)
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(_child(*a.child)))
        return 0
    sets = {}
    for kv in a.set:
        k, _, v = kv.partition("=")
        try:
            sets[k] = json.loads(v)
        except json.JSONDecodeError:
            sets[k] = v
    recs = []
    load = os.getloadavg()
    for s in a.specs:
        r = measure(s, sets, a.runs)
        recs.append(r)
        keys = ("imports", "plan", "resolve", "kernel", "solve", "store_create", "store_write", "assemble", "netcdf",
                "summary")
        print(f"{r['spec']} {r['sets'] or ''}: process {r['process']:.2f} s = {r['process_over_kernel']:.2f} x kernel "
              f"({r['process_over_solve']:.2f} x solve); " + ", ".join(f"{k} {r.get(k, 0.0):.2f}" for k in keys),
              flush=True)
    res = {"load_before": load, "load_after": os.getloadavg(), "runs": recs}
    if a.cli:
        res["cli"] = cli_times()
        print("CLI (best of 5 processes):", res["cli"])
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
