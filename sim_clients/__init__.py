"""Simulated robots, world occupancy, intruder, the discrete-event simulator and the
virtual-time fleet runner."""
