"""MovingAI / mapf-IR readers and writers: round trips and every malformed-input message."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gateway.planning.grid import Grid
from gateway.planning.movingai import (
    MapFormatError,
    ScenEntry,
    parse_map,
    parse_mapf_ir,
    parse_scen,
    read_map,
    read_mapf_ir,
    read_scen,
    write_map,
    write_scen,
)

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "maps"

GOOD_MAP = "type octile\nheight 2\nwidth 3\nmap\n.@T\nGSW\n"


def test_parse_map_reads_free_and_blocked_tiles() -> None:
    g = parse_map(GOOD_MAP)
    assert (g.width, g.height) == (3, 2)
    assert g.free.tolist() == [[True, False, False], [True, True, False]]


@settings(max_examples=40, deadline=None)
@given(arrays(np.bool_, st.tuples(st.integers(1, 6), st.integers(1, 6))))
def test_map_round_trip(tmp_path_factory: pytest.TempPathFactory, free: np.ndarray) -> None:
    path = tmp_path_factory.mktemp("maps") / "m.map"
    write_map(Grid(free), path)
    back = read_map(path)
    assert np.array_equal(back.free, free)
    assert back.name == "m.map"


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 99), st.integers(0, 99), st.integers(0, 99),
                          st.integers(0, 99), st.integers(0, 9),
                          st.floats(0, 1000, allow_nan=False).map(lambda f: round(f, 8))),
                max_size=6))
def test_scen_round_trip(tmp_path_factory: pytest.TempPathFactory,
                         rows: list[tuple[int, int, int, int, int, float]]) -> None:
    entries = [ScenEntry(start=(sx, sy), goal=(gx, gy), line=i + 2, bucket=b, map_name="x.map",
                         width=100, height=100, optimal_length=opt)
               for i, (sx, sy, gx, gy, b, opt) in enumerate(rows)]
    path = tmp_path_factory.mktemp("scen") / "x.scen"
    write_scen(entries, path)
    back = read_scen(path)
    assert list(back.agents) == entries
    assert [a.line for a in back.agents] == list(range(2, 2 + len(entries)))


def test_scen_accepts_space_separated_and_crlf_lines() -> None:
    parsed = parse_scen("version 1\r\n0 a.map 4 4 1 2 3 0 2.0\r\n\r\n", "s.scen")
    (entry,) = parsed.agents
    assert isinstance(entry, ScenEntry)
    assert (entry.start, entry.goal, entry.line, entry.map_name) == ((1, 2), (3, 0), 2, "a.map")


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/maps is not present")
def test_shared_benchmark_files_parse() -> None:
    # Free-cell counts as listed in shared/maps/SOURCES.md.
    assert int(read_map(SHARED / "arena.map").free.sum()) == 2054
    assert int(read_map(SHARED / "random-32-32-20.map").free.sum()) == 819
    assert int(read_map(SHARED / "room-32-32-4.map").free.sum()) == 682
    scen = read_scen(SHARED / "scen" / "random-32-32-20-random-1.scen")
    first = scen.agents[0]
    assert isinstance(first, ScenEntry)
    assert (first.start, first.goal, first.map_name) == ((5, 16), (31, 24), "random-32-32-20.map")
    ir = read_mapf_ir(SHARED / "mapf-IR-instances" / "arena_300agents_1.txt")
    assert ir.map_file == "arena.map"
    assert len(ir.agents) == 300
    assert (ir.agents[0].start, ir.agents[0].goal, ir.agents[0].line) == ((36, 33), (5, 23), 7)


@pytest.mark.parametrize(("text", "message"), [
    ("", "m.map:1: bad header: expected 'type', 'height', 'width' and 'map' lines"),
    ("tipe octile\nheight 2\nwidth 3\nmap\n...\n...\n",
     "m.map:1: bad header: expected 'type <value>', got 'tipe octile'"),
    ("type octile\nheight two\nwidth 3\nmap\n...\n...\n",
     "m.map:2: bad header: height 'two' is not an integer"),
    ("type octile\nheight 2\nheight 3\nmap\n...\n...\n",
     "m.map:3: bad header: expected 'height <H>' and 'width <W>', got 'height 3'"),
    ("type octile\nheight 2\nwidth 0\nmap\n\n",
     "m.map:3: bad header: width must be positive, got 0"),
    ("type octile\nheight 2\nwidth 3\nmops\n...\n...\n",
     "m.map:4: bad header: expected 'map', got 'mops'"),
    ("type octile\nheight 2\nwidth 3\nmap\n...\n.x.\n", "m.map:6: unknown tile 'x' at column 1"),
    ("type octile\nheight 2\nwidth 3\nmap\n...\n....\n",
     "m.map:6: ragged row: 4 tiles, header says width 3"),
    ("type octile\nheight 3\nwidth 3\nmap\n...\n...\n",
     "m.map:6: wrong row count: 2 rows, header says height 3"),
    ("type octile\nheight 1\nwidth 3\nmap\n...\n...\n",
     "m.map:6: wrong row count: more than 1 rows (header height)"),
])
def test_malformed_map(text: str, message: str) -> None:
    with pytest.raises(MapFormatError) as err:
        parse_map(text, "m.map")
    assert str(err.value) == message
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(("text", "message"), [
    ("versio 1\n", "s.scen:1: bad header: expected 'version 1', got 'versio 1'"),
    ("version 1\n0\ta.map\t4\t4\t1\t2\t3\n",
     "s.scen:2: bad scenario line: 7 fields, expected 9 (bucket map width height start_x "
     "start_y goal_x goal_y optimal_length)"),
    ("version 1\n0\ta.map\t4\t4\t1\t2\t3\t0\t1\n0\ta.map\t4\t4\t1\tb\t3\t0\t1\n",
     "s.scen:3: bad scenario line: start_y 'b' is not an integer"),
    ("version 1\n0\ta.map\t4\t4\t1\t2\t3\t0\tlong\n",
     "s.scen:2: bad scenario line: optimal_length 'long' is not a number"),
])
def test_malformed_scen(text: str, message: str) -> None:
    with pytest.raises(MapFormatError) as err:
        parse_scen(text, "s.scen")
    assert str(err.value) == message


@pytest.mark.parametrize(("text", "message"), [
    ("agents=1\n1,2,3,4\n", "i.txt:1: bad header: no 'map_file=' line"),
    ("map_file=a.map\n1,2,3\n",
     "i.txt:2: bad agent line: expected 'start_x,start_y,goal_x,goal_y', got '1,2,3'"),
    ("map_file=a.map\n1,2,3,z\n", "i.txt:2: bad agent line: goal_y 'z' is not an integer"),
    ("map_file=a.map\n1,2,3,4\nseed=3\n", "i.txt:3: bad header: 'seed=3' after agent lines"),
    ("map_file=a.map\nagents=3\n1,2,3,4\n", "i.txt:3: header says agents=3, the file lists 1"),
])
def test_malformed_mapf_ir(text: str, message: str) -> None:
    with pytest.raises(MapFormatError) as err:
        parse_mapf_ir(text, "i.txt")
    assert str(err.value) == message
