"""ROS recordings as RGB-D sequences: ROS 1 ``.bag`` files, ROS 2 bag folders (sqlite3 or MCAP storage) and
bare ``.mcap`` files, read with ``rosbags`` (``pip install "ogscene3d[ros]"``; no ROS install needed).

What is read (each chosen by message type when the recording has one candidate, else by the ``data.ros_*``
settings; a missing one is an error listing the recording's topics and types):

- colour: sensor_msgs/Image (rgb8, bgr8, mono8, rgba8, bgra8) or CompressedImage (jpeg/png);
- depth: sensor_msgs/Image (16UC1 / mono16 in raw units, millimetres unless ``data.depth_scale`` says
  otherwise; 32FC1 in metres) or CompressedImage (image_transport's compressedDepth, or a 16-bit PNG).
  Depth must be registered to colour (RealSense's ``aligned_depth_to_color``): a depth topic whose images
  have another size or another ``frame_id`` than the colour images is refused;
- intrinsics: the colour camera's sensor_msgs/CameraInfo (``data.intrinsics`` overrides it). Lens distortion
  is not corrected; a non-zero one is warned about with the pixel error it causes in the image corners;
- poses: the camera frame's pose in the world frame from /tf and /tf_static, chained through intermediate
  frames and interpolated to each colour image's stamp; else a geometry_msgs/PoseStamped,
  PoseWithCovarianceStamped or nav_msgs/Odometry topic (interpolated too, composed with /tf_static when it
  gives the pose of another frame, e.g. ``base_link``); else none, and frames must be tracked
  (``--poses odometry``).

Frames are the colour images with a depth image within ``data.ros_sync_tolerance`` seconds (paired one to
one, closest first, by header stamps) and, when the recording has poses, a pose; the images left out are
counted and named in a warning. A frame is named ``frameNNNNNN`` after its colour image's position on the
colour topic, which is what precomputed segments are looked up by. Pixels are decoded when a frame is read;
a corrupt message is a DataError naming the topic and its time (skipped with ``data.on_bad_frame: skip``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import DataConfig
from ..errors import DataError
from .base import FrameRecord, decode_depth
from .decoded import DecodedDataset
from .rosbag_io import (
    CAMERA_INFO,
    COMPRESSED,
    IMAGE,
    POSE_TYPES,
    TF,
    Bag,
    camera_info,
    decode_colour,
    decode_depth_message,
    distortion_shift,
    image_kind,
    is_bag_path,
    stamp_seconds,
)
from .rosbag_tf import TfTree, Track
from .tum import associate

log = logging.getLogger(__name__)

LISTED = 5  # dropped images named in a warning; the rest are counted


@dataclass
class BagFrameRecord(FrameRecord):
    """A frame's colour and depth messages: (receive time in ns, position among the topic's messages with
    that receive time)."""

    rgb_ref: tuple[int, int] = (0, 0)
    depth_ref: tuple[int, int] = (0, 0)


@dataclass
class _Image:
    """What the header scan learnt about one image message."""

    index: int  # position on its topic
    stamp: float  # header stamp, seconds
    ref: tuple[int, int]
    frame_id: str
    size: tuple[int, int] | None  # (height, width); None for a compressed image (known once decoded)


def _topic_choice(what: str, option: str, candidates: list[str], bag: Bag, hint: str = "") -> str:
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        raise DataError(f"{bag.path}: no {what} topic{hint}; the recording's topics:\n{bag.topics()}")
    listed = ", ".join(sorted(candidates))
    raise DataError(f"{bag.path}: several {what} topics ({listed}); choose one with data.{option}")


def _without_transport_copies(topics: list[str]) -> list[str]:
    """``topics`` less the image_transport republications (``X/compressed``, ``X/compressedDepth``) of a
    topic ``X`` that is there too: the same images, once."""
    names = set(topics)
    return [
        t
        for t in topics
        if not (t.rsplit("/", 1)[0] in names and t.rsplit("/", 1)[-1].startswith("compressed"))
    ]


class RosBagDataset(DecodedDataset):
    kind = "rosbag"
    depth_scale_default = 1000.0  # 16UC1 depth is in millimetres by ROS convention (REP 118)
    pixel_centers_default = "integer"  # CameraInfo is an OpenCV calibration

    @staticmethod
    def detect(root: Path) -> bool:
        return is_bag_path(Path(root))

    def __init__(self, root: Path, config: DataConfig, segments_dir: Path | None = None) -> None:
        root = Path(root)
        tol = float(config.ros_sync_tolerance)
        if not np.isfinite(tol) or tol < 0:
            raise DataError(f"data.ros_sync_tolerance must be a number of seconds >= 0, got {tol}")
        self.bag = Bag(root)
        try:
            records, K, size = self._scan(root, config, tol)
        except BaseException:
            self.bag.close()
            raise
        self._size = size
        super().__init__(root, records, K, config, segments_dir)

    # -- opening

    def _scan(
        self, root: Path, config: DataConfig, tol: float
    ) -> tuple[list[BagFrameRecord], np.ndarray | None, tuple[int, int]]:
        bag = self.bag
        by_topic = bag.topic_map()
        self._skip = config.on_bad_frame == "skip"
        rgb_topic, depth_topic = self._image_topics(config, by_topic)
        self.rgb_conn, self.depth_conn = by_topic[rgb_topic], by_topic[depth_topic]
        colour = self._scan_images(self.rgb_conn)
        depth = self._scan_images(self.depth_conn)
        if not colour or not depth:
            empty = rgb_topic if not colour else depth_topic
            raise DataError(f"{root}: topic {empty} holds no readable image")
        size = self._check_registered(colour, depth)

        d_idx = associate(
            np.array([c.stamp for c in colour]),
            np.array([d.stamp for d in depth]),
            max_dt=tol,
            one_to_one=True,
        )
        paired = [(c, depth[j]) for c, j in zip(colour, d_idx) if j >= 0]
        unpaired = [c for c, j in zip(colour, d_idx) if j < 0]
        if not paired:
            gap = min(abs(c.stamp - d.stamp) for c in colour[:50] for d in depth[:50])
            raise DataError(
                f"{root}: no colour image on {rgb_topic} has a depth image on {depth_topic} within "
                f"data.ros_sync_tolerance = {tol} s (the closest pair among the first 50 of each is "
                f"{gap:.3f} s apart): the streams are not synchronised, or their stamps use different clocks"
            )
        self._warn_dropped(unpaired, f"have no depth image on {depth_topic} within {tol} s", len(colour))

        poses = self._poses(config, by_topic, colour[0].frame_id, [c.stamp for c, _ in paired], tol)
        records: list[BagFrameRecord] = []
        no_pose: list[_Image] = []
        for k, (c, d) in enumerate(paired):
            pose, source = poses[k] if poses is not None else (None, "")
            if poses is not None and pose is None:
                no_pose.append(c)
                continue
            name = f"frame{c.index:06d}"
            records.append(
                BagFrameRecord(
                    name=name,
                    rgb_path=root / name,
                    depth_path=root / name,
                    pose=pose,
                    pose_source=f"{root}: {source} at t={c.stamp:.6f}",
                    timestamp=c.stamp,
                    rgb_ref=c.ref,
                    depth_ref=d.ref,
                )
            )
        if not records:
            raise DataError(
                f"{root}: none of the {len(paired)} synchronised colour/depth pairs has a camera pose "
                f"({self.pose_desc}) within {tol} s of its stamp"
            )
        self._warn_dropped(no_pose, f"have no pose ({self.pose_desc}) within {tol} s", len(colour))
        K = None if config.intrinsics is not None else self._intrinsics(config, by_topic, rgb_topic, size)
        return records, K, size

    def _first_message(self, conn: Any) -> Any | None:
        for c, _, raw in self.bag.messages([conn]):
            try:
                return self.bag.deserialize(raw, c)
            except DataError:
                return None
        return None

    def _image_topics(self, config: DataConfig, by_topic: dict[str, Any]) -> tuple[str, str]:
        bag = self.bag
        for option in ("ros_rgb_topic", "ros_depth_topic"):
            topic = getattr(config, option)
            if topic is not None and topic not in by_topic:
                raise DataError(
                    f"{bag.path}: data.{option} = {topic!r} is not a topic of the recording; its topics:\n"
                    f"{bag.topics()}"
                )
            if topic is not None and by_topic[topic].msgtype not in (IMAGE, COMPRESSED):
                raise DataError(
                    f"{bag.path}: data.{option} = {topic!r} carries {by_topic[topic].msgtype}, not "
                    "sensor_msgs/Image or sensor_msgs/CompressedImage"
                )
        kinds: dict[str, str | None] = {}
        firsts: dict[str, Any] = {}
        for topic, conn in by_topic.items():
            if conn.msgtype in (IMAGE, COMPRESSED) and topic not in (
                config.ros_rgb_topic,
                config.ros_depth_topic,
            ):
                msg = self._first_message(conn)
                firsts[topic] = msg
                kinds[topic] = None if msg is None else image_kind(msg, conn.msgtype)
        rgb = config.ros_rgb_topic
        if rgb is None:
            cands = _without_transport_copies([t for t, k in kinds.items() if k == "colour"])
            # infrared cameras publish mono8 too: with a colour stream beside them, they are not candidates
            coloured = [t for t in cands if getattr(firsts[t], "encoding", "rgb8") != "mono8"]
            rgb = _topic_choice(
                "colour image", "ros_rgb_topic", coloured or cands, bag,
                " (sensor_msgs/Image rgb8/bgr8/mono8, or a jpeg/png CompressedImage)",
            )  # fmt: skip
        depth = config.ros_depth_topic
        if depth is None:
            cands = _without_transport_copies([t for t, k in kinds.items() if k == "depth"])
            if len(cands) > 1:
                # the depth registered to the colour camera (RealSense's aligned_depth_to_color) is the one
                rgb_msg = firsts.get(rgb) or self._first_message(by_topic[rgb])
                frame = None if rgb_msg is None else rgb_msg.header.frame_id
                registered = [
                    t for t in cands if firsts[t] is not None and firsts[t].header.frame_id == frame
                ]
                cands = registered or cands
            depth = _topic_choice(
                "depth image", "ros_depth_topic", cands, bag,
                " (sensor_msgs/Image 16UC1/32FC1, or a compressedDepth CompressedImage)",
            )  # fmt: skip
        if rgb == depth:
            raise DataError(f"{bag.path}: the colour and depth topics are both {rgb}")
        return rgb, depth

    def _bad(self, msg: str) -> None:
        if not self._skip:
            raise DataError(f"{msg}; set data.on_bad_frame: skip to leave such messages out")
        log.warning("%s; leaving it out (data.on_bad_frame: skip)", msg)

    def _deserialized(self, conns: list[Any], what: str = "message") -> Iterator[tuple[Any, Any]]:
        """(connection, message) of every message on ``conns`` in order; one that does not deserialize is
        :meth:`_bad` (an error, or left out with ``data.on_bad_frame: skip``)."""
        for k, (c, t, raw) in enumerate(self.bag.messages(conns)):
            try:
                msg = self.bag.deserialize(raw, c)
            except DataError as e:
                self._bad(f"{self.bag.path}: {what} {k} on {c.topic} (t={t * 1e-9:.6f}): {e}")
                continue
            yield c, msg

    def _scan_images(self, conn: Any) -> list[_Image]:
        """Header stamp, frame and size of every image on ``conn`` (pixels are not decoded)."""
        out: list[_Image] = []
        last_t, same = None, 0
        for k, (c, t, raw) in enumerate(self.bag.messages([conn])):
            same = same + 1 if t == last_t else 0
            last_t = t
            try:
                msg = self.bag.deserialize(raw, c)
                stamp = stamp_seconds(msg.header)
            except (DataError, AttributeError) as e:
                self._bad(f"{self.bag.path}: message {k} on {conn.topic} (t={t * 1e-9:.6f}): {e}")
                continue
            size = (int(msg.height), int(msg.width)) if conn.msgtype == IMAGE else None
            out.append(_Image(k, stamp, (t, same), str(msg.header.frame_id).lstrip("/"), size))
        return out

    def _read_message(self, conn: Any, ref: tuple[int, int]) -> Any:
        t, same = ref
        for k, (c, _, raw) in enumerate(self.bag.messages([conn], start=t, stop=t + 1)):
            if k == same:
                return self.bag.deserialize(raw, c)
        raise DataError(f"{self.bag.path}: the message of {conn.topic} at t={t * 1e-9:.6f} is gone")

    def _compressed_size(self, conn: Any, images: list[_Image]) -> tuple[int, int]:
        msg = self._read_message(conn, images[0].ref)
        try:
            arr = (
                decode_colour(msg, conn.msgtype)
                if image_kind(msg, conn.msgtype) == "colour"
                else (decode_depth_message(msg, conn.msgtype))
            )
        except ValueError as e:
            raise DataError(f"{self.bag.path}: the first image on {conn.topic} cannot be decoded: {e}") from e
        return arr.shape[:2]

    def _check_registered(self, colour: list[_Image], depth: list[_Image]) -> tuple[int, int]:
        """The frames' (height, width); DataError when the depth images are not registered to colour."""
        rgb_topic, depth_topic = self.rgb_conn.topic, self.depth_conn.topic
        c_size = colour[0].size or self._compressed_size(self.rgb_conn, colour)
        d_size = depth[0].size or self._compressed_size(self.depth_conn, depth)
        fix = (
            "record depth registered to colour (realsense2_camera: align_depth.enable:=true, topic "
            "/camera/aligned_depth_to_color/image_raw) or choose such a topic with data.ros_depth_topic"
        )
        if c_size != d_size:
            raise DataError(
                f"{self.bag.path}: depth on {depth_topic} ({d_size[1]}x{d_size[0]}) is not registered to "
                f"colour "
                f"on {rgb_topic} ({c_size[1]}x{c_size[0]}): the sizes differ; {fix}"
            )
        c_frame, d_frame = colour[0].frame_id, depth[0].frame_id
        if c_frame and d_frame and c_frame != d_frame:
            raise DataError(
                f"{self.bag.path}: depth on {depth_topic} (frame {d_frame!r}) is not registered to colour on "
                f"{rgb_topic} (frame {c_frame!r}): the camera frames differ; {fix}"
            )
        return c_size

    def _warn_dropped(self, dropped: list[_Image], why: str, total: int) -> None:
        if not dropped:
            return
        named = ", ".join(f"frame{c.index:06d} (t={c.stamp:.6f})" for c in dropped[:LISTED])
        if len(dropped) > LISTED:
            named += f" and {len(dropped) - LISTED} more"
        log.warning(
            "%s: %d of the %d colour images on %s %s; left out: %s",
            self.bag.path, len(dropped), total, self.rgb_conn.topic, why, named,
        )  # fmt: skip

    def _intrinsics(
        self, config: DataConfig, by_topic: dict[str, Any], rgb_topic: str, size: tuple[int, int]
    ) -> np.ndarray:
        topic = config.ros_camera_info_topic
        if topic is None:
            cands = [t for t, c in by_topic.items() if c.msgtype == CAMERA_INFO]
            base = rgb_topic
            if base.rsplit("/", 1)[-1].startswith("compressed"):
                base = base.rsplit("/", 1)[0]
            beside = base.rsplit("/", 1)[0] + "/camera_info"
            topic = beside if beside in cands else _topic_choice(
                "sensor_msgs/CameraInfo", "ros_camera_info_topic", cands, self.bag,
                " for the colour camera (or give data.intrinsics = [fx, fy, cx, cy])",
            )  # fmt: skip
        elif topic not in by_topic or by_topic[topic].msgtype != CAMERA_INFO:
            raise DataError(
                f"{self.bag.path}: data.ros_camera_info_topic = {topic!r} is not a CameraInfo topic of the "
                f"recording; its topics:\n{self.bag.topics()}"
            )
        msg = self._first_message(by_topic[topic])
        if msg is None:
            raise DataError(f"{self.bag.path}: {topic} holds no readable CameraInfo message")
        K, D, model, info_size = camera_info(msg)
        if info_size != (0, 0) and info_size != size:
            raise DataError(
                f"{self.bag.path}: {topic} describes {info_size[1]}x{info_size[0]} images, the colour "
                "images are "
                f"{size[1]}x{size[0]}: give the colour camera's info with data.ros_camera_info_topic"
            )
        if np.any(D != 0):
            shift = distortion_shift(K, D, model, size)
            log.warning(
                "%s: %s gives lens distortion %s %s, which is not corrected: %s; rectified images "
                "(image_rect topics) have none",
                self.bag.path, topic, model, np.round(D, 4).tolist(),
                f"colour and depth land up to {shift:.1f} px off in the image corners" if shift is not None
                else "its effect is unknown",
            )  # fmt: skip
        return K

    # -- poses

    def _poses(
        self, config: DataConfig, by_topic: dict[str, Any], image_frame: str, stamps: list[float], tol: float
    ) -> list[tuple[np.ndarray | None, str]] | None:
        """(pose, source) per stamp, or None when the recording has no poses (frames must be tracked)."""
        camera = (config.ros_camera_frame or image_frame).lstrip("/")
        tf = self._read_tf(by_topic)
        pose_topic = config.ros_pose_topic
        if pose_topic is not None and (
            pose_topic not in by_topic or by_topic[pose_topic].msgtype not in POSE_TYPES
        ):
            raise DataError(
                f"{self.bag.path}: data.ros_pose_topic = {pose_topic!r} is not a "
                f"{'/'.join(POSE_TYPES)} topic of "
                f"the recording; its topics:\n{self.bag.topics()}"
            )
        if pose_topic is None and tf is not None and (tf.chain(camera) or config.ros_world_frame):
            return self._tf_poses(
                tf, (config.ros_world_frame or tf.root(camera)).lstrip("/"), camera, stamps, tol
            )
        if pose_topic is None:
            cands = [t for t, c in by_topic.items() if c.msgtype in POSE_TYPES]
            if len(cands) > 1:
                _topic_choice("pose", "ros_pose_topic", cands, self.bag)
            pose_topic = cands[0] if cands else None
        if pose_topic is None:
            self.pose_desc = "none"
            log.warning(
                "%s: the recording has no camera poses (no /tf chain to %r, no PoseStamped/Odometry topic): "
                "track them with --poses odometry (config tracking.poses: odometry)",
                self.bag.path, camera,
            )  # fmt: skip
            return None
        return self._topic_poses(by_topic[pose_topic], pose_topic, tf, camera, stamps, tol)

    def _tf_poses(
        self, tf: TfTree, world: str, camera: str, stamps: list[float], tol: float
    ) -> list[tuple[np.ndarray | None, str]]:
        """The camera's poses in ``world`` from the recording's tf tree."""
        if camera not in tf.frames or world not in tf.frames:
            missing = camera if camera not in tf.frames else world
            raise DataError(
                f"{self.bag.path}: tf has no frame {missing!r}; its frames: "
                f"{', '.join(sorted(tf.frames))} "
                "(set data.ros_world_frame / data.ros_camera_frame)"
            )
        if tf.root(world) != tf.root(camera):
            raise DataError(
                f"{self.bag.path}: tf does not connect {world!r} and {camera!r} (their trees' roots are "
                f"{tf.root(world)!r} and {tf.root(camera)!r})"
            )
        self.pose_desc = f"tf {world} -> {camera}"
        self._rep103(world)
        out = [(tf.lookup(world, camera, t, tol), self.pose_desc) for t in stamps]
        if not any(p is not None for p, _ in out):
            raise DataError(
                f"{self.bag.path}: tf gives no pose of {camera!r} in {world!r} at the images' stamps "
                f"({stamps[0]:.3f}..{stamps[-1]:.3f} s): transform "
                f"{tf.gap(world, camera, stamps[0], tol)} "
                "has no sample near them"
            )
        return out

    def _topic_poses(
        self, conn: Any, pose_topic: str, tf: TfTree | None, camera: str, stamps: list[float], tol: float
    ) -> list[tuple[np.ndarray | None, str]]:
        """The camera's poses from a PoseStamped/Odometry topic, through tf where the topic's frame is
        another body than the camera."""
        track = self._read_pose_topic(conn)
        body = track.child or camera
        link = None
        if body != camera:
            if (
                tf is None
                or camera not in tf.frames
                or body not in tf.frames
                or tf.root(body) != tf.root(camera)
            ):
                raise DataError(
                    f"{self.bag.path}: {pose_topic} gives the pose of frame {body!r}, and no tf chain leads "
                    "from it "
                    f"to the camera frame {camera!r}: record /tf_static too, or set data.ros_camera_frame"
                )
            link = tf
        self._rep103(track.parent or pose_topic)
        self.pose_desc = f"{pose_topic} ({track.parent} -> {body})" + (
            f" and tf {body} -> {camera}" if link else ""
        )
        out = []
        for t in stamps:
            T = track.at(t, tol)
            if T is not None and link is not None:
                step = link.lookup(body, camera, t, tol)
                T = None if step is None else T @ step
            out.append((T, self.pose_desc))
        return out

    def _rep103(self, world: str) -> None:
        """The poses' world is a ROS world frame: z-up (REP 103: x forward, y left, z up)."""
        self.up_axis = (0.0, 0.0, 1.0)
        self.up_axis_source = f"ROS's REP 103 (the world frame {world!r} of the recording's poses is z-up)"

    def _read_tf(self, by_topic: dict[str, Any]) -> TfTree | None:
        conns = [c for c in by_topic.values() if c.msgtype == TF]
        if not conns:
            return None
        tree = TfTree()
        for c, msg in self._deserialized(conns, "tf message"):
            static = c.topic.rstrip("/").endswith("tf_static")
            for tr in msg.transforms:
                v, q = tr.transform.translation, tr.transform.rotation
                tree.add(
                    tr.header.frame_id, tr.child_frame_id, stamp_seconds(tr.header),
                    (v.x, v.y, v.z), (q.x, q.y, q.z, q.w), static,
                )  # fmt: skip
        tree.finish()
        return tree

    def _read_pose_topic(self, conn: Any) -> Track:
        track: Track | None = None
        for _, msg in self._deserialized([conn]):
            pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
            if track is None:
                track = Track(
                    str(msg.header.frame_id).lstrip("/"), str(getattr(msg, "child_frame_id", "")).lstrip("/")
                )
            p, q = pose.position, pose.orientation
            track.add(stamp_seconds(msg.header), np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w]))
        if track is None:
            raise DataError(f"{self.bag.path}: pose topic {conn.topic} holds no readable message")
        track.finish()
        return track

    # -- reading

    def _image_size(self) -> tuple[int, int]:
        return self._size

    def _read_arrays(self, rec: FrameRecord) -> tuple[np.ndarray, np.ndarray]:
        assert isinstance(rec, BagFrameRecord)
        out = []
        for conn, ref, what in (
            (self.rgb_conn, rec.rgb_ref, "colour"),
            (self.depth_conn, rec.depth_ref, "depth"),
        ):
            msg = self._read_message(conn, ref)
            try:
                if what == "colour":
                    arr = decode_colour(msg, conn.msgtype)
                else:
                    raw = decode_depth_message(msg, conn.msgtype)
                    arr = (
                        raw
                        if raw.dtype == np.float32
                        else decode_depth(raw, self.depth_format, self.depth_scale)
                    )
                    if self.invalid_raw is not None and raw.dtype == np.uint16:
                        arr[raw == self.invalid_raw] = 0.0
            except (ValueError, AttributeError) as e:
                raise DataError(
                    f"{self.bag.path}: {what} image of {rec.name} on {conn.topic} "
                    f"(t={ref[0] * 1e-9:.6f}): {e}"
                ) from e
            if arr.shape[:2] != self._size:
                raise DataError(
                    f"{self.bag.path}: {what} image of {rec.name} on {conn.topic} is "
                    f"{arr.shape[1]}x{arr.shape[0]}, "
                    f"the recording's first is {self._size[1]}x{self._size[0]}"
                )
            out.append(arr)
        return out[0], out[1]
