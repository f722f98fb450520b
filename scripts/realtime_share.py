"""The real-time share of the test suite: how many test functions run on the real clock.

Runs pytest with the probe plugin ``tests.realtime_share`` (its docstring defines ``real``,
``virtual`` and ``pure``) and prints one line: the counts and the share of ``real`` tests;
``--list`` also prints every real test with what made it real. ``--from FILE`` summarises the
lines of an earlier run instead (``FLEETGATE_REALTIME_SHARE=FILE pytest -p
tests.realtime_share ...`` writes them, e.g. beside a full suite run).

    .venv/bin/python scripts/realtime_share.py -- -n 0 -p no:randomly tests/sim
    .venv/bin/python scripts/realtime_share.py --from /tmp/share.jsonl --list
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path


def summary(lines: list[dict[str, object]]) -> str:
    """One line: counts per kind and the real share (a test counted once, its last line)."""
    kinds = Counter(str(r["kind"]) for r in {str(r["test"]): r for r in lines}.values())
    total = sum(kinds.values())
    share = kinds["real"] / total if total else 0.0
    return (f"{total} tests: real {kinds['real']}, virtual {kinds['virtual']}, pure "
            f"{kinds['pure']}; real-time share {share:.1%}")


def main() -> int:
    """Run (or read) and print the summary; pytest's exit code when it ran."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--from", dest="source", type=Path, help="summarise this file's lines")
    p.add_argument("--list", action="store_true", help="also list the real tests")
    p.add_argument("pytest_args", nargs="*", help="passed to pytest (after --)")
    args = p.parse_args()
    rc = 0
    if args.source is None:
        fd, name = tempfile.mkstemp(suffix=".jsonl")
        os.close(fd)
        source = Path(name)
        env = {**os.environ, "FLEETGATE_REALTIME_SHARE": str(source)}
        rc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "tests.realtime_share",
                             *args.pytest_args], env=env, check=False).returncode
    else:
        source = args.source
    try:
        lines = [json.loads(x) for x in source.read_text(encoding="utf-8").splitlines() if x]
    except (OSError, ValueError) as exc:
        print(f"realtime_share: cannot read {source}: {exc}", file=sys.stderr)
        return 2
    finally:
        if args.source is None:
            source.unlink(missing_ok=True)
    if args.list:
        for r in sorted(lines, key=lambda r: str(r["test"])):
            if r["kind"] == "real":
                print(f"{r['test']}: {', '.join(map(str, r['why']))}")
    print(summary(lines))
    return rc


if __name__ == "__main__":
    sys.exit(main())
