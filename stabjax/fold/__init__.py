"""The fold compiled into every engine: what a trajectory keeps of its history (verdicts at every horizon, late-window features), when it may stop early, and what its solver status means."""
