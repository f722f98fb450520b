"""The fuzzer's test mode (bench/fuzz.py benchmarks 100,000 frames): 3,000 hostile frames
(hypothesis messages from the protocol models, their mutations, byte-level mutations and
attacks) against a live gateway's websockets while a well-behaved fleet runs in virtual time:
no handler exception, a reply with a code (or a documented close) for the bad frames, and the
fleet's run exactly as without the fuzzer (same SOC, clean trace)."""

from __future__ import annotations

from bench.fuzz import run_fuzz
from gateway.server.clock import run_virtual
from protocol import CloseCode, ErrorCode


def test_fuzzing_a_live_gateway_changes_nothing_for_the_fleet() -> None:
    result = run_virtual(run_fuzz(3000, seed=1, per_run=3000))
    assert result["handler_exceptions"] == 0, result["exception_samples"]
    assert result["sent"] >= 2500
    assert result["soc_ms_fuzzed"] == [result["soc_ms_undisturbed"]]
    assert result["soc_ms_undisturbed"] == 1000.0 * result["plan_soc"]
    assert result["trace_errors"] == 0 and result["collisions"] == 0
    replies = result["replies"]
    for code in (ErrorCode.MALFORMED, ErrorCode.INVALID, ErrorCode.TOO_LARGE,
                 ErrorCode.UNKNOWN_TYPE, ErrorCode.UNSUPPORTED_VERSION, ErrorCode.FORBIDDEN):
        assert replies.get(code.value, 0) > 0, (code, replies)
    assert set(replies) <= {c.value for c in ErrorCode} | {"ok", "welcome"}
    documented = {str(int(c)) for c in CloseCode}
    assert set(result["closes"]) <= documented, result["closes"]
    assert result["refused"].get(403, 0) > 0  # bad tokens and foreign Origins
