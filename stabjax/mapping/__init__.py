"""From features to outcomes: outcome assignment, templates, attractor discovery and continuation, basin statistics and entropy."""
