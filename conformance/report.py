"""Check results and how they are reported: human text, JSON and JUnit XML."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from fleetgate.userio.files import atomic_open

EXIT_PASSED = 0
"""Every required check passed."""
EXIT_FAILED = 1
"""At least one required check failed."""
EXIT_USAGE = 2
"""Bad invocation, or the target cannot be reached or refuses the given credentials."""


@dataclass(frozen=True)
class CheckResult:
    """The outcome of one named check; ``rule`` is the id of the rule in docs/protocol.md."""

    name: str
    rule: str
    required: bool
    passed: bool
    detail: str


class CheckFailed(Exception):
    """A check found the implementation breaking its rule (the message says how)."""


class UsageProblem(Exception):
    """The checker cannot run as invoked (bad option, unreachable target): one line, exit 2."""


def all_required_passed(results: Sequence[CheckResult]) -> bool:
    """True if no required check failed."""
    return all(r.passed or not r.required for r in results)


def exit_code(results: Sequence[CheckResult]) -> int:
    """0 if every required check passed, else 1."""
    return EXIT_PASSED if all_required_passed(results) else EXIT_FAILED


def as_json(results: Sequence[CheckResult]) -> str:
    """``{"passed": bool, "checks": [{"name", "rule", "required", "passed", "detail"}]}``."""
    return json.dumps({"passed": all_required_passed(results),
                       "checks": [asdict(r) for r in results]}, indent=2)


def as_text(results: Sequence[CheckResult], target: str) -> str:
    """One line per check, then a summary line."""
    lines = [f"fleetgate conformance: {target}"]
    for r in results:
        mark = "PASS" if r.passed else ("FAIL" if r.required else "warn")
        kind = "" if r.required else " (optional)"
        lines.append(f"  {mark}  {r.name} [{r.rule}]{kind}")
        if not r.passed:
            lines.append(f"        {r.detail}")
    failed = [r for r in results if not r.passed and r.required]
    warned = [r for r in results if not r.passed and not r.required]
    verdict = "CONFORMS" if not failed else "DOES NOT CONFORM"
    lines.append(f"{verdict}: {len(results) - len(failed) - len(warned)} passed, "
                 f"{len(failed)} required failed, {len(warned)} optional failed "
                 f"({len(results)} checks)")
    return "\n".join(lines)


def write_junit(results: Sequence[CheckResult], suite: str, path: Path) -> None:
    """A JUnit XML file: one test case per check; failed optional checks are ``skipped``
    with their detail (CI tools show them without failing the build)."""
    failures = sum(1 for r in results if not r.passed and r.required)
    skipped = sum(1 for r in results if not r.passed and not r.required)
    root = ET.Element("testsuite", name=suite, tests=str(len(results)),
                      failures=str(failures), errors="0", skipped=str(skipped))
    for r in results:
        case = ET.SubElement(root, "testcase", classname=f"{suite}.{r.rule}", name=r.name)
        if not r.passed:
            tag = "failure" if r.required else "skipped"
            ET.SubElement(case, tag, message=r.detail).text = r.detail
    with atomic_open(path, "wb") as f:
        ET.ElementTree(root).write(f, encoding="utf-8", xml_declaration=True)
