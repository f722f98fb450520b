"""The README's checkable claims, checked: the test count, the conformance checks' count, the
exit codes, where the examples write, the ``--fallback`` example, and that a load-dependent
campaign command says so."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from fleetgate.userio.exits import EPILOG

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
OUTPUT_OPTIONS = ("--out", "--output", "-o", "--trace", "--junit", "--log-file", "--profile")


def _commands() -> list[list[str]]:
    """Every command line of the README's bash blocks (continuations joined, comments
    dropped), split as a shell would."""
    found = []
    for block in re.findall(r"```bash\n(.*?)```", README, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words:
                found.append(words)
    return found


def test_the_test_count_is_within_ten_percent() -> None:
    (claimed,) = re.findall(r"about ([\d,]+) tests", README)
    done = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q",
                           "-p", "no:randomly", "-p", "no:xdist", "tests"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600, check=False)
    (count,) = re.findall(r"^(\d+) tests? collected", done.stdout, flags=re.M)
    assert abs(int(count) - int(claimed.replace(",", ""))) <= 0.1 * int(count), (count, claimed)


def test_the_named_check_count_is_the_checklists() -> None:
    from conformance.gateway_checks import GATEWAY_CHECKS
    from conformance.robot_checks import ROBOT_CHECKS

    (claimed,) = re.findall(r"against it \((\d+) named\s+checks", README)
    assert int(claimed) == len(GATEWAY_CHECKS.checks) + len(ROBOT_CHECKS.checks)


def test_the_exit_codes_are_the_commands_own() -> None:
    assert EPILOG in README.replace("\n", " ")


def test_the_examples_write_only_into_scratch() -> None:
    assert "The examples below write only into\n`scratch/`" in README
    outputs = [(words, words[i + 1]) for words in _commands() for i, w in enumerate(words[:-1])
               if w in OUTPUT_OPTIONS and words[0] in ("fleetgate", "python")]
    assert outputs  # the check sees the examples
    assert [(" ".join(w), path) for w, path in outputs
            if not path.startswith("scratch/")] == []


def test_every_paper_campaign_without_solver_time_zero_is_said_to_depend_on_load() -> None:
    measured = [w for w in _commands() if w[:2] == ["fleetgate", "experiment"]
                and "--paper" in w and "zero" not in w]
    assert measured  # there are such commands, and then the README says what they depend on
    assert re.search(r"Without `--solver-time zero`.*depend on the machine's load", README,
                     flags=re.S)


@pytest.mark.slow
def test_the_fallback_example_falls_back(tmp_path: Path) -> None:
    lines = [w for w in _commands() if w[:3] == ["fleetgate", "maps", "generate"]
             or (w[:2] == ["fleetgate", "simulate"] and "--fallback" in w)]
    generate, simulate = lines
    (said,) = re.findall(r"\(`fleetgate:\s+(no optimal plan for [\w-]+ within \d+ s); using",
                         README)
    env = {**os.environ, "FLEETGATE_MAPS": ""}
    (tmp_path / "scratch").mkdir()
    for words in (generate, simulate):
        done = subprocess.run([sys.executable, "-m", "fleetgate", *words[1:]], cwd=tmp_path,
                              capture_output=True, text=True, timeout=300, env=env,
                              check=False)
        assert done.returncode == 0, done.stderr
    assert said in " ".join(done.stderr.split()), done.stderr
