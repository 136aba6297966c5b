"""An Intel RealSense camera through pyrealsense2 (``pip install "ogscene3d[realsense]"``): colour and depth,
depth aligned to colour by librealsense (``rs.align``), intrinsics of the colour stream, depth units from the
depth sensor. A librealsense recording (``.db3``, or ``.bag`` from SDKs before 2.57) plays back as the device.

Frames carry no pose: they are tracked (``tracking.poses: odometry``).
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import DataError
from ..frame import Frame
from ..optional import require
from .base import CameraStream, frame_from_arrays

log = logging.getLogger(__name__)

# the colour formats asked of a live device (rgb8: no conversion) and the ones a recording may hold
_TO_RGB = {"rgb8": None, "bgr8": cv2.COLOR_BGR2RGB, "rgba8": cv2.COLOR_RGBA2RGB, "bgra8": cv2.COLOR_BGRA2RGB}


class RealSenseStream(CameraStream):
    """``serial``: the device to open (None: the first one); ``playback``: a recording to play instead, at
    recorded speed when ``real_time`` (frames the mapper is too slow for are skipped, as live) or frame by
    frame otherwise (none skipped: the player waits for the mapper). ``width``/``height``/``fps``: the colour
    and depth stream modes of a live device. ``rs``: the pyrealsense2 module (tests pass a stand-in)."""

    def __init__(
        self,
        serial: str | None = None,
        playback: str | Path | None = None,
        width: int = 640,
        height: int = 480,
        fps: int = 30,
        real_time: bool = True,
        max_frames: int | None = None,
        timeout: float = 10.0,
        rs: Any = None,
    ) -> None:
        super().__init__(max_frames, timeout)
        self.serial, self.playback = serial, Path(playback) if playback is not None else None
        self.width, self.height, self.fps, self.real_time = width, height, fps, real_time
        self.name = f"realsense {playback}" if playback else f"realsense {serial or '(first device)'}"
        self._rs = rs
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.K: np.ndarray | None = None
        self.unsynchronised = 0  # framesets left out: colour and depth more than half a frame apart
        self.depth_scale = 0.001

    def _module(self) -> Any:
        return self._rs or require("pyrealsense2", "realsense", "--source realsense")

    def check(self) -> None:
        rs = self._module()
        if self.playback is not None:
            if not self.playback.is_file():
                raise DataError(f"{self.playback}: RealSense recording does not exist")
            return
        serials = [d.get_info(rs.camera_info.serial_number) for d in rs.context().query_devices()]
        if not serials:
            raise DataError(
                "RealSense: no camera connected (on a USB 3 port?); rs-enumerate-devices lists them"
            )
        if self.serial and self.serial not in serials:
            raise DataError(
                f"RealSense: no camera with serial {self.serial}; connected: {', '.join(serials)}"
            )

    def _open(self) -> None:
        rs = self._module()
        if self.playback is not None and not self.playback.is_file():
            raise DataError(f"{self.playback}: RealSense recording does not exist")
        pipe, cfg = rs.pipeline(), rs.config()
        if self.playback is not None:
            cfg.enable_device_from_file(str(self.playback), repeat_playback=False)
        else:
            if self.serial:
                cfg.enable_device(self.serial)
            cfg.enable_stream(rs.stream.depth, self.width, self.height, rs.format.z16, self.fps)
            cfg.enable_stream(rs.stream.color, self.width, self.height, rs.format.rgb8, self.fps)
        try:
            profile = pipe.start(cfg)
        except RuntimeError as e:
            what = f"recording {self.playback}" if self.playback else f"device {self.serial or '(any)'}"
            raise DataError(
                f"RealSense: cannot start the {what} ({e}); is the camera plugged in (USB 3) and free?"
            ) from e
        try:
            device = profile.get_device()
            if self.playback is not None:
                device.as_playback().set_real_time(self.real_time)
            self.depth_scale = float(device.first_depth_sensor().get_depth_scale())
            intr = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
            # librealsense counts pixel centres from 0 (OpenCV); ogscene3d's K puts (0, 0)'s at (0.5, 0.5)
            self.K = np.array(
                [[intr.fx, 0.0, intr.ppx + 0.5], [0.0, intr.fy, intr.ppy + 0.5], [0.0, 0.0, 1.0]], np.float32
            )
            coeffs = [float(c) for c in intr.coeffs]
            if any(abs(c) > 1e-6 for c in coeffs):
                log.warning(
                    "%s: the colour stream has lens distortion %s %s, which is not corrected", self.name,
                    intr.model, np.round(coeffs, 4).tolist(),
                )  # fmt: skip
        except Exception:
            pipe.stop()
            raise
        self._pipe = pipe
        self._align = None if _registered(rs, profile) else rs.align(rs.stream.color)
        self._formats = {getattr(rs.format, name, None): name for name in _TO_RGB}
        self._thread = threading.Thread(target=self._capture, name="realsense-capture", daemon=True)
        self._thread.start()

    def _capture(self) -> None:
        try:
            while not self._stop.is_set():
                ok, frames = self._pipe.try_wait_for_frames(1000)
                if not ok:
                    if self.playback is not None:
                        break  # the recording has ended
                    continue
                if not self._synchronised(frames):
                    continue
                aligned = self._align.process(frames) if self._align is not None else frames
                colour, depth = aligned.get_color_frame(), aligned.get_depth_frame()
                if not colour or not depth:
                    continue
                fmt = self._formats.get(colour.get_profile().format())
                if fmt is None:
                    raise DataError(
                        f"{self.name}: colour format {colour.get_profile().format()} is not supported "
                        f"(expected one of {sorted(_TO_RGB)})"
                    )
                # copies: librealsense reuses the frames' memory once they are released
                rgb = np.array(np.asanyarray(colour.get_data()), copy=True)
                raw = np.array(np.asanyarray(depth.get_data()), copy=True)
                item = (rgb, fmt, raw, float(frames.get_timestamp()) * 1e-3)
                self.buffer.put(item, wait=self.playback is not None and not self.real_time)
        except BaseException as e:  # noqa: BLE001 - raised on the mapping side
            self.buffer.finish(e)
            return
        self.buffer.finish()

    def _synchronised(self, frames: Any) -> bool:
        """Whether the frameset's colour and depth images were taken within half a frame of each other
        (librealsense's syncer hands over an unmatched pair when one stream lags); counted otherwise."""
        colour, depth = frames.get_color_frame(), frames.get_depth_frame()
        if not colour or not depth:
            return False
        fps = colour.get_profile().fps() or 30
        if abs(colour.get_timestamp() - depth.get_timestamp()) <= 500.0 / fps:
            return True
        self.unsynchronised += 1
        if self.unsynchronised == 1:
            log.warning("%s: colour and depth frames more than half a frame apart are left out", self.name)
        return False

    def _close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self._pipe.stop()

    def _to_frame(self, raw: Any, index: int) -> Frame:
        rgb, fmt, depth, timestamp = raw
        if _TO_RGB[fmt] is not None:
            rgb = cv2.cvtColor(rgb, _TO_RGB[fmt])
        return frame_from_arrays(
            index, rgb, depth.astype(np.float32) * np.float32(self.depth_scale), self.K, timestamp
        )


def _registered(rs: Any, profile: Any) -> bool:
    """Whether the depth stream is already registered to colour (same intrinsics, no rotation or offset
    between them): aligning it would only add librealsense's resampling holes."""
    try:
        d = profile.get_stream(rs.stream.depth).as_video_stream_profile()
        c = profile.get_stream(rs.stream.color).as_video_stream_profile()
        ext = d.get_extrinsics_to(c)
        di, ci = d.get_intrinsics(), c.get_intrinsics()
    except RuntimeError:
        return False
    same = (di.width, di.height, di.fx, di.fy, di.ppx, di.ppy) == (
        ci.width,
        ci.height,
        ci.fx,
        ci.fy,
        ci.ppx,
        ci.ppy,
    )
    return same and np.allclose(ext.rotation, np.eye(3).reshape(-1)) and np.allclose(ext.translation, 0.0)
