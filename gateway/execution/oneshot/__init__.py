"""One-shot execution: a whole plan up front, its ADG, the retiming executor, the slack
monitor and the replanning policies."""
