"""Opening ROS recordings with ``rosbags`` (ROS 1 ``.bag``, ROS 2 bag folders with sqlite3 or MCAP storage,
bare ``.mcap`` files) and decoding the sensor messages ogscene3d reads: sensor_msgs/Image,
sensor_msgs/CompressedImage (jpeg/png and image_transport's compressedDepth) and sensor_msgs/CameraInfo.

Message fields are read under both spellings: ROS 1 definitions name CameraInfo's matrices ``K``/``D``,
ROS 2 ones ``k``/``d``.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import DataError
from ..optional import require

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF = "tf2_msgs/msg/TFMessage"
POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
)

COLOUR_ENCODINGS = ("rgb8", "bgr8", "mono8", "rgba8", "bgra8")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")


def is_ros2_folder(path: Path) -> bool:
    """Whether ``path`` is a ROS 2 bag folder (its ``metadata.yaml`` describes a rosbag2 recording)."""
    meta = path / "metadata.yaml"
    if not meta.is_file():
        return False
    try:
        with meta.open("r", encoding="utf-8", errors="replace") as f:
            return "rosbag2_bagfile_information" in f.read(4096)
    except OSError:
        return False


def is_bag_path(path: Path) -> bool:
    """A ROS 1 ``.bag`` file, a bare ``.mcap`` file or a ROS 2 bag folder."""
    if path.is_file():
        return path.suffix.lower() in (".bag", ".mcap")
    return path.is_dir() and is_ros2_folder(path)


def stamp_seconds(header: Any) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def field(msg: Any, *names: str) -> Any:
    """The first of ``names`` that ``msg`` has (ROS 1 and ROS 2 spell some fields differently)."""
    for name in names:
        if hasattr(msg, name):
            return getattr(msg, name)
    raise AttributeError(f"message has none of the fields {names}")


@dataclass(frozen=True)
class Topic:
    """A topic with all its connections (a ROS 1 bag has one per publisher: /tf often has several)."""

    topic: str
    msgtype: str
    connections: tuple


class Bag:
    """A ROS recording open for reading: ``topic_map()``, ``messages()`` and ``deserialize()``."""

    def __init__(self, path: Path) -> None:
        require("rosbags", "ros", "reading ROS bags")
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        self._mcap = None
        self._any = None
        try:
            if self.path.is_file() and self.path.suffix.lower() == ".mcap":
                # a bare MCAP file (no metadata.yaml beside it): rosbags' MCAP storage reads it on its own
                from rosbags.rosbag2.storage_mcap import McapReader

                self._mcap = McapReader(self.path)
                self._mcap.open()
                self._store = get_typestore(Stores.ROS2_HUMBLE)
                self.connections = list(self._mcap.connections)
            else:
                from rosbags.highlevel import AnyReader

                self._any = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
                self._any.open()
                self.connections = list(self._any.connections)
        except DataError:
            raise
        except Exception as e:  # rosbags raises its own error types, and struct/OSError on damaged files
            raise DataError(f"{self.path}: cannot open the ROS recording ({type(e).__name__}: {e})") from e

    def close(self) -> None:
        if self._any is not None:
            self._any.close()
            self._any = None
        if self._mcap is not None:
            self._mcap.close()
            self._mcap = None

    def topics(self) -> str:
        """The recording's topics with their types and message counts, one per line (for error messages)."""
        rows = sorted({(c.topic, c.msgtype, c.msgcount) for c in self.connections})
        if not rows:
            return "  (no topics)"
        return "\n".join(f"  {t}  [{m}, {n} messages]" for t, m, n in rows)

    def topic_map(self) -> dict[str, Topic]:
        """The recording's topics by name (connections of one topic with another type than its first are
        left out: no recorder writes them)."""
        out: dict[str, Topic] = {}
        for c in self.connections:
            t = out.get(c.topic)
            if t is None:
                out[c.topic] = Topic(c.topic, c.msgtype, (c,))
            elif c.msgtype == t.msgtype:
                out[c.topic] = Topic(c.topic, c.msgtype, (*t.connections, c))
        return out

    def messages(self, topics: list[Topic], start: int | None = None, stop: int | None = None) -> Iterator:
        """(connection, receive time in ns, raw bytes) of the ``topics`` in receive-time order."""
        reader = self._mcap if self._mcap is not None else self._any
        connections = [c for t in topics for c in t.connections]
        try:
            yield from reader.messages(connections=connections, start=start, stop=stop)
        except DataError:
            raise
        except Exception as e:
            raise DataError(f"{self.path}: cannot read messages ({type(e).__name__}: {e})") from e

    def deserialize(self, raw: bytes, connection: Any) -> Any:
        """The message ``raw`` of ``connection``; DataError naming the topic when it is corrupt."""
        try:
            if self._mcap is not None:
                return self._store.deserialize_cdr(raw, connection.msgtype)
            return self._any.deserialize(raw, connection.msgtype)
        except Exception as e:
            raise DataError(
                f"{self.path}: a {connection.msgtype} message on {connection.topic} is corrupt "
                f"({type(e).__name__}: {e})"
            ) from e


