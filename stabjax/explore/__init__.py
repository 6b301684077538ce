"""Searches built on the runner: adaptive boundary refinement."""
