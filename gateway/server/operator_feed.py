"""What a run tells the outside: the operators' event stream and series, and the trace file.

The engine hands every executor trace record, status change, fleet-slack sample, connection
change and intruder report to one :class:`OperatorFeed`; it writes the run's trace (DESIGN
section 3) and sends operators their events, and keeps what a snapshot shows besides the
executor (the slack series, the replan marks, the intruders).

The trace is only ever appended to: records are buffered and written, then flushed, by
:meth:`OperatorFeed.flush_trace` (the engine calls it right after each journal commit, so the
trace never runs ahead of the journal). A new run moves an existing trace file aside
(``NAME.1``, ``NAME.2``, ...) rather than truncating it; a resumed run appends to it
(:meth:`OperatorFeed.resume_trace` first adds what the journal holds and the file lacks, and
cuts what the journal lost).
"""

from __future__ import annotations

import contextlib
import itertools
from collections import deque
from pathlib import Path
from typing import IO, Any, get_args

from gateway.execution.trace_records import intruder_record
from gateway.planning.grid import Cell
from gateway.runtime.trace import trace_line
from gateway.server.wire.session import Session
from protocol import Event
from protocol.messages import EventKind

EVENT_KINDS = frozenset(get_args(EventKind))
"""Trace records operators are sent as events (others, e.g. a lifelong segment, are trace
only)."""


class OperatorFeed:
    """Operators' events and series, and the trace file of the current run."""

    def __init__(self, slack_series_len: int, trace: Path | None) -> None:
        self.operators: set[Session] = set()
        self.slack_series: deque[tuple[float, float]] = deque(maxlen=slack_series_len)
        self.replan_marks: list[dict[str, Any]] = []
        """The current run's replans (fields of protocol.ReplanMark)."""
        self.intruders: set[Cell] = set()
        self._trace_path = trace
        self._trace: IO[str] | None = None
        self._pending: list[str] = []
        self.trace_lines = 0
        """Records the current run's trace file holds (or will, once flushed)."""

    def event(self, kind: str, t_ms: float, **fields: Any) -> None:
        """Send every operator an ``event``."""
        for op in list(self.operators):
            op.send(Event, event=kind, t_ms=t_ms, **fields)

    def new_run(self) -> None:
        """A run starts: fresh series and marks, a fresh trace file (if configured; an
        existing one is moved aside, never truncated)."""
        self.slack_series.clear()
        self.replan_marks.clear()
        self.close_trace()
        path = self._trace_path
        if path is not None:
            if path.exists() and path.stat().st_size > 0:
                for n in itertools.count(1):
                    aside = path.with_name(f"{path.name}.{n}")
                    if not aside.exists():
                        path.rename(aside)
                        break
            self._trace = path.open("a", encoding="utf-8")
        self.trace_lines = 0

    def resume_trace(self, records: list[str], skip: int = 0) -> None:
        """A resumed run: reopen its trace for appending, after adding the tail of
        ``records`` (the run's trace after its first ``skip`` records, rebuilt by replay) that
        the file lacks (it is written after the journal, so a crash can leave it behind). A
        torn last line is completed the same way. A file ahead of the journal (a power cut lost
        the journal's last records, not the trace's) is cut back to what the journal holds:
        the trace never tells of what the resumed run does not stand behind."""
        self.close_trace()
        self._pending.clear()
        path = self._trace_path
        if path is None:
            return
        have = path.read_text(encoding="utf-8").splitlines(keepends=True) \
            if path.exists() else []
        if have and not have[-1].endswith("\n"):
            have.pop()
        del have[skip + len(records):]
        with path.open("w" if not have else "r+", encoding="utf-8") as f:
            f.seek(sum(len(line.encode()) for line in have))
            f.truncate()
        self._trace = path.open("a", encoding="utf-8")
        missing = records[max(0, len(have) - skip):]
        self.trace_lines = len(have) + len(missing)
        self._pending.extend(missing)
        self.flush_trace()

    def record(self, rec: dict[str, object]) -> None:
        """An executor trace record: to the trace file, and to operators as an event."""
        self.write_trace(rec)
        t_ms: Any = rec["t_ms"]
        kind = str(rec["type"])
        if kind == "trigger":
            self.replan_marks.append({"trigger_ms": float(t_ms), "policy": str(rec["policy"])})
        elif kind == "plan" and rec.get("plan") and self.replan_marks:
            self.replan_marks[-1].update(plan=rec["plan"], adopted_ms=float(t_ms))
        if not self.operators or kind not in EVENT_KINDS:
            return  # several records per action: build no event nobody would receive
        fields: dict[str, Any] = {k: v for k, v in rec.items()
                                  if k not in ("type", "t_ms", "agents", "motion", "lifelong")}
        agents: Any = rec.get("agents")
        if agents is not None:
            fields["paths"] = [[c[:2] for c in a["path"]] for a in agents]
            if rec.get("motion") == "turning":
                fields["headings"] = [[c[2] for c in a["path"]] for a in agents]
        self.event(kind, float(t_ms), **fields)

    def slack(self, t_ms: float, slack_ms: float) -> None:
        """A fleet-slack sample: kept (on change, or once a second) and sent."""
        series = self.slack_series
        if not series or series[-1][1] != slack_ms or t_ms - series[-1][0] >= 1000.0:
            series.append((t_ms, slack_ms))
            self.event("slack", t_ms, fleet_slack_ms=slack_ms)

    def intruder(self, t_ms: float, cell: Cell, state: str) -> None:
        """The world reports an intruder on (or off) ``cell``."""
        if state == "on":
            self.intruders.add(cell)
        else:
            self.intruders.discard(cell)
        self.write_trace(intruder_record(t_ms, cell, state))
        self.event("intruder", t_ms, cell=cell, state=state)

    def write_trace(self, rec: dict[str, object]) -> None:
        """One record for the trace file (if one is open), written by :meth:`flush_trace`."""
        if self._trace is not None:
            self._pending.append(trace_line(rec))
            self.trace_lines += 1

    def flush_trace(self) -> None:
        """Write and flush the buffered records (after the journal committed their cause)."""
        if self._pending and self._trace is not None:
            self._trace.write("".join(self._pending))
            self._trace.flush()
        self._pending.clear()

    def close_trace(self) -> None:
        """Flush and close the trace file (the run is complete, or the gateway stops)."""
        if self._trace is not None:
            with contextlib.suppress(OSError):
                self.flush_trace()
                self._trace.close()
            self._trace = None
