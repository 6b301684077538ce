"""`stabjax reproduce twobody` in quick mode writes its figures and summary."""
from __future__ import annotations

import re

import pytest

import stabjax  # noqa: F401
from stabjax.model.registry import get_reproducer


# the full suite's (~20 s on 2 cores); in CI's 10 minutes: the reproduce command end to end is
# test_saakyan_sweeps.py::test_reproduce_quick; the b* figures of the summary are the theory's, checked in
# test_twobody_theory.py::test_physical_koenig_bstar_spec_value_and_explicit_formula and ::test_rotating_bstar_spec_value;
# convergence near s0 = -r0 in test_twobody_sweeps.py::test_near_unstable_and_b_rate_end_to_end and
# test_twobody_dynamics.py::test_starts_near_unstable_equilibria_leave
@pytest.mark.slow
def test_reproduce_quick(tmp_path):
    files = get_reproducer("twobody")(tmp_path, quick=True)
    assert files and all(f.exists() and f.stat().st_size > 0 for f in files)
    text = (tmp_path / "summary.txt").read_text()
    bstar = [float(x) for x in re.findall(r"b\* physical ([0-9.]+)", text)]
    assert len(bstar) == 2 and abs(bstar[0] - 2.3458) < 2e-4 and abs(bstar[1] - 3.1005) < 2e-3  # docs/models/twobody.md
    # Theorem 1 starts over the sphere and near s0 = -r0 all converge
    lines = [ln for ln in text.splitlines() if ln.startswith("Thm 1")]
    assert len(lines) == 2 and all("converged 1.000" in ln for ln in lines)


def test_one_name_per_paper():
    """`stabjax reproduce NAME` writes results/NAME by default: NAME is its module's name and the folder of its
    shipped figures (the two-body paper was 'two-body' here and 'twobody' in every folder and module)."""
    from pathlib import Path

    from stabjax.model.registry import REPRODUCE

    root = Path(__file__).resolve().parents[2]
    for name, target in REPRODUCE.items():
        assert target == f"stabjax.reproduce.{name}:run"
        assert (root / "results" / name).is_dir()
