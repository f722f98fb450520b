"""The lifelong windowed planner in its own process, so it never holds the event loop's GIL.

:class:`PlannerProcess` starts one persistent worker process (``python -m
gateway.server.runs.planner_process``: a fresh interpreter that imports only the planner, with no
copy of the gateway's threads or sockets and no re-import of the caller's main module). The
worker builds the :class:`~gateway.execution.lifelong.executor.WindowPlanner` once (the grid's state
space and its cached distance tables live there; PIBT's priorities come with each request) and
then answers one
:class:`~gateway.execution.lifelong.executor.PlanRequest` at a time over a pair of pipes with its
:class:`~gateway.execution.lifelong.executor.Segment` and the CPU time the call took (what a virtual
clock charges). Only the request and the segment cross the pipes. Between calls the gateway
has it compute distance tables ahead (:class:`Warm`: the planner's own for the cells of
submitted tasks, and the scheduler's, sent back), so that neither the first planning calls
nor the gateway's event loop build them. ``start(wait=False)`` starts a worker without
waiting for it to be ready (a restarting gateway replays its journal meanwhile).

If the worker dies (killed, out of memory), :meth:`PlannerProcess.call` raises
:class:`PlannerDied` with one line saying so, and the next call starts a new worker (its
tables are computed again; it answers as the first would have: each request carries PIBT's
priorities and the call's random stream is its own). A planner error inside the worker
comes back as :class:`PlannerFailed` (one line). :meth:`PlannerProcess.close` ends the worker;
a worker whose gateway died ends by itself (its input pipe closes). The worker ignores the
terminal's Ctrl-C: its gateway shuts it down.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from array import array
from dataclasses import dataclass
from multiprocessing.connection import Connection

from gateway.execution.lifelong.executor import PlanRequest, Segment, WindowPlanner
from gateway.planning.grid import Grid
from gateway.planning.pibt import goal_tables

START_TIMEOUT_S = 120.0
"""How long a new worker may take to import and build its planner (a loaded machine)."""


class PlannerDied(RuntimeError):
    """The planner process ended during a call (the message says how)."""


class PlannerFailed(RuntimeError):
    """The planner raised inside its process (the message is its one-line error)."""


def serve(requests: Connection, answers: Connection) -> None:
    """The worker's loop: build the planner from the first message ``(grid, robots, turning,
    seed)``, say ready, then answer requests until told to stop (None) or the gateway's end
    of the pipe closes."""
    try:
        grid, n_robots, turning, seed = requests.recv()
    except (EOFError, OSError):
        return
    planner = WindowPlanner(grid, n_robots, turning, seed)
    answers.send(("ready", None, 0.0))
    while True:
        try:
            req = requests.recv()
        except (EOFError, OSError):
            return
        if req is None:
            return
        t0 = time.thread_time()
        try:
            answer: Segment | dict[int, array[int]] = (
                warm(planner, req) if isinstance(req, Warm) else planner(req))
        except Exception as exc:  # a planner bug: one line back, the worker lives on
            answers.send(("error", f"{type(exc).__name__}: {exc}"[:300], 0.0))
            continue
        answers.send(("ok", answer, (time.thread_time() - t0) * 1000.0))


@dataclass(frozen=True)
class Warm:
    """Tables to compute before they are asked for: the planner's own tables of the cells
    ``goals`` (kept in the worker), and the scheduler's (``omni``) tables of the cells
    ``tables`` (sent back: :meth:`~gateway.planning.pibt.StateSpace.offer`)."""

    goals: tuple[int, ...]
    tables: tuple[int, ...]


def warm(planner: WindowPlanner, req: Warm) -> dict[int, array[int]]:
    """Carry out ``req`` in the worker: the scheduler's tables, by cell."""
    planner.space.prefetch(req.goals)
    return goal_tables(planner.space.grid, False, req.tables)


