"""One module per model (state, right-hand side, equilibria, error metric) and one per
paper's theorems (vectorised predicates)."""
