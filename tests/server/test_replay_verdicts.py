"""Replay decides every journaled input as it was decided live (issue 26): a report the executor
refused live is journaled with a ``rejected`` record after it and refused again; any other is
accepted again. A journal edited so that replay would decide otherwise, its checksums and seal
recomputed (a writer using the journal's own code), is refused with one line naming the record
(exit 2), never resumed in a state the robots were not told of."""

from __future__ import annotations

import asyncio
import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from websockets.asyncio.client import connect

from gateway.runtime.journal import GENESIS, SEAL_BYTES, chain_next
from gateway.server.gateway import Gateway
from protocol import Action, ErrorCode, Finished, LoadPlan, Start, Started
from tests.server.conftest import LAB_PATHS, make_config
from tests.server.robots import TestRobot


def _journal_with_a_refusal(path: Path) -> None:
    """A run whose robot reported ``finished`` of its first action before ``started`` (refused
    live), then started and finished it."""

    async def main() -> None:
        async with Gateway(make_config(journal=path, policy="none")) as gw:
            await gw.listen()
            code, detail = await gw.command(LoadPlan(msg_id="l", seq=0, map="lab",
                                                     paths=LAB_PATHS[:1]))
            assert code is None, detail
            robot = TestRobot(await connect(
                f"ws://127.0.0.1:{gw.port}/ws", proxy=None,
                additional_headers={"Authorization": "Bearer demo-robot-0"}), 0)
            await robot.hello()
            await gw.command(Start(msg_id="s", seq=1))
            first: Action = await robot.expect(Action)
            early = await robot.send(Finished, action_id=first.action_id, pose=first.dst)
            assert (await robot.error_for(early)).code == ErrorCode.REJECTED
            await robot.send(Started, action_id=first.action_id, pose=first.src)
            await robot.send(Finished, action_id=first.action_id, pose=first.dst)
            await robot.expect(Action)  # the next one: the finish was taken
            await robot.link.close()

    asyncio.run(main())


def _rows(path: Path) -> list[tuple[int, str, dict[str, object]]]:
    with sqlite3.connect(path) as db:
        return [(seq, kind, json.loads(body)) for seq, kind, body in
                db.execute("SELECT seq, kind, body FROM records ORDER BY seq")]


def _rewrite(path: Path, rows: list[tuple[int, str, dict[str, object]]]) -> None:
    """Write ``rows`` as the journal's records, chained and sealed as the journal would."""
    chain = GENESIS
    with sqlite3.connect(path) as db:
        db.execute("DELETE FROM records")
        for seq, kind, rec in rows:
            body = json.dumps(rec, separators=(",", ":"))
            chain = chain_next(chain, kind, body)
            db.execute("INSERT INTO records (seq, kind, body, chain) VALUES (?, ?, ?, ?)",
                       (seq, kind, body, chain))
    path.with_name(path.name + ".seal").write_bytes(
        json.dumps([[len(rows), chain]]).encode().ljust(SEAL_BYTES))


def _reports(rows: list[tuple[int, str, dict[str, object]]]) -> list[int]:
    """Positions (0-based) of the report records."""
    return [i for i, (_, kind, _) in enumerate(rows) if kind == "report"]


def test_a_report_refused_live_is_journaled_as_refused_and_the_run_resumes(
        tmp_path: Path) -> None:
    path = tmp_path / "journal.sqlite"
    _journal_with_a_refusal(path)
    rows = _rows(path)
    early, started, finished = _reports(rows)[:3]
    assert [rows[i][2]["event"] for i in (early, started, finished)] == \
        ["finished", "started", "finished"]
    assert rows[early + 1][1] == "rejected"  # right after the input it answers

    async def resume() -> None:
        gw = Gateway(make_config(journal=path, policy="none"))
        await gw.start()
        try:
            assert gw.resumed
            assert gw.engine.robot(0).next_index == 1  # the finish taken live, once
        finally:
            await gw.stop()

    asyncio.run(resume())


@pytest.mark.parametrize("edit", ["marker deleted", "accepted report edited",
                                  "refused report edited"])
def test_a_journal_that_replays_otherwise_is_refused_naming_the_record(
        tmp_path: Path, edit: str) -> None:
    path = tmp_path / "journal.sqlite"
    _journal_with_a_refusal(path)
    rows = _rows(path)
    early, started, _ = _reports(rows)[:3]
    if edit == "marker deleted":  # the early finish now reads as accepted
        del rows[early + 1]
        bad, verdict = early + 1, "was accepted, but replay refuses it"
    elif edit == "accepted report edited":  # started -> finished of an action not started
        rows[started][2]["event"] = "finished"
        bad, verdict = started + 1, "was accepted, but replay refuses it"
    else:  # the refused early finish -> a started, which replay accepts
        rows[early][2]["event"] = "started"
        bad, verdict = early + 1, "was refused, but replay accepts it"
    _rewrite(path, rows)
    config = tmp_path / "gateway.json"
    config.write_text(json.dumps({"port": 0, "policy": "none", "dispatch_lookahead": 0,
                                  "close_timeout_s": 1.0}))
    done = subprocess.run([sys.executable, "-m", "gateway", "serve", "--config", str(config),
                           "--journal", str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert f"record {bad} of the journal does not replay: its report {verdict}" in lines[0]
