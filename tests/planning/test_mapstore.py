"""Map name resolution and ``fleetgate maps download|list`` against a local HTTP server."""

from __future__ import annotations

import functools
import io
import json
import threading
import zipfile
from collections.abc import Iterator
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from gateway.runtime import mapstore
from tests.planning.fleetgate_cli import call, run

TINY_MAP = "type octile\nheight 1\nwidth 3\nmap\n...\n"
TINY_SCEN = "version 1\n0\ttiny-3-1.map\t3\t1\t0\t0\t2\t0\t2\n"


def _zip(members: dict[str, str]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, text in members.items():
            z.writestr(name, text)
    return buf.getvalue()


class _QuietHandler(SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:
        """Keep test output clean."""


@pytest.fixture
def server(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """A local HTTP server for MovingAI-style archives of the map ``tiny-3-1``."""
    root = tmp_path / "www"
    root.mkdir()
    (root / "tiny-3-1.map.zip").write_bytes(_zip({"tiny-3-1.map": TINY_MAP}))
    (root / "tiny-3-1.map-scen-random.zip").write_bytes(
        _zip({"scen-random/tiny-3-1-random-1.scen": TINY_SCEN, "scen-random/": ""}))
    (root / "tiny-3-1.map-scen-even.zip").write_bytes(
        _zip({"scen-even/tiny-3-1-even-1.scen": TINY_SCEN}))
    (root / "broken-1-1.map.zip").write_bytes(b"not a zip")
    handler = functools.partial(_QuietHandler, directory=str(root))
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, args=(0.05,), daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/", tmp_path
    httpd.shutdown()
    httpd.server_close()
    thread.join()


def test_download_extracts_map_and_scenarios_into_the_cache(server: tuple[str, Path]) -> None:
    url, tmp = server
    env = {"HOME": str(tmp / "home"), "FLEETGATE_MAPS": ""}
    done = run("maps", "download", "tiny-3-1", "--base-url", url, env=env)
    assert done.returncode == 0, done.stderr
    cache = tmp / "home" / ".cache" / "fleetgate" / "maps"
    assert (cache / "tiny-3-1.map").read_text() == TINY_MAP
    assert (cache / "scen" / "tiny-3-1-random-1.scen").read_text() == TINY_SCEN
    assert (cache / "scen" / "tiny-3-1-even-1.scen").read_text() == TINY_SCEN
    listed = run("maps", "list", "--json", env=env)
    assert listed.returncode == 0, listed.stderr
    rows = {(r["name"], r["kind"]): r for r in json.loads(listed.stdout)}
    assert rows[("tiny-3-1", "map")]["origin"] == "cache"
    assert rows[("tiny-3-1-even-1", "scen")]["path"] == str(cache / "scen" /
                                                             "tiny-3-1-even-1.scen")
    assert rows[("lab", "map")]["origin"] == "shipped"
    # The downloaded names now work for planning: one agent from (0,0) to (2,0) costs 2.
    solved = run("plan", "--map", "tiny-3-1", "--scen", "tiny-3-1-random-1", "--json", env=env)
    assert solved.returncode == 0, solved.stderr
    assert json.loads(solved.stdout)["agents"][0]["path"] == [[0, 0], [1, 0], [2, 0]]


def test_download_by_scenario_name_via_environment_url(server: tuple[str, Path],
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    url, tmp = server
    monkeypatch.setenv("HOME", str(tmp / "home"))
    monkeypatch.setenv("FLEETGATE_MAPS_URL", url)
    done = call("maps", "download", "tiny-3-1-random-1", "--dest", str(tmp / "d"), "--no-scen")
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in (tmp / "d").iterdir()) == ["tiny-3-1.map"]


@pytest.mark.parametrize(("name", "reason"), [
    ("missing-2-2", "HTTP 404 "),
    ("broken-1-1", "is not a zip archive"),
])
def test_failed_download_exits_2_and_writes_nothing(server: tuple[str, Path], name: str,
                                                    reason: str) -> None:
    url, tmp = server
    done = call("maps", "download", name, "--base-url", url, "--dest", str(tmp / "d"),
               "--no-scen")
    assert done.returncode == 2
    assert done.stderr.startswith("fleetgate: ")
    assert reason in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp / "d").exists()


def test_resolution_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    first, second, home = tmp_path / "first", tmp_path / "second", tmp_path / "home"
    cache = home / ".cache" / "fleetgate" / "maps"
    for d in (first, second, cache / "scen"):
        d.mkdir(parents=True)
    for d in (first, second, cache):
        (d / "m.map").write_text(TINY_MAP)
    (cache / "scen" / "m-random-1.scen").write_text(TINY_SCEN)
    monkeypatch.setenv("HOME", str(home))
    env = {"FLEETGATE_MAPS": str(second)}
    assert mapstore.resolve("m", "map", first, env) == first / "m.map"
    assert mapstore.resolve("m.map", "map", None, env) == second / "m.map"
    assert mapstore.resolve("m", "map", None, {}) == cache / "m.map"
    assert mapstore.resolve("m-random-1", "scen", first, env) == cache / "scen" / "m-random-1.scen"
    assert mapstore.resolve("lab", "map", None, {}) == mapstore.SHIPPED_DIR / "lab.map"
    # An existing path is taken as it is.
    assert mapstore.resolve(str(second / "m.map"), "map", first, env) == second / "m.map"
    listed = mapstore.available(first, env)
    assert [(a.origin, a.shadowed) for a in listed if a.name == "m"] == [
        ("--maps-dir", False), ("$FLEETGATE_MAPS", True), ("cache", True)]
    monkeypatch.setenv("FLEETGATE_MAPS", str(second))
    shown = call("maps", "list", "--maps-dir", str(first))
    assert shown.returncode == 0
    lines = [line.split() for line in shown.stdout.splitlines()[1:]]
    assert ["map", "m", "$FLEETGATE_MAPS", str(second / "m.map"), "(shadowed)"] in lines
    assert ["map", "lab", "shipped", str(mapstore.SHIPPED_DIR / "lab.map")] in lines


def test_unknown_names_and_missing_paths(tmp_path: Path) -> None:
    with pytest.raises(mapstore.MapNotFound, match=r"no map named 'nope' in .*shipped\)"):
        mapstore.resolve("nope", "map", tmp_path, {})
    with pytest.raises(mapstore.MapNotFound, match=r"scen file 'x/y\.scen' does not exist"):
        mapstore.resolve("x/y.scen", "scen", None, {})
