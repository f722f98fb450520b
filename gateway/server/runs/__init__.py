"""Runs: one-shot and lifelong, their journals and replay, and their planners off the loop."""
