"""The independent trace checker on hand-written traces: it accepts a correct one and catches
every kind of corruption it promises to (DESIGN section 3)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gateway.execution.trace_records import (
    event_record,
    intruder_record,
    plan_record,
    reschedule_record,
    summary_record,
)
from gateway.runtime.trace import JsonlWriter
from tracecheck import build_graph, check_trace, main, read_trace, slack_series

# Robot 0 moves right twice; robot 1 waits twice then enters (1,0), which robot 0 leaves in
# its action 1 (a 1-robust plan). ADG: Type 1 chains plus the Type 2 edge a_1^0 -> a_2^1.
PATHS = [[(0, 0), (1, 0), (2, 0)], [(1, 1), (1, 1), (1, 1), (1, 0)]]


def ev(t: float, kind: str, robot: int, action: int, plan: int = 0) -> dict:
    return event_record(t, kind, plan, robot, action)


def run(robot: int, action: int, t0: float, t1: float, plan: int = 0) -> list[dict]:
    return [ev(t0, "dispatch", robot, action, plan), ev(t0, "start", robot, action, plan),
            ev(t1, "finish", robot, action, plan)]


def ordered(*records: dict) -> list[dict]:
    """The records in time order (stable), the summary last."""
    return sorted(records, key=lambda r: r.get("t_ms", float("inf")))


def good_trace() -> list[dict]:
    # both robots run undelayed: robot 0 ends at 2000, robot 1 at 3000 => SOC 5000
    return ordered(plan_record(0, 0, PATHS), *run(0, 0, 0, 1000), *run(1, 0, 0, 1000),
                   *run(0, 1, 1000, 2000), *run(1, 1, 1000, 2000), *run(1, 2, 2000, 3000),
                   summary_record(5000, 3000))


def test_graph_has_the_type2_edge() -> None:
    g = build_graph(0, 0.0, PATHS)
    assert g.preds[(1, 2)] == [(1, 1), (0, 1)]
    assert g.type2_in[(1, 2)] == [(0, 1)]
    assert all(g.type2_in[a] == [] for a in g.type2_in if a != (1, 2))


def test_correct_trace_passes_and_measures() -> None:
    report = check_trace(good_trace())
    assert report.ok, report.errors
    assert (report.plans, report.actions_run, report.soc_ms, report.makespan_ms) == (
        1, 5, 5000, 3000)


def test_action_before_predecessor_and_shared_cell_are_caught() -> None:
    # robot 0's action 1 is slow (finishes at 2500); robot 1 enters (1,0) at 2000 anyway
    bad = ordered(plan_record(0, 0, PATHS), *run(0, 0, 0, 1000), *run(1, 0, 0, 1000),
                  *run(1, 1, 1000, 2000), ev(1000, "dispatch", 0, 1), ev(1000, "start", 0, 1),
                  ev(2000, "dispatch", 1, 2), ev(2000, "start", 1, 2), ev(2500, "finish", 0, 1),
                  ev(3000, "finish", 1, 2), summary_record(5500, 3000))
    report = check_trace(bad)
    assert not report.ok
    assert any("started before its predecessors [(0, 1)]" in e for e in report.errors)
    assert [(c.t_ms, c.cell, c.who, c.holders) for c in report.collisions] == [
        (2000, (1, 0), "robot 1", ("robot 0",))]


def test_a_reschedule_may_not_add_a_dependency_to_a_dispatched_action_or_a_cycle() -> None:
    start = [plan_record(0, 0, PATHS), ev(0, "dispatch", 0, 0), ev(0, "dispatch", 1, 0)]
    late = check_trace([*start, reschedule_record(0, 0, [(0, 1, 1, 2), (1, 1, 0, 0)], [], 0)])
    assert any("action (0, 0) gains predecessors [(1, 1)] after its dispatch" in e
               for e in late.errors)
    cycle = check_trace([*start, reschedule_record(0, 0, [(0, 1, 1, 2), (1, 2, 0, 1)], [], 0)])
    assert any("the rescheduled graph has a cycle" in e for e in cycle.errors)
    # the same edges as the plan's are a reschedule that changes nothing
    same = check_trace([plan_record(0, 0, PATHS),
                        reschedule_record(0, 0, [(0, 1, 1, 2)], [], 0), *good_trace()[1:]])
    assert same.ok, same.errors


def test_two_robots_on_one_cell_without_precedence_error() -> None:
    # a plan whose two robots both walk into (1,0) at the same time is not 1-robust: no edge
    # orders them, so only the occupancy replay sees the collision
    paths = [[(0, 0), (1, 0)], [(2, 0), (1, 0)]]
    trace = [plan_record(0, 0, paths), ev(0, "dispatch", 0, 0), ev(0, "dispatch", 1, 0),
             ev(0, "start", 0, 0), ev(0, "start", 1, 0), ev(1000, "finish", 0, 0),
             ev(1000, "finish", 1, 0), summary_record(2000, 1000)]
    report = check_trace(trace)
    assert report.errors == []
    assert len(report.collisions) == 1 and report.collisions[0].cell == (1, 0)


def test_intruder_on_a_robot_is_a_collision() -> None:
    trace = good_trace()
    trace.insert(1, intruder_record(0, (1, 1), "on"))
    trace.insert(-1, intruder_record(3000, (1, 1), "off"))
    report = check_trace(trace)
    assert [(c.who, c.holders) for c in report.collisions] == [("intruder", ("robot 1",))]


@pytest.mark.parametrize(("mutate", "message"), [
    (lambda t: t.pop(-2), "never finished"),                       # last finish missing
    (lambda t: t.insert(-1, ev(3000, "start", 1, 2)), "started twice"),
    (lambda t: t.__setitem__(-1, summary_record(4000, 3000)), "summary soc_ms"),
    (lambda t: t.pop(), "no summary"),
    (lambda t: t.insert(3, ev(500, "finish", 1, 2)), "not running"),
    (lambda t: t.insert(1, ev(0, "start", 0, 5)), "no action 5"),
    (lambda t: t.insert(-1, ev(10, "finish", 1, 2)), "time goes back"),
])
def test_corruptions_are_reported(mutate, message: str) -> None:  # type: ignore[no-untyped-def]
    trace = good_trace()
    mutate(trace)
    report = check_trace(trace)
    assert not report.ok
    assert any(message in e for e in report.errors), report.errors


def test_replan_must_start_where_robots_stand() -> None:
    # robot 0 stops after action 0 (on (1,0)); plan 1 claims it starts at (0,0)
    trace = ordered(plan_record(0, 0, PATHS), *run(0, 0, 0, 1000), *run(1, 0, 0, 1000),
                    ev(1000, "dispatch", 1, 1), ev(1000, "cancel", 1, 1),
                    plan_record(1000, 1, [[(0, 0), (1, 0)], [(1, 1), (1, 2)]]))
    report = check_trace(trace)
    assert any("robot 0 starts at (0, 0) but stands on (1, 0)" in e for e in report.errors)
    ok = trace[:-1] + ordered(plan_record(1000, 1, [[(1, 0), (2, 0)], [(1, 1), (1, 2)]]),
                              *run(0, 0, 1000, 2000, plan=1), *run(1, 0, 1000, 2000, plan=1),
                              summary_record(4000, 2000))
    report = check_trace(ok)
    assert report.ok, report.errors
    assert report.plans == 2 and report.soc_ms == 4000


def test_cancelled_action_may_be_dispatched_again_but_not_started_without() -> None:
    # robot 1 is blocked, its action 1 cancelled (a replan that was then abandoned) and
    # dispatched again: fine. Starting it while cancelled is not.
    head = [*ordered(plan_record(0, 0, PATHS), *run(0, 0, 0, 1000), *run(1, 0, 0, 1000)),
            ev(1000, "dispatch", 1, 1), ev(1000, "blocked", 1, 1), ev(1200, "cancel", 1, 1)]
    tail = [ev(1300, "start", 1, 1), ev(2300, "finish", 1, 1), *run(0, 1, 2300, 3300),
            *run(1, 2, 3300, 4300), summary_record(3300 + 4300, 4300)]
    report = check_trace([*head, ev(1300, "dispatch", 1, 1), *tail])
    assert report.ok, report.errors
    report = check_trace([*head, *tail])
    assert any("started without (a standing) dispatch" in e for e in report.errors)


def test_slack_over_time() -> None:
    # robot 0's action 1 starts at 1000 and has not finished at 2600: estimated to finish at
    # 2600 (clamped by the present), so robot 1's entry into (1,0), planned right after its
    # own action 1 ends at 2000, waits 600 ms more than planned: fleet slack 600.
    trace = ordered(plan_record(0, 0, PATHS), *run(0, 0, 0, 1000), *run(1, 0, 0, 1000),
                    *run(1, 1, 1000, 2000), ev(1000, "dispatch", 0, 1), ev(1000, "start", 0, 1))
    assert slack_series(trace, [0, 1500, 2000, 2600]) == [0.0, 0.0, 0.0, 600.0]


def test_file_round_trip_and_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "t.jsonl"
    with JsonlWriter(path) as w:
        for rec in good_trace():
            w(rec)
    assert read_trace(path) == json.loads(json.dumps(good_trace()))
    assert main([str(path)]) == 0
    assert "OK" in capsys.readouterr().out
    bad = [*good_trace()[:-2], summary_record(5000, 3000)]
    with JsonlWriter(path) as w:
        for rec in bad:
            w(rec)
    assert main([str(path)]) == 1
    path.write_text('{"t_ms": 0}\nnot json\n')
    with pytest.raises(ValueError, match=r"t\.jsonl:2: not JSON"):
        read_trace(path)


# Turning: robot 0 on (0,0) facing north turns to east (its turns take 1500 ms), then drives
# to (2,0); robot 1 on (1,1) facing east turns north, waits twice and drives into (1,0) after
# robot 0 left it. ADG: Type 1 chains plus a_2^0 -> a_3^1; the turns enter no cell.
T_PATHS = [[(0, 0), (0, 0), (1, 0), (2, 0)], [(1, 1), (1, 1), (1, 1), (1, 1), (1, 0)]]
T_HEADS = [[3, 0, 0, 0], [0, 3, 3, 3, 3]]
T_DURATIONS = [{"move": 1000.0, "turn": 1500.0, "wait": 1000.0}, None]


def turning_trace(heads: list[list[int]] = T_HEADS) -> list[dict]:
    # robot 0: turn 0-1500, moves 1500-2500-3500; robot 1: turn 0-1000, waits to 3000, its
    # move waits for robot 0's a_2 (3500) and ends at 4500 => SOC 8000, makespan 4500
    return ordered(plan_record(0, 0, T_PATHS, heads, T_DURATIONS),
                   *run(0, 0, 0, 1500), *run(0, 1, 1500, 2500), *run(0, 2, 2500, 3500),
                   *run(1, 0, 0, 1000), *run(1, 1, 1000, 2000), *run(1, 2, 2000, 3000),
                   *run(1, 3, 3500, 4500), summary_record(8000, 4500))


def test_turning_trace_passes_with_kinds_and_durations() -> None:
    trace = turning_trace()
    assert trace[0]["motion"] == "turning" and trace[0]["agents"][0]["path"][1] == [0, 0, 0]
    report = check_trace(trace)
    assert report.ok, report.errors
    assert (report.actions_run, report.soc_ms, report.makespan_ms) == (7, 8000, 4500)
    g = build_graph(0, 0.0, T_PATHS, T_HEADS, [T_DURATIONS[0] or {}, {}])
    assert [g.kinds[(1, i)] for i in range(4)] == ["turn", "wait", "wait", "move"]
    assert g.type2_in[(1, 3)] == [(0, 2)] and g.type2_in[(0, 0)] == g.type2_in[(1, 0)] == []
    assert (g.tx[(0, 0)], g.tx[(1, 0)], g.tx[(0, 1)]) == (1500.0, 1000.0, 1000.0)
    # fleet slack: initially robot 1's move waits Δ0 = t_c(a_2^0) - t_c(a_2^1) = 3500 - 3000;
    # with robot 0's turn still running at 2000 (t_c clamped to 2000), its moves end at 3000
    # and 4000; robot 1's first wait (started at 1000) ends at 2000, its second at 3000, so its
    # move (not started) waits Δ = 4000 - 3000 = 1000: Δ̄F = 1000 - 500 = 500
    partial = [r for r in trace if (r.get("t_ms", 1e9) < 1500 and r["type"] != "finish")
               or r["type"] == "plan" or (r["type"] == "finish" and r["robot"] == 1
                                          and r["t_ms"] <= 1000)]
    assert slack_series(partial, [0.0, 2000.0]) == [0.0, 500.0]


@pytest.mark.parametrize(("heads", "message"), [
    ([[3, 1, 1, 1], T_HEADS[1]], "robot 0 action 0: turn 3 -> 1 on (0, 0) is not 90 degrees"),
    ([[2, 1, 1, 1], T_HEADS[1]], "robot 0 action 1: move (0, 0) -> (1, 0) is not one cell "
                                 "forward along heading 1"),
    ([[3, 3, 0, 0], T_HEADS[1]], "robot 0 action 1: move (0, 0) -> (1, 0) turns from 3 to 0"),
])
def test_illegal_turning_steps_are_reported(heads: list[list[int]], message: str) -> None:
    report = check_trace(turning_trace(heads))
    assert any(message in e for e in report.errors), report.errors


def test_turning_replan_must_start_from_the_held_headings() -> None:
    # after robot 0's turn and robot 1's turn, a new plan claims robot 1 still faces east
    head = [plan_record(0, 0, T_PATHS, T_HEADS), *run(0, 0, 0, 1000), *run(1, 0, 0, 1000)]
    replan = plan_record(1000, 1, [T_PATHS[0][1:], [(1, 1), (1, 1)]], [T_HEADS[0][1:], [0, 3]])
    tail = [*run(0, 0, 1000, 2000, plan=1), *run(0, 1, 2000, 3000, plan=1),
            *run(1, 0, 1000, 2000, plan=1), summary_record(5000, 3000)]
    report = check_trace(ordered(*head, replan, *tail))
    assert any("robot 1 starts with heading 0 but holds 3" in e for e in report.errors)
    good = plan_record(1000, 1, [T_PATHS[0][1:], [(1, 1), (1, 1)]], [T_HEADS[0][1:], [3, 0]])
    assert check_trace(ordered(*head, good, *tail)).ok
    omni = plan_record(1000, 1, [T_PATHS[0][1:], [(1, 1), (1, 1)]])
    assert any("motion model changed" in e
               for e in check_trace(ordered(*head, omni, *tail)).errors)


def test_the_command_reports_an_unreadable_trace_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(tmp_path / "missing.jsonl")]) == 2
    assert capsys.readouterr().err.startswith("tracecheck: cannot read ")
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"type": "plan"}\nnot json\n')
    assert main([str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"tracecheck: {bad}:2: not JSON") and err.count("\n") == 1


def test_skipped_waits_are_no_actions() -> None:
    # Robot 1 skips its two waits: its move into (1,0) follows robot 0's move out directly.
    g = build_graph(0, 0.0, PATHS, skips=[[], [0, 1]])
    assert set(g.preds) == {(0, 0), (0, 1), (1, 2)} and g.preds[(1, 2)] == [(0, 1)]
    record = plan_record(0, 0, PATHS, skip={(1, 0), (1, 1)})
    assert record["agents"][1]["skip"] == [0, 1] and "skip" not in record["agents"][0]
    trace = ordered(record, *run(0, 0, 0, 1000), *run(0, 1, 1000, 2000),
                    *run(1, 2, 2000, 3000), summary_record(5000, 3000))
    report = check_trace(trace)
    assert report.ok, report.errors
    # Without the skip the same trace ran robot 1's move before its waits.
    unskipped = check_trace([plan_record(0, 0, PATHS), *trace[1:]])
    assert any("dispatched before" in e for e in unskipped.errors)
    # Only a wait can be skipped; and the move still waits for robot 0 to leave (1,0).
    bad = check_trace([plan_record(0, 0, PATHS, skip={(0, 0)}), *trace[1:]])
    assert any("skipped but is no wait" in e for e in bad.errors)
    early = ordered(record, *run(0, 0, 0, 1000), *run(1, 2, 1000, 2000),
                    *run(0, 1, 1000, 2000), summary_record(4000, 2000))
    assert any("(1, 2)" in e for e in check_trace(early).errors)