# --------------------------------------------------------------------------------------- image decoding


def _plain_array(msg: Any, dtype: np.dtype, channels: int) -> np.ndarray:
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    row = w * channels * np.dtype(dtype).itemsize
    if h == 0 or w == 0:
        raise ValueError("the image is empty (0 pixels)")
    if step < row or data.size < step * (h - 1) + row:
        raise ValueError(f"{data.size} data bytes do not hold a {w}x{h} {msg.encoding} image (step {step})")
    if data.size < step * h:  # the last row's padding may be left out
        data = np.concatenate([data, np.zeros(step * h - data.size, np.uint8)])
    rows = data[: step * h].reshape(h, step)[:, :row]
    arr = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<"))
    arr = arr.astype(dtype, copy=False).reshape(h, w, channels) if channels > 1 else arr.reshape(h, w)
    return arr


def colour_from_image(msg: Any) -> np.ndarray:
    """uint8 [H, W, 3] RGB from a sensor_msgs/Image (rgb8, bgr8, mono8, rgba8, bgra8)."""
    enc = str(msg.encoding)
    if enc in ("rgb8", "bgr8"):
        img = _plain_array(msg, np.uint8, 3)
        return img if enc == "rgb8" else img[:, :, ::-1]
    if enc in ("rgba8", "bgra8"):
        img = _plain_array(msg, np.uint8, 4)[:, :, :3]
        return img if enc == "rgba8" else img[:, :, ::-1]
    if enc == "mono8":
        return np.repeat(_plain_array(msg, np.uint8, 1)[:, :, None], 3, axis=2)
    raise ValueError(f"colour encoding {enc!r} is not supported (expected one of {COLOUR_ENCODINGS})")


def depth_from_image(msg: Any) -> np.ndarray:
    """Depth from a sensor_msgs/Image: uint16 raw units (16UC1, mono16: millimetres by convention) or
    float32 metres (32FC1)."""
    enc = str(msg.encoding)
    if enc in ("16UC1", "mono16"):
        return _plain_array(msg, np.uint16, 1)
    if enc == "32FC1":
        return _plain_array(msg, np.float32, 1)
    raise ValueError(f"depth encoding {enc!r} is not supported (expected one of {DEPTH_ENCODINGS})")


def _imdecode(data: np.ndarray) -> np.ndarray:
    buf = np.asarray(data, dtype=np.uint8)
    if buf[:8].tobytes() == b"\x89PNG\r\n\x1a\n" and not buf[-16:].tobytes().rstrip(b"\x00").endswith(
        b"IEND\xaeB`\x82"
    ):
        raise ValueError("the PNG is truncated (no IEND chunk)")
    if buf[:2].tobytes() == b"\xff\xd8" and b"\xff\xd9" not in buf[-64:].tobytes():
        raise ValueError("the JPEG is truncated (no end-of-image marker)")
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError("the compressed image cannot be decoded (corrupt or not jpeg/png)")
    return img


def is_compressed_depth(fmt: str) -> bool:
    return "compresseddepth" in fmt.lower().replace(" ", "")


def colour_from_compressed(msg: Any) -> np.ndarray:
    """uint8 [H, W, 3] RGB from a jpeg/png sensor_msgs/CompressedImage (compressed_image_transport stores
    colour as BGR, as OpenCV decodes it)."""
    img = _imdecode(msg.data)
    if img.dtype != np.uint8:
        raise ValueError(f"compressed colour image is {img.dtype}, expected 8-bit")
    if img.ndim == 2:
        return np.repeat(img[:, :, None], 3, axis=2)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


