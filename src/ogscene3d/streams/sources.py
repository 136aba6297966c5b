"""Which camera stream a ``--source`` names, and the stream ``ogscene3d-live --source`` maps.

Apart from :mod:`.base` (what every stream shares), so that the camera modules, which build on it, are not
imported by it.
"""

from __future__ import annotations

import logging
from typing import Any

from ..errors import ConfigError
from .base import SOURCES, CameraStream
from .realsense import RealSenseStream
from .record3d import Record3DUSBStream

log = logging.getLogger(__name__)


def open_stream(source: str, max_frames: int | None = None, **options: Any) -> CameraStream:
    """The camera stream that ``--source`` names (not started yet): ``realsense``, ``realsense:SERIAL``,
    ``realsense:RECORDING.db3`` (or ``.bag``), ``record3d``, ``record3d:DEVICE_INDEX``."""
    kind, _, arg = source.partition(":")
    kind = kind.strip().lower()
    if kind == "realsense":
        if arg.lower().endswith((".db3", ".bag")):
            return RealSenseStream(playback=arg, max_frames=max_frames, **options)
        return RealSenseStream(serial=arg or None, max_frames=max_frames, **options)
    if kind == "record3d":
        if arg and not arg.isdigit():
            raise ConfigError(
                f"--source record3d:{arg}: the device index must be a number (0: the first device)"
            )
        return Record3DUSBStream(device_index=int(arg or 0), max_frames=max_frames, **options)
    raise ConfigError(f"unknown --source {source!r}; expected {SOURCES}")


def stream_for_live(
    source: str, cfg: Any, max_frames: int | None, overrides: list[str], check: bool = True
) -> CameraStream:
    """The stream ``ogscene3d-live --source`` maps, with ``cfg.tracking.poses`` set for it: odometry unless
    ``--set tracking.poses=...`` says otherwise (Record3D frames carry ARKit's poses, which ``gt`` uses; a
    RealSense has none). ``check``: look for the camera (or recording) now, so that a missing one is an
    error before the viewer and the mapper are set up; it starts streaming when mapping starts."""
    kind = source.partition(":")[0].strip().lower()
    options = {"min_confidence": int(cfg.data.r3d_min_confidence)} if kind == "record3d" else {}
    stream = open_stream(source, max_frames=max_frames, **options)
    if not any(o.split("=", 1)[0].strip() == "tracking.poses" for o in overrides):
        cfg.tracking.poses = "odometry"
    elif kind == "realsense" and cfg.tracking.poses != "odometry":
        raise ConfigError("--source realsense: the camera gives no poses; leave tracking.poses at odometry")
    log.info("%s: mapping with tracking.poses=%s", stream.name, cfg.tracking.poses)
    if check:
        stream.check()
    return stream
