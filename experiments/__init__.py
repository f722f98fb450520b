"""Experiment campaigns over the simulator: runs, statistics, plots and the
``fleetgate experiment`` command (DESIGN section 1: may import everything above it)."""
