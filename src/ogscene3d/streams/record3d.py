"""An iPhone/iPad streaming RGB-D over USB with the Record3D app, through the ``record3d`` package (``pip
install "ogscene3d[record3d-usb]"``; Record3D's "USB Streaming mode" must be on).

Frames have the depth image's size (LiDAR: 256x192): colour is resampled to it and the intrinsics scaled to
it; depth below ``min_confidence`` (ARKit: 0 low, 1 medium, 2 high) is left out. Frames carry ARKit's pose
turned to OpenCV axes (as in ``.r3d`` captures); the live command tracks them by default
(``tracking.poses: odometry``) and uses ARKit's with ``--set tracking.poses=gt``.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import cv2
import numpy as np

from ..datasets.record3d import arkit_to_opencv
from ..errors import DataError
from ..frame import Frame
from ..optional import require
from .base import CameraStream, frame_from_arrays

log = logging.getLogger(__name__)

TRUEDEPTH = 0  # Record3D's device type of the front (TrueDepth) camera, whose images come mirrored


class Record3DUSBStream(CameraStream):
    """``device_index``: which of the connected devices (0: the first). ``r3d``: the ``record3d`` module
    (tests pass a stand-in)."""

    def __init__(
        self,
        device_index: int = 0,
        min_confidence: int = 1,
        max_frames: int | None = None,
        timeout: float = 10.0,
        r3d: Any = None,
    ) -> None:
        super().__init__(max_frames, timeout)
        self.device_index = device_index
        self.min_confidence = min_confidence
        self.name = f"record3d device {device_index}"
        self._r3d = r3d
        self._session: Any = None
        self._grab_lock = threading.Lock()
        self._warned_K = False

    def _devices(self) -> tuple[Any, list]:
        r3d = self._r3d or require("record3d", "record3d-usb", "--source record3d")
        devices = list(r3d.Record3DStream.get_connected_devices())
        if len(devices) <= self.device_index:
            raise DataError(
                f"Record3D: {len(devices)} device(s) streaming over USB, so no device {self.device_index}: "
                "connect the iPhone/iPad by cable, open Record3D, turn on USB Streaming mode in its settings "
                "and press record"
            )
        return r3d, devices

    def check(self) -> None:
        self._devices()

    def _open(self) -> None:
        r3d, devices = self._devices()
        session = r3d.Record3DStream()
        session.on_new_frame = self._on_new_frame
        session.on_stream_stopped = self._on_stopped
        self._session = session
        session.connect(devices[self.device_index])

    def _on_new_frame(self) -> None:
        """Called on the record3d library's thread for every frame: copy it out (the library reuses its
        buffers) and hand it over; never raises into the library."""
        try:
            s = self._session
            with self._grab_lock:
                depth = np.array(s.get_depth_frame(), dtype=np.float32, copy=True)
                rgb = np.array(s.get_rgb_frame(), dtype=np.uint8, copy=True)
                conf = np.array(s.get_confidence_frame(), dtype=np.uint8, copy=True)
                c = s.get_intrinsic_mat()
                p = s.get_camera_pose()
                device_type = int(s.get_device_type())
            K = (float(c.fx), float(c.fy), float(c.tx), float(c.ty))
            pose = np.array([p.qx, p.qy, p.qz, p.qw, p.tx, p.ty, p.tz], dtype=np.float64)
            self.buffer.put((rgb, depth, conf, K, pose, device_type, time.time()))
        except BaseException as e:  # noqa: BLE001 - raised on the mapping side
            self.buffer.finish(
                DataError(f"{self.name}: cannot read a streamed frame ({type(e).__name__}: {e})")
            )

    def _on_stopped(self) -> None:
        log.info("%s: the stream stopped", self.name)
        self.buffer.finish()

    def _close(self) -> None:
        disconnect = getattr(self._session, "disconnect", None)
        if callable(disconnect):
            disconnect()

    def _to_frame(self, raw: Any, index: int) -> Frame:
        rgb, depth, conf, (fx, fy, tx, ty), pose, device_type, timestamp = raw
        if depth.ndim != 2 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise DataError(f"{self.name}: frame {index} has depth {depth.shape} and colour {rgb.shape}")
        if device_type == TRUEDEPTH:  # the front camera's images are mirrored
            depth, rgb = depth[:, ::-1], rgb[:, ::-1]
            conf = conf[:, ::-1] if conf.ndim == 2 else conf
        dh, dw = depth.shape
        h, w = rgb.shape[:2]
        # the coefficients describe the colour image; a principal point near the depth image's centre says
        # they were given for the depth image instead
        sx, sy = (1.0, 1.0) if abs(tx - dw / 2) < abs(tx - w / 2) else (dw / w, dh / h)
        if not self._warned_K:
            log.info("%s: intrinsics of the %s image", self.name, "depth" if sx == 1.0 else "colour")
            self._warned_K = True
        # Record3D's (like ARKit's) principal point counts pixel centres from 0; ours puts (0, 0)'s at 0.5
        K = np.array(
            [[fx * sx, 0.0, (tx + 0.5) * sx], [0.0, fy * sy, (ty + 0.5) * sy], [0.0, 0.0, 1.0]], np.float32
        )
        if (h, w) != (dh, dw):
            rgb = cv2.resize(np.ascontiguousarray(rgb), (dw, dh), interpolation=cv2.INTER_AREA)
        depth = np.ascontiguousarray(depth)
        if self.min_confidence > 0 and conf.shape == depth.shape:
            depth = np.where(conf >= self.min_confidence, depth, 0.0)
        return frame_from_arrays(index, rgb, depth, K, timestamp, arkit_to_opencv(pose))
