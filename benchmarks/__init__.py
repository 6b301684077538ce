"""Benchmarks of stabjax against named baselines: research code run from a source checkout
(``python -m benchmarks.bench`` or ``stabjax bench`` at the top of a clone), never installed with the package."""
