"""The newest-frame-wins hand-over between a camera's capture thread and the mapper; ``--source``."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from ..errors import DataError
from ..frame import Frame

log = logging.getLogger(__name__)

SOURCES = "realsense[:SERIAL or :RECORDING.db3/.bag] or record3d[:DEVICE_INDEX]"


class LatestFrame:
    """A one-slot buffer: the capture side ``put``s every frame it receives, the mapping side ``get``s the
    newest one; a frame replaced before it was taken counts as skipped. ``finish`` ends the stream (the camera
    stopped, or an error, raised on the mapping side)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: Any = None
        self._finished = False
        self._error: BaseException | None = None
        self.received = 0
        self.skipped = 0

    def put(self, item: Any, wait: bool = False) -> None:
        """Hand ``item`` over. ``wait``: first wait until the previous item was taken (a recording replayed
        frame by frame), so that none is skipped; the buffer still holds one."""
        with self._cond:
            while wait and self._item is not None and not self._finished:
                self._cond.wait(0.1)
            if self._finished:
                return
            if self._item is not None:
                self.skipped += 1
            self._item = item
            self.received += 1
            self._cond.notify_all()

    def finish(self, error: BaseException | None = None) -> None:
        with self._cond:
            self._finished = True
            self._error = self._error or error
            self._cond.notify_all()

    @property
    def finished(self) -> bool:
        return self._finished

    def get(self, timeout: float) -> Any:
        """The newest item not taken yet; None once the stream has finished and nothing is left. Raises the
        capture side's error, or :class:`DataError` when nothing came for ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._item is None and not self._finished:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DataError(
                        f"no frame from the camera for {timeout:g} s (unplugged, or stopped streaming?)"
                    )
                self._cond.wait(left)
            if self._error is not None:
                raise self._error
            item, self._item = self._item, None
            self._cond.notify_all()
            return item


class CameraStream:
    """A live camera as an iterable of frames. Subclasses implement ``_open()`` (start the device; its capture
    thread or callback calls ``self.buffer.put(raw)`` and ``self.buffer.finish()``), ``_close()`` and
    ``_to_frame(raw, index)``.

    ``max_frames``: end after this many frames (None: while the camera streams). ``timeout``: seconds without
    a frame after which iteration fails. Iterating starts the camera; :meth:`close` stops it, and iteration
    then ends without another frame (a live session then finishes and saves its map).
    """

    name = "camera"

    def __init__(self, max_frames: int | None = None, timeout: float = 10.0) -> None:
        self.max_frames = max_frames
        self.timeout = timeout
        self.buffer = LatestFrame()
        self.delivered = 0
        self._started = False
        self._closed = threading.Event()
        self._lock = threading.Lock()

    @property
    def skipped(self) -> int:
        """Frames the camera delivered that were replaced by a newer one before mapping took them."""
        return self.buffer.skipped

    def start(self) -> CameraStream:
        with self._lock:
            if not self._started and not self._closed.is_set():
                self._open()
                self._started = True
        return self

    def close(self) -> None:
        """Stop the camera; iteration ends (idempotent, from any thread)."""
        with self._lock:
            if self._closed.is_set():
                return
            self._closed.set()
            self.buffer.finish()
            if self._started:
                try:
                    self._close()
                except Exception:  # noqa: BLE001 - a driver failing to stop must not lose the map
                    log.exception("%s: stopping the camera failed", self.name)
        if self.delivered:
            log.info(
                "%s: %d frames mapped, %d skipped while mapping was busy (of %d received)",
                self.name, self.delivered, self.skipped, self.buffer.received,
            )  # fmt: skip

    def __iter__(self) -> Iterator[Frame]:
        self.start()
        try:
            while not self._closed.is_set():
                if self.max_frames is not None and self.delivered >= self.max_frames:
                    break
                raw = self.buffer.get(self.timeout)
                if raw is None or self._closed.is_set():
                    break
                frame = self._to_frame(raw, self.delivered)
                self.delivered += 1
                yield frame
        finally:
            self.close()

    def check(self) -> None:
        """Raise a clear error when the camera is not there (a driver package, a device, a recording),
        without starting it."""

    # -- for subclasses

    def _open(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def _to_frame(self, raw: Any, index: int) -> Frame:
        raise NotImplementedError


def frame_from_arrays(
    index: int,
    rgb: np.ndarray,
    depth_m: np.ndarray,
    K: np.ndarray,
    timestamp: float,
    pose: np.ndarray | None = None,
) -> Frame:
    """A :class:`Frame` named ``frameNNNNNN`` from decoded arrays (invalid depth: 0)."""
    depth = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, 0.0).astype(np.float32)
    return Frame(
        index=index,
        rgb=np.ascontiguousarray(rgb, dtype=np.uint8),
        depth=depth,
        K=K,
        pose=pose,
        timestamp=timestamp,
        name=f"frame{index:06d}",
    )


def close_stream(frames: Any) -> bool:
    """Close ``frames`` when it is a camera stream (what a live session maps), so that the session's loop ends
    and the map is finished and saved; anything else is left as it is. -> whether a stream was closed."""
    if isinstance(frames, CameraStream):
        frames.close()
        return True
    return False
