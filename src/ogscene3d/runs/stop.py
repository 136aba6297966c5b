"""The stop signal of a run: a request to end mapping after the frame in progress (docs/runs.md "Stops")."""

from __future__ import annotations

import contextlib
import logging
import signal
from collections.abc import Iterator
from typing import Any

log = logging.getLogger(__name__)


class StopRequest:
    """A request to end mapping after the frame in progress (saving from inside a frame could write a
    half-updated state): from another thread (:meth:`request`) or, within :meth:`signals`, from Ctrl-C
    or SIGTERM, where a second signal stops at once."""

    def __init__(self) -> None:
        self.requested = False

    def request(self) -> None:
        self.requested = True

    @contextlib.contextmanager
    def signals(self) -> Iterator[StopRequest]:
        previous: dict[int, Any] = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                previous[sig] = signal.signal(sig, self._handle)
            except ValueError:  # not the main thread (an embedding application): its handlers stay
                break
        try:
            yield self
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.request()
        log.warning("stopping after this frame to save the map (again to stop at once, losing it)")


__all__ = ["StopRequest"]
