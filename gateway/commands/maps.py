"""``fleetgate maps list|download|generate``: what map names resolve to, fetching MovingAI
maps, and generating maps with scenarios."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from fleetgate.userio.files import make_folder, write_text
from gateway.runtime import mapstore
from gateway.runtime.exits import EXIT_OK, UsageError

if TYPE_CHECKING:
    from gateway.planning.grid import Grid


def _list(args: argparse.Namespace) -> int:
    found = mapstore.available(args.maps_dir)
    if args.json:
        rows = [{"name": a.name, "kind": a.kind, "path": str(a.path), "origin": a.origin,
                 "shadowed": a.shadowed} for a in found]
        print(json.dumps(rows, indent=1))
        return EXIT_OK
    print("search order: " + ", ".join(f"{d.path} ({d.origin})"
                                       for d in mapstore.search_dirs(args.maps_dir)))
    for a in found:
        note = "  (shadowed)" if a.shadowed else ""
        print(f"{a.kind:4}  {a.name:40}  {a.origin:10}  {a.path}{note}")
    return EXIT_OK


def _download(args: argparse.Namespace) -> int:
    try:
        written = mapstore.download(args.name, base_url=args.base_url, dest=args.dest,
                                    with_scen=not args.no_scen, timeout=args.timeout)
    except mapstore.DownloadError as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"cannot write into {args.dest or mapstore.cache_dir()}: "
                         f"{exc.strerror}") from None
    maps = sum(1 for p in written if p.suffix == ".map")
    print(f"{maps} map(s) and {len(written) - maps} scenario(s) written under "
          f"{args.dest or mapstore.cache_dir()}", file=sys.stderr)
    for path in written:
        print(path)
    return EXIT_OK


def _generated_map(args: argparse.Namespace) -> Grid:
    import numpy as np

    from gateway.planning.generators import random_map, rooms_map, warehouse_map

    rng = np.random.default_rng(args.seed)
    name = f"{args.name}.map"
    if args.kind == "random":
        return random_map(args.width, args.height, args.obstacles, rng, name)
    if args.kind == "rooms":
        return rooms_map(args.rooms_x, args.rooms_y, args.room_size, rng, args.extra_doors, name)
    return warehouse_map(args.blocks_x, args.blocks_y, args.shelf_length, args.shelf_depth,
                         args.aisle, args.border, name)


def _generate(args: argparse.Namespace) -> int:
    from gateway.planning.generators import scenario_set
    from gateway.planning.movingai import format_map, format_scen

    if "/" in args.name or not args.name:
        raise UsageError(f"NAME must be a plain file name, got {args.name!r}")
    if args.scenarios < 0:
        raise UsageError(f"--scenarios must not be negative, got {args.scenarios}")
    try:
        grid = _generated_map(args)
        texts = {f"{args.name}.map": format_map(grid)}
        if args.scenarios:
            for i, entries in enumerate(scenario_set(grid, f"{args.name}.map", args.scenarios,
                                                     args.agents, args.seed), start=1):
                texts[f"{args.name}-random-{i}.scen"] = format_scen(entries)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = Path(args.out)
    clash = [n for n in texts if (out / n).exists()]
    if clash and not args.force:
        raise UsageError(f"{out / clash[0]} exists (use --force to overwrite)")
    make_folder(out)
    for file, text in texts.items():
        write_text(out / file, text)
    for file in texts:
        print(out / file)
    return EXIT_OK


def _add_generate(inner: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    gen = inner.add_parser(
        "generate", help="make a connected random, rooms or warehouse map and scenarios",
        description="Write OUT/NAME.map and, with --scenarios K, OUT/NAME-random-{1..K}.scen "
                    "(distinct starts, distinct reachable goals). The same --seed gives the "
                    "same files.")
    gen.add_argument("kind", choices=("random", "rooms", "warehouse"))
    gen.add_argument("name", metavar="NAME", help="file name without .map")
    gen.add_argument("--out", metavar="DIR", default=".", help="folder to write (default .)")
    gen.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    gen.add_argument("--scenarios", type=int, default=0, metavar="K",
                     help="also write K scenario files (default 0)")
    gen.add_argument("--agents", type=int, default=20, metavar="N",
                     help="agents per scenario (default 20)")
    gen.add_argument("--force", action="store_true", help="overwrite existing files")
    shape = gen.add_argument_group("random map")
    shape.add_argument("--width", type=int, default=32)
    shape.add_argument("--height", type=int, default=32)
    shape.add_argument("--obstacles", type=float, default=0.2, metavar="SHARE",
                       help="share of blocked cells before pockets are filled (default 0.2)")
    rooms = gen.add_argument_group("rooms map")
    rooms.add_argument("--rooms-x", type=int, default=4)
    rooms.add_argument("--rooms-y", type=int, default=4)
    rooms.add_argument("--room-size", type=int, default=7)
    rooms.add_argument("--extra-doors", type=float, default=0.3, metavar="P",
                       help="chance of a door between rooms beyond a spanning tree")
    house = gen.add_argument_group("warehouse map")
    house.add_argument("--blocks-x", type=int, default=3)
    house.add_argument("--blocks-y", type=int, default=3)
    house.add_argument("--shelf-length", type=int, default=5)
    house.add_argument("--shelf-depth", type=int, default=2)
    house.add_argument("--aisle", type=int, default=2)
    house.add_argument("--border", type=int, default=2)
    gen.set_defaults(func=_generate)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleetgate maps`` with its ``list`` and ``download`` subcommands."""
    parser = sub.add_parser("maps", help="list and download maps and scenarios",
                            description="Map names resolve in --maps-dir, $FLEETGATE_MAPS, "
                                        "~/.cache/fleetgate/maps, then the shipped maps.")
    inner = parser.add_subparsers(dest="maps_command", required=True, metavar="SUBCOMMAND")
    listing = inner.add_parser("list", help="show what each name resolves to",
                               description="List maps and scenarios in resolution order.")
    listing.add_argument("--maps-dir", metavar="DIR", help="look here first")
    listing.add_argument("--json", action="store_true", help="print a JSON list")
    listing.set_defaults(func=_list)
    fetch = inner.add_parser(
        "download", help="fetch a MovingAI benchmark map into the cache",
        description="Fetch NAME.map.zip and its scenario archives (NAME.map-scen-random.zip, "
                    "NAME.map-scen-even.zip) from the MovingAI MAPF benchmark and extract "
                    "them into the cache. NAME may also be a scenario name such as "
                    "random-32-32-20-random-1.")
    fetch.add_argument("name", metavar="NAME", help="map name, e.g. random-32-32-20")
    fetch.add_argument("--base-url", metavar="URL",
                       help=f"archive folder (default ${mapstore.ENV_BASE_URL} or "
                            f"{mapstore.DEFAULT_BASE_URL})")
    fetch.add_argument("--dest", metavar="DIR", type=Path,
                       help="extract here instead of ~/.cache/fleetgate/maps")
    fetch.add_argument("--no-scen", action="store_true", help="fetch the map only")
    fetch.add_argument("--timeout", type=float, default=60.0, metavar="SEC",
                       help="network timeout per archive (default 60)")
    fetch.set_defaults(func=_download)
    _add_generate(inner)
