"""``fleetgate-robot`` / ``python -m robot_client``: run one real robot of the fleet.

Exit codes (:mod:`fleetgate.userio.exits`): 0 on SIGTERM, 130 on Ctrl-C, 2 on bad settings or
a file or device that cannot be opened (named).
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing cv2 is one line)

# isort: split

import argparse
import asyncio
import logging
import sys

from fleetgate.userio.exits import UsageError, call
from fleetgate.userio.files import describe
from fleetgate.userio.signals import StopSignals
from robot_client.client import build_client
from robot_client.config import ConfigError, load_settings
from robot_client.frames import FrameSource, VideoCaptureSource
from robot_client.kobuki import KobukiSerial


def _main(argv: list[str] | None) -> int:
    # --config is needed before the settings are parsed (the file is one of their sources);
    # both options are settings too, so that --help lists them.
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--config")
    pre.add_argument("--log-level", type=str.upper)
    opts, rest = pre.parse_known_args(sys.argv[1:] if argv is None else argv)
    try:
        settings = load_settings(rest, config_file=opts.config,
                                 **({"log_level": opts.log_level} if opts.log_level else {}))
        logging.basicConfig(level=settings.log_level,
                            format="%(asctime)s %(levelname)s %(name)s: %(message)s")
        settings.ssl_context()  # refuse unreadable TLS files now, with a one-line reason
        base = KobukiSerial(settings.serial_port)
        frames: FrameSource | None = None
        if not settings.no_camera:
            frames = VideoCaptureSource(settings.camera_index, settings.camera_width_px,
                                        settings.camera_height_px)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    except BrokenPipeError:
        raise  # --help into a closed pipe
    except OSError as exc:
        raise UsageError(f"{exc.filename}: {describe(exc)}" if exc.filename else str(exc)
                         ) from None
    client = build_client(settings, base, frames)

    async def _run() -> int:
        stop = StopSignals(client.stop)
        await client.run()
        return stop.exit_code

    try:
        return asyncio.run(_run())
    finally:
        base.close()
        if frames is not None:
            frames.close()


def main(argv: list[str] | None = None) -> int:
    """Parse settings, open the base and the camera, run the client until SIGTERM or Ctrl-C."""
    return call("fleetgate-robot", _main, argv)


if __name__ == "__main__":
    sys.exit(main())
