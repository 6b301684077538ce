"""``stabjax reproduce | bench | examples``: the papers' figures, the benchmarks of a source checkout, and the
shipped examples copied out of the package."""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import typer

from ..run.outputs import input_files
from .common import ForceOpt, check_output, int_list, console


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
    from ..run.outputs import reproduce_into
    from ..model.registry import get_reproducer

    fn = get_reproducer(name)
    out_dir = out_dir or Path("results") / name
    for dest, replaced in reproduce_into(out_dir, name, fn, quick=quick, force=force):
        console.print(f"wrote {dest}" + (" (replaced)" if replaced else ""), markup=False)


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
    """Benchmark against named baselines in one process (figures in docs/guide/benchmarks.md and docs/performance.md).

    The benchmarks are research code kept beside the tests in a source checkout (benchmarks/), not
    in the installed package: run this from the top of a clone."""
    from .. import validate
    from ..errors import ValidationError

    if suite not in ("engines", "models", "refine", "dask", "peers"):
        raise ValidationError("--suite", f"unknown suite {suite!r}; choose engines, models, refine, dask, peers")
    if suite == "engines":  # every input checked before the checkout is looked for
        n = int_list(sizes, "--sizes")
        validate.number(t1, "--t1", lo=0.0, lo_open=True)
        check_output(out, "--out", (".json",), inputs=input_files(), force=force, same=_is_bench_record,
                      what="a previous benchmark record")
        benchmark_module("bench").main(sizes=n, t1=t1, out=out, quick=quick, with_fused=fused)
    elif suite == "models":
        benchmark_module("bench_models").main(["--n", "256", "--t1", "200", "--rounds", "1"] if quick else [])
    elif suite == "refine":
        raise typer.Exit(benchmark_module("refine_bench").main(["--t1", "200", "--full-rows", "8"] if quick else []))
    elif suite == "peers":
        raise typer.Exit(benchmark_module("peer_bench").main(["--n", "256", "--t1", "100", "--diffrax-n", "32"] if quick else []))
    else:
        benchmark_module("dask_bench").main(["workers"])


def benchmark_module(module: str):
    """``benchmarks.<module>`` of the source checkout in the current directory (the installed wheel holds
    no benchmark code), or a ValidationError saying how to run it."""
    import importlib

    from ..errors import ValidationError

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


def examples_cmd(
    dest: Path = typer.Argument(..., help="folder to copy the examples into (made if missing)"),
    force: bool = typer.Option(False, "--force", help="replace example files that already exist in DEST"),
):
    """Copy the shipped examples (user models outside attitude control: spec + model + figure) out of the
    installed package, so a wheel's user can run them: stabjax sweep DEST/duffing/spec.toml."""
    from ..errors import ValidationError
    from ..reproduce import copy_examples

    if dest.exists() and not dest.is_dir():
        raise ValidationError("dest", f"{dest} exists and is not a directory")
    written = copy_examples(dest, force=force)
    for f in written:
        console.print(f"wrote {f}", markup=False, soft_wrap=True)
    names = sorted({f.parent.name for f in written})
    console.print(f"run one with: stabjax sweep {dest / names[0] / 'spec.toml'}" if names else "", markup=False,
                  soft_wrap=True)
