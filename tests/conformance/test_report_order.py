"""REPORT-5, the order of one action's reports, as the robot checker reads it (a table of
sequences written by hand from the rule)."""

from __future__ import annotations

import pytest

from conformance.robot_checks import _valid_reports

CASES = [
    ("started finished", False, True),
    ("blocked unblocked blocked unblocked started finished", False, True),
    ("blocked started finished", False, True),
    ("cancelled", False, True),
    ("blocked cancelled", False, True),
    ("started finished finished", False, True),  # a finished repeated for a duplicate
    ("finished", False, False),  # finished before started
    ("started started finished", False, False),
    ("started cancelled", True, False),  # a moving robot finishes
    ("cancelled started", False, False),
    ("started blocked unblocked finished", False, False),  # v1 or a wait: no stop on the way
    ("started blocked unblocked finished", True, True),  # v2 move stopped on the way
    ("started blocked cancelled", True, True),  # stopped, then cancelled by a replan
    ("started blocked finished", True, False),  # a stop ends with unblocked first
]


@pytest.mark.parametrize(("kinds", "moving_stops", "valid"), CASES)
def test_report_sequences(kinds: str, moving_stops: bool, valid: bool) -> None:
    assert _valid_reports(kinds.split(), moving_stops) is valid
