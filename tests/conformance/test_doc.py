"""docs/protocol.md: its generated blocks are current, and every check cites one of its rules."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from conformance.doc import render
from conformance.gateway_checks import GATEWAY_CHECKS
from conformance.robot_checks import ROBOT_CHECKS
from gateway.cli import main

DOC = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"
RULE = re.compile(r"^- \*\*([A-Z]+-\d+)\*\*", re.M)


def test_generated_blocks_are_current() -> None:
    text = DOC.read_text()
    assert render(text) == text, (
        "docs/protocol.md is stale: run `fleetgate protocol schema --markdown docs/protocol.md`")


def test_the_command_rewrites_a_stale_document(tmp_path: Path) -> None:
    stale = tmp_path / "protocol.md"
    text = DOC.read_text()
    stale.write_text(text.replace('"title": "fleetgate protocol v1"', '"title": "old"'))
    assert main(["protocol", "schema", "--markdown", str(stale)]) == 0
    assert stale.read_text() == text


def test_a_document_without_markers_is_refused(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    bare = tmp_path / "bare.md"
    bare.write_text("# nothing generated here\n")
    assert main(["protocol", "schema", "--markdown", str(bare)]) == 2
    assert "GENERATED MESSAGE TABLE" in capsys.readouterr().err


def test_rule_ids_are_unique() -> None:
    ids = RULE.findall(DOC.read_text())
    assert len(ids) == len(set(ids)) > 60


def test_every_check_cites_a_rule_of_the_document() -> None:
    rules = set(RULE.findall(DOC.read_text()))
    checks = [*GATEWAY_CHECKS.checks, *ROBOT_CHECKS.checks]
    assert [c.name for c in checks if c.rule not in rules] == []
    assert len(checks) >= 40
    assert len({c.name for c in checks}) == len(checks)
    assert all(c.doc for c in checks), "every check says what it checks"
