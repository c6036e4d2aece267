"""Motion planners from the three seeds: pure functions, immutable profiles, no I/O."""
