"""fleetgate's master control against VDA 5050 vehicles it did not write: the virtual AGVs of
the npm package vda-5050-lib (2.0.0). Runs where ``node`` is installed and
``FLEETGATE_VDA5050_LIB`` names a node_modules folder holding that package (docs/vda5050.md
says how); skipped otherwise. The plan completes through the gateway, the trace passes the
independent checker, and every message on the broker validates against the 2.0.0 schemas."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from tests.vda5050.fleets import run_vda
from tests.vda5050.schemas import SCHEMA_DIR, schema_errors
from tracecheck import check_trace, read_trace

LIB = os.environ.get("FLEETGATE_VDA5050_LIB", "")

pytestmark = pytest.mark.skipif(
    shutil.which("node") is None or not (Path(LIB) / "vda-5050-lib").is_dir(),
    reason="needs node and FLEETGATE_VDA5050_LIB=<node_modules with vda-5050-lib>")


async def test_plan_with_vda_5050_lib_virtual_agvs(broker_url: str, tmp_path: Path) -> None:
    run = await run_vda(tmp_path / "t.jsonl", broker_url, "warehouse-small",
                        "warehouse-small-random-1", 10, list(range(10)),
                        versions=("2.0.0",), external=Path(LIB), timeout_s=180)
    report = check_trace(read_trace(tmp_path / "t.jsonl"))
    assert report.ok, report.errors
    assert report.actions_run > 100 and run.soc_ms > 0
    states = [json.loads(p) for t, p in run.traffic if t.endswith("/state")]
    assert states and all(s["errors"] == [] for s in states[-10:])
    if (SCHEMA_DIR / "2.0.0").is_dir():
        bad = {t.rsplit("/", 1)[-1]: schema_errors("2.0.0", t.rsplit("/", 1)[-1], p)
               for t, p in run.traffic if t.rsplit("/", 1)[-1] in ("order", "instantActions")}
        assert not any(bad.values()), bad