class PlannerProcess:
    """A persistent worker process running the windowed planner (see the module doc). Calls
    are serialised (one planner call at a time, as the executor asks)."""

    def __init__(self, grid: Grid, n_robots: int, turning: bool, seed: int = 0) -> None:
        self._args = (grid, n_robots, turning, seed)
        self._lock = threading.Lock()
        self._proc: subprocess.Popen[bytes] | None = None
        self._send: Connection | None = None
        self._recv: Connection | None = None
        self._ready = False
        self.starts = 0
        """Worker processes started so far (a replaced worker counts again)."""
        self.closed = False

    @property
    def pid(self) -> int | None:
        """The live worker's process id (None: none running)."""
        proc = self._proc
        return proc.pid if proc is not None and proc.poll() is None else None

    def start(self, wait: bool = True) -> None:
        """Start the worker and wait until it has built its planner (PlannerDied, one line,
        if it cannot); with ``wait`` False, do not wait: the first call does (a restarted
        gateway replays its journal meanwhile)."""
        with self._lock:
            try:
                send, recv = self._ensure()
                if wait:
                    self._handshake(send, recv)
            except (EOFError, OSError, PlannerDied) as exc:
                raise PlannerDied(self._died(exc)) from None

    def _handshake(self, send: Connection, recv: Connection) -> None:
        if not self._ready:
            if not recv.poll(START_TIMEOUT_S):
                raise PlannerDied(f"the planner process did not start within "
                                  f"{START_TIMEOUT_S:.0f} s")
            recv.recv()
            self._ready = True

    def _ensure(self) -> tuple[Connection, Connection]:
        if self.closed:
            raise PlannerDied("the planner process is closed (the gateway is closing)")
        if self._send is None or self._recv is None:
            to_worker_r, to_worker_w = os.pipe()
            from_worker_r, from_worker_w = os.pipe()
            try:
                self._proc = subprocess.Popen(
                    [sys.executable, "-m", "gateway.server.runs.planner_process",
                     str(to_worker_r), str(from_worker_w)],
                    stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                    pass_fds=(to_worker_r, from_worker_w),  # stderr: its one-line errors
                    process_group=0)  # Ctrl-C on a terminal is the gateway's, which ends it

            finally:
                os.close(to_worker_r)
                os.close(from_worker_w)
            self._send = Connection(to_worker_w, readable=False)
            self._recv = Connection(from_worker_r, writable=False)
            self._ready = False
            self.starts += 1
            with contextlib.suppress(OSError):  # it died at once: the call says so
                self._send.send(self._args)
        return self._send, self._recv

    def call(self, req: PlanRequest) -> tuple[Segment, float]:
        """The segment for ``req`` and the worker's CPU ms for it (blocks until answered)."""
        segment, cpu_ms = self._ask(req)
        assert isinstance(segment, Segment)
        return segment, cpu_ms

    def warm(self, req: Warm) -> dict[int, array[int]]:
        """Have the worker compute the tables ``req`` names (blocks until done): the
        scheduler's, by cell (a planner call waits for this one: keep them small)."""
        tables, _ = self._ask(req)
        assert isinstance(tables, dict)
        return tables

    def _ask(self, req: PlanRequest | Warm) -> tuple[object, float]:
        with self._lock:
            send, recv = self._ensure()
            try:
                self._handshake(send, recv)
                send.send(req)
                kind, payload, cpu_ms = recv.recv()
            except (EOFError, OSError, PlannerDied) as exc:
                raise PlannerDied(self._died(exc)) from None
            if kind == "error":
                raise PlannerFailed(str(payload))
            return payload, cpu_ms

    def _died(self, exc: BaseException) -> str:
        """Forget the worker (the next call starts a new one); say how it ended."""
        proc = self._proc
        self._drop()
        if proc is None:
            return str(exc)
        if isinstance(exc, PlannerDied):  # it hangs: end it
            proc.kill()
        try:
            code: int | None = proc.wait(5.0)
        except subprocess.TimeoutExpired:
            code = None
        how = (str(exc) if isinstance(exc, PlannerDied) else
               f"killed by signal {-code}" if code is not None and code < 0 else
               f"exit code {code}")
        return (f"the planner process (pid {proc.pid}) died ({how}); the next period plans "
                "again in a new one")

    def _drop(self) -> None:
        for conn in (self._send, self._recv):
            if conn is not None:
                conn.close()
        self._proc = self._send = self._recv = None

    def close(self) -> None:
        """End the worker: it stops after its current call (killed if that takes over a
        second). Idempotent; a call waiting in another thread gets :class:`PlannerDied`."""
        self.closed = True
        proc, send = self._proc, self._send
        if send is not None:
            with contextlib.suppress(OSError):
                send.send(None)
        if proc is not None:
            try:
                proc.wait(1.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5.0)
        if self._lock.acquire(blocking=False):  # no call is using the pipes
            try:
                self._drop()
            finally:
                self._lock.release()


def main() -> int:
    """The worker process: ``python -m gateway.server.runs.planner_process IN_FD OUT_FD``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the gateway ends it
    try:
        serve(Connection(int(sys.argv[1]), writable=False),
              Connection(int(sys.argv[2]), readable=False))
    except (BrokenPipeError, EOFError):  # the gateway is gone (it exited, or was killed)
        return 0
    except Exception as exc:  # one line, never a traceback
        print(f"fleetgate planner process: {type(exc).__name__}: {exc}"[:300],
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    # this module by its name, not as __main__: its classes are the ones the gateway pickles
    from gateway.server.runs.planner_process import main as worker_main

    sys.exit(worker_main())
