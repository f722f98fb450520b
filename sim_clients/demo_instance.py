"""The zero-setup demo's instance, shared by `fleetgate demo` and the benchmarks that replay
it (nothing may import the CLI modules)."""

from __future__ import annotations

DEFAULT_MAP, DEFAULT_SCEN, DEFAULT_AGENTS = "lab", "lab-random-4", 10
"""The zero-setup demo: 10 robots on the shipped lab map. Its seed-0 intruder blocks a robot
that others queue behind, the fleet slack passes 2 s at about 7.1 s and the replan saves about
3 s of SOC (virtual time: 95.2 s against 98.3 s without replanning), robustly in real time too."""
