"""``fleetgate-robot`` / ``python -m robot_client``: run one real robot of the fleet.

Exit codes: 0 on Ctrl-C / SIGTERM, 2 on bad settings or a device that cannot be opened.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys

from robot_client.client import build_client
from robot_client.config import ConfigError, load_settings
from robot_client.frames import FrameSource, VideoCaptureSource
from robot_client.kobuki import KobukiSerial


def main(argv: list[str] | None = None) -> int:
    """Parse settings, open the base and the camera, run the client until interrupted."""
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
    except (ConfigError, OSError) as exc:
        print(f"fleetgate-robot: {exc}", file=sys.stderr)
        return 2
    client = build_client(settings, base, frames)

    async def _run() -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, client.stop)
        await client.run()

    try:
        asyncio.run(_run())
    finally:
        base.close()
        if frames is not None:
            frames.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
