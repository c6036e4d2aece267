"""The bench physics, the simulation loop (which owns the clock) and the CLI."""
