"""Opening the gateway's journal: one writer, and only for the configuration it was made with.

:func:`open_journal` takes the journal's lock (:class:`~gateway.runtime.journal.JournalLock`: a
second gateway on the same file is refused, naming the holder's pid), abandons the journaled run
if asked (``--fresh``), and compares the configuration's fingerprint (:func:`fingerprint`: the
mode and what the run is made of: map, scenario, robots, instance, or the shift's settings)
with the one journaled: a journal of another configuration is refused with one line naming the
difference (never deleted), unless ``--fresh``.
"""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path

from gateway.runtime.journal import Journal, JournalError, JournalLock
from gateway.server.config import GatewayConfig

log = logging.getLogger("fleetgate.journal")

_SHIFT_FIELDS = ("problem", "map", "robots", "warehouse", "seed", "scheduler", "planner",
                 "period_ms", "window", "reveal", "task_list")
"""The lifelong settings a journaled shift is made of (its tuning, e.g. ``snapshot_segments``
or ``threshold_ms``, may change across a restart)."""


def _file_digest(path: Path | None) -> str:
    if path is None:
        return ""
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    except OSError:
        return "unreadable"


def fingerprint(cfg: GatewayConfig) -> dict[str, str]:
    """What the runs journaled under ``cfg`` are made of, as strings."""
    if cfg.lifelong is not None:
        s = cfg.lifelong
        out = {"mode": "lifelong"}
        for name in _SHIFT_FIELDS:
            value = getattr(s, name)
            out[name] = "" if value is None else str(value)
        out["map"] = cfg.shift_map or ""
        out["problem file"] = _file_digest(s.problem)
        return out
    return {"mode": "one-shot", "map": cfg.map or "", "scen": cfg.scen or "",
            "agents": "" if cfg.agents is None else str(cfg.agents),
            "instance": "" if cfg.instance is None else str(cfg.instance),
            "instance file": _file_digest(cfg.instance),
            "generate_seed": str(cfg.generate_seed)}


def difference(journaled: dict[str, str], configured: dict[str, str]) -> str:
    """The fields that differ, as ``name 'journaled' (journal) vs 'configured' (config)``."""
    names = sorted(set(journaled) | set(configured))
    return ", ".join(f"{n} {journaled.get(n, '')!r} (journal) vs {configured.get(n, '')!r} "
                     f"(config)" for n in names if journaled.get(n) != configured.get(n))


def open_journal(cfg: GatewayConfig, fresh: bool) -> tuple[Journal, JournalLock]:
    """The journal of ``cfg`` (locked), checked against ``cfg`` (:class:`JournalError` if it
    is in use or holds a run of another configuration), emptied first if ``fresh``."""
    assert cfg.journal is not None
    lock = JournalLock(cfg.journal)
    try:
        journal = Journal(cfg.journal)
    except JournalError:
        lock.release()
        raise
    try:
        want = fingerprint(cfg)
        if not fresh:  # before anything is written: a new seal would hide lost records
            journal.check_sealed()
        if fresh:
            journal.discard()
            log.warning("journaled run abandoned: starting fresh",
                        extra={"journal": str(cfg.journal)})
        elif journal.count():
            have = journal.fingerprint()
            if journal.legacy:
                raise JournalError(f"the journal {cfg.journal} was written by an earlier "
                                   f"fleetgate (records without checksums): start with --fresh "
                                   f"to abandon its run")
            if have is None:
                raise JournalError(f"the journal {cfg.journal} holds a run but no configuration "
                                   f"fingerprint: start with --fresh to abandon it")
            if have != want:
                raise JournalError(f"the journal {cfg.journal} holds a run of another "
                                   f"configuration: {difference(have, want)}; start with "
                                   f"--fresh to abandon it")
        if journal.fingerprint() != want:
            journal.set_fingerprint(want)
    except JournalError:
        journal.close()
        lock.release()
        raise
    return journal, lock
