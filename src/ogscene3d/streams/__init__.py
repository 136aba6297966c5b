"""Live RGB-D cameras as frame sources of ``ogscene3d-live --source``: an Intel RealSense
(``realsense[:SERIAL]``, or ``realsense:RECORDING.db3|.bag`` to replay a librealsense recording as if live)
and an iPhone/iPad streaming over USB with the Record3D app (``record3d[:INDEX]``).

A stream is an iterable of :class:`~ogscene3d.frame.Frame` that ends when the camera stops or the stream is
closed. When mapping is slower than the camera, the newest frame is taken and the skipped ones are counted
(``stream.skipped``); frames never pile up in memory.
"""

from __future__ import annotations

from .base import CameraStream, LatestFrame, close_stream
from .sources import open_stream, stream_for_live

__all__ = ["CameraStream", "LatestFrame", "close_stream", "open_stream", "stream_for_live"]
