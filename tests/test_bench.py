"""Smoke test of the benchmark (stabjax bench --quick): it runs every contender, checks agreement,
and writes results/bench.json + .md. Not a timing test."""
import json
import platform

import numpy as np
import pytest

from stabjax import bench, native


def test_quick_benchmark_runs_and_agrees(tmp_path):
    out = tmp_path / "bench.json"
    r = bench.main(quick=True, out=out)
    assert out.exists() and out.with_suffix(".md").exists()
    on_disk = json.loads(out.read_text())
    assert on_disk["quick"] is True and on_disk["machine"]["cpus"] >= 1 and "jax" in on_disk["versions"]
    (n, row), = r["sizes"].items()
    for name in ("stabjax", "diffrax_vmap"):
        c = row[name]
        assert c["wall_s"] > 0 and c["compile_s"] > 0 and c["accepted_steps"] > 0 and c["peak_rss_mb"] > 0
    assert row["scipy_dop853"]["wall_s_per_trajectory"] > 0
    a = row["agreement"]
    assert a["verdicts_equal_native_vs_diffrax_engine"] == a["verdict_check_n"] == int(n)
    assert a["verdicts_equal_fused_vs_diffrax_engine"] == a["verdict_check_n"]
    assert a["verdicts_equal_run_spec_vs_diffrax_engine"] == a["verdict_check_n"]
    assert a["max_abs_state_diff_native_vs_diffrax"] < 1e-6
    assert a["max_abs_state_diff_fused_vs_diffrax"] < 1e-6
    assert a["max_abs_state_diff_native_vs_scipy"] < 1e-6
    assert row["stabjax_fused"]["accepted_steps"] > 0
    md = out.with_suffix(".md").read_text()
    assert f"| stabjax (run_spec, {row['stabjax']['engine']} engine) |" in md
    assert "| stabjax (run_spec, fused XLA engine) |" in md
    nf = r["native_flops"]
    assert nf["step"] > 0 and nf["counts"]["f_rhs"]["libm_calls"] >= 3  # cos, t**alpha (exp, log), cbrt
    for key in ("measured_peak", "measured_peak_end"):
        mp = on_disk[key]
        assert "error" in mp or (mp["gflops_f64_one_thread"] > 0 and mp["gflops_f64_all_threads"] > 0), mp
    if "gflops_f64_all_threads" in on_disk["measured_peak"]:
        assert "Measured peak before the run" in md and "Measured peak after it" in md
        if row["stabjax"]["engine"] == "native":
            assert 0 < row["ratios"]["fraction_of_measured_f64_peak"] < 1


def test_measured_peak_kernel_does_the_work_it_counts():
    """The peak microbenchmark's flop count is honest: its result equals the same recurrence in
    NumPy (chains x lanes multiply-adds per iteration, none optimised away)."""
    if platform.machine() not in ("x86_64", "AMD64") or not native.available():
        pytest.skip("x86-64 with a C compiler only")
    lib = bench.peak_library()
    lanes, chains, iters = lib.stabjax_peak_lanes(), lib.stabjax_peak_chains(), 1000
    acc = np.repeat(1.0 + 1e-3 * np.arange(chains), lanes)
    x = 1.0
    for _ in range(iters):
        acc = acc * 0.999999 + 1e-7
        x = x * 0.999999 + 1e-7
    assert lib.stabjax_peak_fma(iters) == pytest.approx(acc.sum(), rel=1e-12)
    assert lib.stabjax_peak_chain(iters) == pytest.approx(x, rel=1e-12)


def test_gpu_defaults_and_accelerator_report(monkeypatch):
    """On a GPU backend the fused engine gets 2^18 lanes and 2^20-trajectory chunks (NOTES.md G2)
    and the benchmark names the accelerator with its float64 peak; CPU defaults are unchanged."""
    import jax

    from stabjax import fast
    from stabjax.spec import make_plan
    from stabjax.sweep import default_batch

    plan = make_plan(bench.spec(4, 1.0))
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")  # whatever this machine has
    assert fast.default_lanes() == 256 and default_batch(plan) == 65536
    assert bench.accelerator() is None

    class Dev:
        device_kind = "NVIDIA H100 80GB HBM3"

    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    monkeypatch.setattr(jax, "devices", lambda *a: [Dev()])
    assert fast.default_lanes() == 262144 and default_batch(plan) == 1 << 20
    acc = bench.accelerator()
    assert acc["device_kind"] == Dev.device_kind and acc["peak_tflops_f64"] == 34.0
    r = {"accelerator": acc}
    assert "NVIDIA H100 80GB HBM3" in bench._accelerator_lines(r)[0]
