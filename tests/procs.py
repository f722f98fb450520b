"""What the tests read about live processes from /proc."""

from __future__ import annotations

from pathlib import Path


def child_pids(pid: int) -> set[int]:
    """The processes ``pid`` started (from any of its threads) that are still there; empty
    once ``pid`` itself is gone."""
    found: set[int] = set()
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            found.update(int(c) for c in (task / "children").read_text().split())
    except OSError:  # it ended meanwhile
        pass
    return found
