"""A private Eclipse Mosquitto broker on a free loopback port, for the VDA 5050 demo, the
simulated vehicles and the tests (a real broker, never a mock). Needs the ``mosquitto``
package (Debian/Ubuntu: ``apt-get install mosquitto``)."""

from __future__ import annotations

import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from types import TracebackType

from fleetgate.userio import children

CANDIDATES = ("/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto")


class MosquittoMissing(RuntimeError):
    """No mosquitto binary: what to install."""


def find_mosquitto() -> str:
    """The mosquitto binary; MosquittoMissing says what to install if there is none."""
    for path in (*CANDIDATES, shutil.which("mosquitto")):
        if path and Path(path).is_file():
            return path
    raise MosquittoMissing("mosquitto is not installed (Debian/Ubuntu: apt-get install "
                           "mosquitto), or give a broker with --broker mqtt://HOST:PORT")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class LocalBroker:
    """``with LocalBroker() as url:`` runs mosquitto on 127.0.0.1 (anonymous clients, no
    persistence) until the block ends; ``url`` is ``mqtt://127.0.0.1:PORT``."""

    def __init__(self, start_timeout_s: float = 10.0) -> None:
        self.binary = find_mosquitto()
        self.start_timeout_s = start_timeout_s
        self.port = 0
        self._dir: tempfile.TemporaryDirectory[str] | None = None
        self._proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        """The broker's URL."""
        return f"mqtt://127.0.0.1:{self.port}"

    def start(self) -> str:
        """Start the broker (a few tries: a free port may be taken before mosquitto binds
        it); RuntimeError if it never listens."""
        self._dir = tempfile.TemporaryDirectory(prefix="fleetgate-mosquitto-")
        for _ in range(3):
            self.port = _free_port()
            conf = Path(self._dir.name) / "mosquitto.conf"
            conf.write_text(f"listener {self.port} 127.0.0.1\nallow_anonymous true\n"
                            "persistence false\nlog_dest stderr\nlog_type error\n"
                            "max_queued_messages 100000\n")
            log = Path(self._dir.name) / "mosquitto.log"
            with log.open("wb") as out:
                self._proc = children.spawn([self.binary, "-c", str(conf)],
                                            stdout=subprocess.DEVNULL, stderr=out)
            if self._listening():
                return self.url
            self._kill()
        raise RuntimeError("mosquitto did not start: "
                           f"{log.read_text(errors='replace').strip()[-300:]}")

    def _listening(self) -> bool:
        deadline = time.monotonic() + self.start_timeout_s
        while time.monotonic() < deadline:
            assert self._proc is not None
            if self._proc.poll() is not None:
                return False
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return True
            except OSError:
                time.sleep(0.05)
        return False

    def _kill(self) -> None:
        if self._proc is not None:
            children.stop(self._proc, grace_s=5.0)
        self._proc = None

    def stop(self) -> None:
        """Stop the broker and remove its files."""
        self._kill()
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None

    def __enter__(self) -> str:
        return self.start()

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()