# image_transport's compressedDepth header: enum compressionFormat (int32) and float depthParam[2]
_DEPTH_HEADER = struct.Struct("<iff")


def depth_from_compressed(msg: Any) -> np.ndarray:
    """Depth from a sensor_msgs/CompressedImage: image_transport's compressedDepth (a 12-byte header, then a
    PNG: 16UC1 raw units, or 32FC1 quantised inverse depth) or a plain 16-bit PNG."""
    fmt = str(msg.format)
    data = np.asarray(msg.data, dtype=np.uint8)
    if not is_compressed_depth(fmt):
        img = _imdecode(data)
        if img.dtype != np.uint16 or img.ndim != 2:
            raise ValueError(f"compressed depth ({fmt!r}) must be a single-channel 16-bit PNG")
        return img
    if "rvl" in fmt.lower():
        raise ValueError(f"compressedDepth format {fmt!r} (RVL) is not supported; record png compressedDepth")
    if data.size <= _DEPTH_HEADER.size:
        raise ValueError("compressedDepth message is shorter than its 12-byte header")
    _, quant_a, quant_b = _DEPTH_HEADER.unpack(data[: _DEPTH_HEADER.size].tobytes())
    img = _imdecode(data[_DEPTH_HEADER.size :])
    if img.dtype != np.uint16 or img.ndim != 2:
        raise ValueError("compressedDepth PNG must be single-channel 16-bit")
    if fmt.split(";")[0].strip() == "32FC1":
        # inverse-depth quantisation of compressed_depth_image_transport: depth = A / (q - B), 0 = invalid
        q = img.astype(np.float32)
        out = np.zeros(img.shape, np.float32)
        ok = img > 0
        out[ok] = np.float32(quant_a) / (q[ok] - np.float32(quant_b))
        return out
    return img


def decode_colour(msg: Any, msgtype: str) -> np.ndarray:
    return colour_from_image(msg) if msgtype == IMAGE else colour_from_compressed(msg)


def decode_depth_message(msg: Any, msgtype: str) -> np.ndarray:
    return depth_from_image(msg) if msgtype == IMAGE else depth_from_compressed(msg)


def image_kind(msg: Any, msgtype: str) -> str | None:
    """ "colour", "depth" or None (another image, e.g. a 16-bit infrared one is "depth" by its encoding,
    which topic options then tell apart) from a message's encoding or format."""
    if msgtype == IMAGE:
        enc = str(msg.encoding)
        return "colour" if enc in COLOUR_ENCODINGS else "depth" if enc in DEPTH_ENCODINGS else None
    fmt = str(msg.format).lower()
    if is_compressed_depth(fmt) or fmt.split(";")[0].strip() in ("16uc1", "mono16", "32fc1"):
        return "depth"
    return "colour"


def camera_info(msg: Any) -> tuple[np.ndarray, np.ndarray, str, tuple[int, int]]:
    """(K 3x3, distortion coefficients, distortion model, (height, width)) of a CameraInfo message."""
    K = np.asarray(field(msg, "k", "K"), dtype=np.float64).reshape(3, 3)
    D = np.asarray(field(msg, "d", "D"), dtype=np.float64).reshape(-1)
    return K, D, str(msg.distortion_model), (int(msg.height), int(msg.width))


def distortion_shift(K: np.ndarray, D: np.ndarray, model: str, size: tuple[int, int]) -> float | None:
    """The largest distance in pixels between where an image corner is and where the pinhole model ``K``
    puts it (the error of ignoring the distortion); None for a model OpenCV does not know."""
    h, w = size
    if h <= 0 or w <= 0:
        return None
    pts = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [w / 2, 0], [0, h / 2]], np.float64)
    if model in ("plumb_bob", "rational_polynomial"):
        und = cv2.undistortPoints(pts.reshape(-1, 1, 2), K, D, P=K).reshape(-1, 2)
    elif model == "equidistant" and D.size >= 4:
        und = cv2.fisheye.undistortPoints(pts.reshape(-1, 1, 2), K, D[:4], P=K).reshape(-1, 2)
    else:
        return None
    return float(np.max(np.linalg.norm(und - pts, axis=1)))
