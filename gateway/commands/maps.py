"""``fleetgate maps list|download``: what map names resolve to, and fetching MovingAI maps."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from gateway.cli import EXIT_OK, UsageError
from gateway.commands import mapstore


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
