"""The instance options shared by commands: ``--map --scen --agents --instance --maps-dir``."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from gateway.planning.motion import (
    DEFAULT_START_HEADING,
    HEADING_NAMES,
    MOTIONS,
    Motion,
    parse_heading,
)
from gateway.runtime.exits import UsageError

if TYPE_CHECKING:
    from gateway.planning.instance import Instance
    from gateway.planning.problem import Place


def add_instance_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options that choose an instance (read back with :func:`instance_from_args`)."""
    group = parser.add_argument_group("instance")
    group.add_argument("--map", metavar="M", help="map file or name (e.g. random-32-32-20, lab)")
    group.add_argument("--scen", metavar="S",
                       help="scenario file or name (e.g. random-32-32-20-random-1)")
    group.add_argument("--agents", metavar="N", type=int,
                       help="use the first N agents (default: all)")
    group.add_argument("--instance", metavar="FILE",
                       help="a mapf-IR instance file instead of --scen (its map_file is looked "
                            "for next to it and by name; --map overrides it)")
    group.add_argument("--maps-dir", metavar="DIR", help="look up map and scenario names here "
                                                         "first")


def instance_from_args(args: argparse.Namespace) -> Instance:
    """Load and check the instance the options name; bad input raises :class:`UsageError`."""
    from gateway.planning.instance import load_instance, load_mapf_ir
    from gateway.planning.movingai import MapFormatError
    from gateway.runtime import mapstore

    if args.agents is not None and args.agents < 1:
        raise UsageError(f"--agents must be at least 1, got {args.agents}")
    if args.instance and args.scen:
        raise UsageError("give either --scen or --instance, not both")
    try:
        if args.instance:
            map_path = mapstore.resolve(args.map, "map", args.maps_dir) if args.map else None
            dirs = [d.path for d in mapstore.search_dirs(args.maps_dir)]
            return load_mapf_ir(args.instance, args.agents, map_path, dirs)
        if not args.map or not args.scen:
            raise UsageError("give --map and --scen, or --instance")
        return load_instance(mapstore.resolve(args.map, "map", args.maps_dir),
                             mapstore.resolve(args.scen, "scen", args.maps_dir), args.agents)
    except (mapstore.MapNotFound, MapFormatError) as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"cannot read {exc.filename}: {exc.strerror}") from None
    except UnicodeDecodeError:
        given = " or ".join(str(f) for f in (args.map, args.scen, args.instance) if f)
        raise UsageError(f"cannot read {given}: not a text file") from None


def add_motion_arguments(parser: argparse.ArgumentParser, default: Motion) -> None:
    """Add ``--motion`` (with this entry point's ``default``) and ``--start-heading``."""
    group = parser.add_argument_group("motion")
    group.add_argument("--motion", choices=MOTIONS, default=default,
                       help=f"motion model: omni (move to any neighbour) or turning (turn 90 "
                            f"degrees in place, move forward); default {default}")
    group.add_argument("--start-heading", metavar="H", default=None,
                       help="turning: the start heading of every robot whose instance gives "
                            "none (MovingAI scenarios give none): east, south, west, north or "
                            f"0-3 (default {HEADING_NAMES[DEFAULT_START_HEADING]})")


def starts_from_args(args: argparse.Namespace, instance: Instance) -> tuple[Place, ...]:
    """The planner's starts under ``--motion``: cells, or ``(x, y, heading)`` when turning."""
    if args.motion != "turning":
        if args.start_heading is not None:
            raise UsageError("--start-heading needs --motion turning")
        return instance.starts
    if args.start_heading is None:
        return instance.turning_starts()
    try:
        return instance.turning_starts(parse_heading(args.start_heading))
    except ValueError as exc:
        raise UsageError(f"--start-heading: {exc}") from None
