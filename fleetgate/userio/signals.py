"""How a long-running asyncio command stops on a signal: cleanly, then with its exit code.

Ctrl-C (SIGINT) ends it with 130 (:data:`fleetgate.userio.exits.EXIT_INTERRUPTED`), SIGTERM
(a service manager stopping it) with 0; a second Ctrl-C while it stops gives up on the clean
stop (KeyboardInterrupt, still 130).
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable

from fleetgate.userio.exits import EXIT_INTERRUPTED, EXIT_OK


class StopSignals:
    """SIGINT and SIGTERM handlers on the running loop (create it inside the loop): each sets
    :attr:`event` and calls ``on_stop``; :attr:`exit_code` says how the command should end."""

    def __init__(self, on_stop: Callable[[], object] | None = None) -> None:
        import asyncio

        self.event = asyncio.Event()
        self.received: int | None = None
        self._on_stop = on_stop
        self._loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError):
                self._loop.add_signal_handler(sig, self._got, sig)

    def _got(self, sig: int) -> None:
        if self.received == signal.SIGINT and sig == signal.SIGINT:
            raise KeyboardInterrupt  # a second Ctrl-C: stop now
        if self.received is None:
            self.received = sig
        self.event.set()
        if self._on_stop is not None:
            self._on_stop()

    async def wait(self) -> None:
        """Until a signal came."""
        await self.event.wait()

    @property
    def exit_code(self) -> int:
        """130 after Ctrl-C, else 0."""
        return EXIT_INTERRUPTED if self.received == signal.SIGINT else EXIT_OK
