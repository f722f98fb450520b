"""Simulated robots, world occupancy, intruder, virtual-time runner and experiment campaigns."""
