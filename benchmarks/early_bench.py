"""Benchmark of the early stops (:mod:`stabjax.fold.stops`): each example with and without them.

``python -m benchmarks.early_bench [EXAMPLE ...] [--n N] [--engine E] [--set key=value ...]``: for each
example spec (``stabjax/examples/<name>/spec.toml``), the sweep runs with ``[integrate] early_stop =
false``, ``true``, and ``true`` with ``attractor_stop = true`` (the recurrence stop, where the example
allows it), each once to compile and once timed; printed: trajectory-steps, wall time of the timed run,
how many trajectories stopped at a fixed point and near an attractor, and the number of starts whose
outcome differs from the run without stops (must be 0). ``--set outcomes.discovery.lyapunov=false`` and
the like edit the spec.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

EXAMPLES = Path(__file__).resolve().parents[1] / "stabjax" / "examples"


def _set(spec: dict, dotted: str, value) -> None:
    keys = dotted.split(".")
    d = spec
    for k in keys[:-1]:
        d = d.setdefault(k, {})
    d[keys[-1]] = value


def measure(name: str, n: int | None = None, engine: str = "auto", sets: dict | None = None) -> dict:
    from stabjax.fold.stops import STOP_ATTRACTOR, STOP_FIXED_POINT
    from stabjax.errors import ValidationError
    from stabjax.plan.spec import load_spec, make_plan
    from stabjax.run.sweep import run_plan

    base = load_spec(EXAMPLES / name / "spec.toml")
    if n is not None and "sample" in base:
        base["sample"]["n"] = int(n)
    for k, v in (sets or {}).items():
        _set(base, k, v)
    row: dict = {"example": name, "n": None}
    labels = {}
    for key, es, ats in (("off", False, False), ("on", True, False), ("attractor", True, True)):
        spec = json.loads(json.dumps(base))
        spec["integrate"] = {**spec.get("integrate", {}), "engine": engine, "early_stop": es}
        if ats:
            spec["integrate"]["attractor_stop"] = True
        try:
            plan = make_plan(spec)
        except ValidationError as exc:  # the recurrence stop refused for this example: say why
            row[f"steps_{key}"] = None
            row[f"why_no_{key}"] = exc.message
            continue
        run_plan(plan)  # compile (and warm caches)
        t = time.perf_counter()
        ds = run_plan(plan)
        wall = time.perf_counter() - t
        names = str(ds["outcome"].attrs["flag_meanings"]).split()
        labels[key] = np.asarray(names)[ds["outcome"].values.ravel()]
        row["n"] = int(ds["outcome"].size)
        row["engine"] = ds.attrs.get("engine")
        row[f"steps_{key}"] = int(ds["n_steps"].sum())
        row[f"wall_{key}"] = round(wall, 2)
        row[f"active_{key}"] = bool(plan.icfg.early_stop)
        if es:
            reasons = ds["stop_reason"].values
            row[f"stopped_fixed_point_{key}"] = int((reasons == STOP_FIXED_POINT).sum())
            row[f"stopped_attractor_{key}"] = int((reasons == STOP_ATTRACTOR).sum())
        if key == "off":
            row["outcomes"] = {k: int(v) for k, v in zip(*np.unique(labels[key], return_counts=True))}
    for key in ("on", "attractor"):
        if key in labels:
            row[f"outcome_changes_{key}"] = int((labels["off"] != labels[key]).sum())
            row[f"steps_ratio_{key}"] = round(row["steps_off"] / max(row[f"steps_{key}"], 1), 2)
            row[f"wall_ratio_{key}"] = round(row["wall_off"] / max(row[f"wall_{key}"], 1e-9), 2)
    return row


def main(argv: list[str] | None = None) -> int:
    from stabjax.config import setup_jax

    ap = argparse.ArgumentParser(prog="python -m benchmarks.early_bench", description=__doc__.split("\n")[0])
    ap.add_argument("examples", nargs="*", default=["pendulum", "lorenz", "lorenz63", "duffing"])
    ap.add_argument("--n", type=int, default=None, help="starts per example (default: the spec's)")
    ap.add_argument("--engine", default="auto")
    ap.add_argument("--set", action="append", default=[], help="spec key=value (JSON value), e.g. integrate.t1=500")
    a = ap.parse_args(argv)
    setup_jax()
    sets = {}
    for kv in a.set:
        k, _, v = kv.partition("=")
        try:
            sets[k] = json.loads(v)
        except json.JSONDecodeError:
            sets[k] = v
    for name in a.examples:
        print(json.dumps(measure(name, a.n, a.engine, sets)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
