"""Smoke test of the benchmark (stabjax bench --quick): it runs every contender, checks agreement,
and writes results/bench.json + .md. Not a timing test."""
import json
from pathlib import Path

import pytest

from benchmarks import bench
from stabjax.engines import native


@pytest.mark.slow  # the full suite's; in CI's 10 minutes: the benchmark's harness; the engines' agreement is tests/engines/test_verdict_engines.py's
def test_quick_benchmark_runs_and_agrees(tmp_path):
    out = tmp_path / "bench.json"
    r = bench.main(quick=True, out=out)
    assert out.exists() and out.with_suffix(".md").exists()
    on_disk = json.loads(out.read_text())
    assert on_disk["quick"] is True and on_disk["machine"]["cpus"] >= 1 and "jax" in on_disk["versions"]
    (n, row), = r["sizes"].items()
    for name in ("stabjax", "stabjax_fused", "diffrax_vmap"):
        c = row[name]
        assert c["wall_s"] > 0 and c["compile_s"] > 0 and c["accepted_steps"] > 0 and c["peak_rss_mb"] > 0
    assert row["stabjax"]["engine"] == ("native" if native.available() else "fused")
    assert row["stabjax_fused"]["engine"] == "fused"
    assert row["scipy_dop853"]["wall_s_per_trajectory"] > 0
    a = row["agreement"]
    assert a["verdicts_equal_native_vs_diffrax_engine"] == a["verdict_check_n"] == int(n)
    assert a["verdicts_equal_fused_vs_diffrax_engine"] == a["verdict_check_n"]
    assert a["verdicts_equal_run_spec_vs_diffrax_engine"] == a["verdict_check_n"]
    # rtol 1e-8 over t1 = 20: both engines and the baseline agree far below 1e-6
    assert a["max_abs_state_diff_native_vs_diffrax"] < 1e-6
    assert a["max_abs_state_diff_fused_vs_diffrax"] < 1e-6
    assert a["max_abs_state_diff_native_vs_scipy"] < 1e-6
    md = out.with_suffix(".md").read_text()
    assert f"| stabjax (run_spec, {row['stabjax']['engine']} engine) |" in md
    assert "| stabjax (run_spec, fused XLA engine) |" in md


def test_gpu_defaults_and_accelerator_report(monkeypatch):
    """On a GPU backend the fused engine gets 2^18 lanes and 2^20-trajectory chunks
    (docs/performance.md) and the benchmark names the accelerator; CPU defaults are unchanged."""
    import jax

    from stabjax.engines import fused
    from stabjax.plan.spec import make_plan
    from stabjax.run.sweep import default_batch

    plan = make_plan(bench.spec(4, 1.0))
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")  # whatever this machine has
    assert fused.default_lanes() == 256 and default_batch(plan) == 65536
    assert bench.accelerator() is None

    class Dev:
        device_kind = "NVIDIA H100 80GB HBM3"

    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    monkeypatch.setattr(jax, "devices", lambda *a: [Dev()])
    assert fused.default_lanes() == 262144 and default_batch(plan) == 1 << 20
    acc = bench.accelerator()
    assert acc["device_kind"] == Dev.device_kind
    assert "NVIDIA H100 80GB HBM3" in bench._accelerator_lines({"accelerator": acc})[0]


ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("module", ["bench", "bench_models", "refine_bench", "dask_bench", "peer_bench"])
def test_every_bench_suite_loads_from_the_checkout(module, monkeypatch):
    """`stabjax bench --suite ...` imports its module from benchmarks/ of the checkout it runs in; each has the
    ``main`` the CLI calls (the dask suite once called ``distributed.main``, which did not exist: ImportError)."""
    import inspect

    from stabjax.app.paper_cmds import benchmark_module

    monkeypatch.chdir(ROOT)
    m = benchmark_module(module)
    assert Path(m.__file__).resolve() == ROOT / "benchmarks" / f"{module}.py"
    assert callable(m.main) and len(inspect.signature(m.main).parameters) >= 1


def test_bench_outside_a_checkout_says_where_the_benchmarks_are(tmp_path, monkeypatch, capsys):
    """The installed package holds no benchmark code: outside a clone `stabjax bench` refuses with status 2
    and says how to run it, instead of an ImportError."""
    from stabjax.app.cli import main

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--suite", "dask"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "benchmarks/dask_bench.py" in err and "clone" in err


def test_peer_suite_measures_the_pyBasin_pendulum(monkeypatch, capsys):
    """The peers' case (pyBasin's pendulum) runs from the checkout, every trajectory to t1 (no stop: the
    throughput the peers report), with the per-core rate; the step count per trajectory follows from the
    tolerances (a few hundred accepted Tsit5 steps per 100 time units at rtol 1e-8), so a run that stopped
    early or a rate not divided by the cores would fail."""
    import json as _json

    monkeypatch.chdir(ROOT)
    out = Path(ROOT / ".pytest_peer.json")
    try:
        from stabjax.app.paper_cmds import benchmark_module

        rc = benchmark_module("peer_bench").main(["--n", "64", "--t1", "100", "--diffrax-n", "16", "--json", str(out)])
        assert rc == 0
        rec = _json.loads(out.read_text())
    finally:
        out.unlink(missing_ok=True)
    s = rec["stabjax"]
    assert s["n"] == 64 and s["steps"] > 64 * 200
    assert s["traj_steps_per_s_per_core"] == pytest.approx(s["traj_steps_per_s"] / rec["cores"])
    assert rec["diffrax_vmap"]["steps"] > 16 * 200
    # the same starts' step counts agree between stabjax's Tsit5 and diffrax's (same method and controller)
    assert abs(rec["diffrax_vmap"]["steps"] / 16 - s["steps"] / 64) < 0.5 * s["steps"] / 64
    assert "pyBasin pendulum" in capsys.readouterr().out
