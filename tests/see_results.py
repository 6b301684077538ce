"""Small results of each shipped kind, for the report and view tests (issue 24): a verdict map of a
paper system (with a theory), a basin result of an example model (named outcomes, samples) and a
boundary refinement. Each takes seconds; built once per test module."""
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

VERDICT_MAP = {
    "system": "monoaxial", "name": "tiny_map", "params": {"mu": 1.5},
    "grid": {"alpha": {"start": 0.3, "stop": 1.0, "num": 5}, "sigma": [1.2, 1.3, 1.4, 1.5]},
    "integrate": {"t1": 400.0, "n_checkpoints": 128},
}
BASIN = {  # every trajectory runs to t1 (no early stop): its stored features are those of the whole run
    "system": f"{ROOT / 'stabjax' / 'examples' / 'pendulum' / 'model.py'}:Pendulum", "name": "tiny_pendulum",
    "sample": {"n": 48, "seed": 1, "theta0": {"dist": "uniform", "low": -2.6, "high": 3.6},
               "omega0": {"dist": "uniform", "low": -10.0, "high": 10.0}},
    "integrate": {"t1": 150.0, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 400, "early_stop": False},
}
BASIN_ALONG = {  # a swept parameter with samples at each value: basin fractions along it
    "system": f"{ROOT / 'stabjax' / 'examples' / 'pendulum' / 'model.py'}:Pendulum", "name": "tiny_pendulum_T",
    "grid": {"T": [0.3, 0.5, 0.7]},
    "sample": {"n": 16, "seed": 1, "theta0": {"dist": "uniform", "low": -2.6, "high": 3.6},
               "omega0": {"dist": "uniform", "low": -10.0, "high": 10.0}},
    "integrate": {"t1": 150.0, "rtol": 1e-8, "atol": 1e-8, "n_checkpoints": 400},
}
REFINE = {
    "system": "monoaxial", "name": "tiny_refine", "params": {"mu": 1.5},
    "grid": {"alpha": {"start": 0.3, "stop": 1.0, "num": 3}, "sigma": {"start": 1.2, "stop": 1.6, "num": 3}},
    "integrate": {"t1": 300.0, "n_checkpoints": 128},
    "refine": {"rel_tol": "1/8", "pair": ["converged", "*"]},
}


def build(folder: Path, along: bool = False) -> dict[str, Path]:
    """Write the three results (and with ``along`` a sampled 1-D sweep) into ``folder``; {kind: path}."""
    from stabjax.explore.refine import refine_spec
    from stabjax.run.sweep import run_spec

    out = {"verdicts": folder / "tiny_map.nc", "basin": folder / "tiny_pendulum.nc", "refine": folder / "tiny_refine.nc"}
    run_spec(VERDICT_MAP, out["verdicts"])
    run_spec(BASIN, out["basin"])
    refine_spec(REFINE, out["refine"])
    if along:
        out["along"] = folder / "tiny_pendulum_T.nc"
        run_spec(BASIN_ALONG, out["along"])
    return out
