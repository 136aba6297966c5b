"""Write ROS bags (ROS 1, ROS 2 sqlite3 / MCAP, bare MCAP) and Record3D ``.r3d`` captures from RGB-D frames,
with rosbags' writers and liblzfse, for the robot-input tests."""

from __future__ import annotations

import json
import shutil
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

# camera_link -> camera_color_optical_frame as the RealSense driver publishes it: optical z forward is the
# link's x, optical x right its -y, optical y down its -z (plus the lens offset)
LINK_TO_OPTICAL = np.eye(4)
LINK_TO_OPTICAL[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
LINK_TO_OPTICAL[:3, 3] = [0.01, 0.015, 0.0]

OPTICAL = "camera_color_optical_frame"


@dataclass
class BagSpec:
    """What :func:`write_bag` writes. ``t0`` + ``dt`` * i is frame i's colour stamp."""

    storage: str = "ros1"  # ros1 | sqlite3 | mcap | mcap-file
    colour: str = "rgb8"  # rgb8 | bgr8 | mono8 | png | jpeg
    depth: str = "32FC1"  # 32FC1 | 16UC1 | compressedDepth | none
    poses: str | None = "tf"  # tf | odometry | pose | None
    t0: float = 100.0
    dt: float = 0.1
    depth_offset: float = 0.0  # seconds added to the depth stamps
    depth_frame: str = OPTICAL
    depth_size: tuple[int, int] | None = None  # (h, w) of the depth images; None: the colour size
    corrupt_colour: set[int] = field(default_factory=set)  # frames whose colour message is garbage bytes
    truncated_colour: set[int] = field(default_factory=set)  # frames whose pixel data is cut short
    missing_depth: set[int] = field(default_factory=set)  # frames without a depth image
    tf_publishers: int = 1  # ROS 1: /tf written through this many connections (one per publishing node)
    extra_colour_topic: tuple[str, str] | None = (
        None  # (topic, encoding): the colour again, e.g. an IR camera
    )
    extra_depth_topic: bool = False  # also an unregistered /camera/depth/image_rect_raw
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)


def small_scene(root: Path) -> tuple[Path, list, np.ndarray]:
    """A 4-frame 64x48 synthetic scene in ``root``: (its folder, its frames, K in the OpenCV convention
    (pixel (0, 0) at its centre) that ROS calibrations, librealsense and Record3D use)."""
    from ogscene3d.datasets import make_synthetic_scene, open_dataset

    folder = make_synthetic_scene(root, 1, 4, 64, 48)
    ds = open_dataset(folder)
    K = ds.K.astype(np.float64).copy()
    K[:2, 2] -= 0.5
    return folder, list(ds), K


def _quat(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R).as_quat()  # x, y, z, w


class _Msgs:
    """Message constructors for one typestore (ROS 1 and ROS 2 spell some fields differently)."""

    def __init__(self, ros1: bool) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.ros1 = ros1
        self.ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        if "tf2_msgs/msg/TFMessage" not in self.ts.types:  # rosbags' ROS 1 store lacks tf2_msgs
            from rosbags.typesys import get_types_from_msg

            self.ts.register(
                get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
            )
        self.T = self.ts.types

    def serialize(self, msg, msgtype: str) -> bytes:
        return bytes(
            self.ts.serialize_ros1(msg, msgtype) if self.ros1 else self.ts.serialize_cdr(msg, msgtype)
        )

    def header(self, t: float, frame: str):
        stamp = self.T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=int(round((t - int(t)) * 1e9)))
        if self.ros1:
            return self.T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def image(self, t: float, frame: str, arr: np.ndarray, encoding: str):
        h, w = arr.shape[:2]
        data = np.ascontiguousarray(arr).view(np.uint8).reshape(-1)
        return self.T["sensor_msgs/msg/Image"](
            header=self.header(t, frame), height=h, width=w, encoding=encoding, is_bigendian=0,
            step=data.size // h, data=data,
        )  # fmt: skip

    def compressed(self, t: float, frame: str, data: bytes, fmt: str):
        return self.T["sensor_msgs/msg/CompressedImage"](
            header=self.header(t, frame), format=fmt, data=np.frombuffer(data, np.uint8).copy()
        )

    def camera_info(self, t: float, K: np.ndarray, size: tuple[int, int], D: tuple[float, ...]):
        roi = self.T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        P = np.zeros((3, 4))
        P[:, :3] = K
        mats = {"D": np.array(D, float), "K": K.reshape(-1), "R": np.eye(3).reshape(-1), "P": P.reshape(-1)}
        kw = {k if self.ros1 else k.lower(): v for k, v in mats.items()}
        return self.T["sensor_msgs/msg/CameraInfo"](
            header=self.header(t, OPTICAL), height=size[0], width=size[1], distortion_model="plumb_bob",
            binning_x=0, binning_y=0, roi=roi, **kw,
        )  # fmt: skip

    def _vec(self, name: str, v):
        return self.T[name](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def _quaternion(self, q):
        return self.T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])

    def tf(self, t: float, parent: str, child: str, T: np.ndarray):
        tr = self.T["geometry_msgs/msg/Transform"](
            translation=self._vec("geometry_msgs/msg/Vector3", T[:3, 3]),
            rotation=self._quaternion(_quat(T[:3, :3])),
        )
        ts = self.T["geometry_msgs/msg/TransformStamped"](
            header=self.header(t, parent), child_frame_id=child, transform=tr
        )
        return self.T["tf2_msgs/msg/TFMessage"](transforms=[ts])

    def pose(self, T: np.ndarray):
        return self.T["geometry_msgs/msg/Pose"](
            position=self._vec("geometry_msgs/msg/Point", T[:3, 3]),
            orientation=self._quaternion(_quat(T[:3, :3])),
        )

    def odometry(self, t: float, parent: str, child: str, T: np.ndarray):
        zero = self._vec("geometry_msgs/msg/Vector3", (0, 0, 0))
        twist = self.T["geometry_msgs/msg/TwistWithCovariance"](
            twist=self.T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
        )
        return self.T["nav_msgs/msg/Odometry"](
            header=self.header(t, parent), child_frame_id=child,
            pose=self.T["geometry_msgs/msg/PoseWithCovariance"](pose=self.pose(T), covariance=np.zeros(36)),
            twist=twist,
        )  # fmt: skip

    def pose_stamped(self, t: float, parent: str, T: np.ndarray):
        return self.T["geometry_msgs/msg/PoseStamped"](header=self.header(t, parent), pose=self.pose(T))


def _open_writer(path: Path, storage: str, msgs: _Msgs):
    if storage == "ros1":
        from rosbags.rosbag1 import Writer

        return Writer(path)
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.SQLITE3 if storage == "sqlite3" else StoragePlugin.MCAP
    return Writer(path, version=9, storage_plugin=plugin)


def _depth_message(msgs: _Msgs, t: float, frame: str, depth: np.ndarray, kind: str):
    if kind == "32FC1":
        return msgs.image(t, frame, depth.astype(np.float32), "32FC1")
    mm = np.round(depth * 1000.0).astype(np.uint16)
    if kind == "16UC1":
        return msgs.image(t, frame, mm, "16UC1")
    ok, buf = cv2.imencode(".png", mm)
    data = np.zeros(12, np.uint8).tobytes() + buf.tobytes()  # image_transport's 12-byte header, then the PNG
    return msgs.compressed(t, frame, data, "16UC1; compressedDepth png")


def write_bag(path: Path, frames: list, K_integer: np.ndarray, spec: BagSpec) -> Path:
    """Write ``frames`` (:class:`~ogscene3d.frame.Frame` with poses) as a recording at ``path`` (a ``.bag``
    file, a ROS 2 bag folder, or, for ``mcap-file``, a bare ``.mcap`` file); -> the path to open."""
    msgs = _Msgs(spec.storage == "ros1")
    folder = path.with_suffix("") if spec.storage == "mcap-file" else path
    writer = _open_writer(folder, spec.storage, msgs)
    writer.open()
    img_type = (
        "sensor_msgs/msg/CompressedImage" if spec.colour in ("png", "jpeg") else "sensor_msgs/msg/Image"
    )
    depth_type = (
        "sensor_msgs/msg/CompressedImage" if spec.depth == "compressedDepth" else "sensor_msgs/msg/Image"
    )
    conns = {}

    def conn(topic: str, msgtype: str):
        if topic not in conns:
            conns[topic] = writer.add_connection(topic, msgtype, typestore=msgs.ts)
        return conns[topic]

    def write(topic: str, msgtype: str, t: float, msg) -> None:
        writer.write(conn(topic, msgtype), int(round(t * 1e9)), msgs.serialize(msg, msgtype))

    h, w = frames[0].rgb.shape[:2]
    if spec.poses == "tf":
        write(
            "/tf_static",
            "tf2_msgs/msg/TFMessage",
            spec.t0,
            msgs.tf(spec.t0, "camera_link", OPTICAL, LINK_TO_OPTICAL),
        )
    for i, f in enumerate(frames):
        t = spec.t0 + spec.dt * i
        td = t + spec.depth_offset
        if i == 0:
            info = msgs.camera_info(t, K_integer, (h, w), spec.distortion)
            write("/camera/color/camera_info", "sensor_msgs/msg/CameraInfo", t, info)
        if spec.colour in ("png", "jpeg"):
            ok, buf = cv2.imencode(".png" if spec.colour == "png" else ".jpg", f.rgb[:, :, ::-1])
            msg = msgs.compressed(t, OPTICAL, buf.tobytes(), f"rgb8; {spec.colour} compressed bgr8")
        elif spec.colour == "mono8":
            msg = msgs.image(t, OPTICAL, cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY), "mono8")
        else:
            arr = f.rgb if spec.colour == "rgb8" else f.rgb[:, :, ::-1]
            msg = msgs.image(t, OPTICAL, arr, spec.colour)
        if i in spec.truncated_colour:
            msg.data = msg.data[: msg.data.size // 2]
        topic = "/camera/color/image_raw" + ("/compressed" if img_type.endswith("CompressedImage") else "")
        if i in spec.corrupt_colour:
            writer.write(conn(topic, img_type), int(round(t * 1e9)), b"\x01\x02garbage")
        else:
            write(topic, img_type, t, msg)
        if spec.extra_colour_topic is not None:
            topic2, enc = spec.extra_colour_topic
            arr = cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY) if enc == "mono8" else f.rgb
            write(topic2, "sensor_msgs/msg/Image", t, msgs.image(t, "camera2_optical_frame", arr, enc))
        if spec.depth != "none" and i not in spec.missing_depth:
            depth = f.depth
            if spec.depth_size is not None:
                depth = cv2.resize(depth, spec.depth_size[::-1], interpolation=cv2.INTER_NEAREST)
            suffix = "/compressedDepth" if spec.depth == "compressedDepth" else ""
            dtopic = "/camera/aligned_depth_to_color/image_raw" + suffix
            write(dtopic, depth_type, td, _depth_message(msgs, td, spec.depth_frame, depth, spec.depth))
            if spec.extra_depth_topic:
                raw = msgs.image(td, "camera_depth_optical_frame", depth.astype(np.float32), "32FC1")
                write("/camera/depth/image_rect_raw", "sensor_msgs/msg/Image", td, raw)
        c2w = np.asarray(f.pose, dtype=np.float64)
        if spec.poses == "tf":
            link = c2w @ np.linalg.inv(LINK_TO_OPTICAL)
            msg = msgs.tf(t, "odom", "camera_link", link)
            if spec.tf_publishers > 1:
                key = f"/tf#{i % spec.tf_publishers}"
                if key not in conns:
                    kw = {"callerid": f"/publisher{i % spec.tf_publishers}"}
                    conns[key] = writer.add_connection(
                        "/tf", "tf2_msgs/msg/TFMessage", typestore=msgs.ts, **kw
                    )
                writer.write(conns[key], int(round(t * 1e9)), msgs.serialize(msg, "tf2_msgs/msg/TFMessage"))
            else:
                write("/tf", "tf2_msgs/msg/TFMessage", t, msg)
        elif spec.poses == "odometry":
            write("/odom", "nav_msgs/msg/Odometry", t, msgs.odometry(t, "odom", OPTICAL, c2w))
        elif spec.poses == "pose":
            write("/camera_pose", "geometry_msgs/msg/PoseStamped", t, msgs.pose_stamped(t, "map", c2w))
    writer.close()
    if spec.storage == "mcap-file":
        (mcap,) = folder.glob("*.mcap")
        shutil.move(mcap, path)
        shutil.rmtree(folder)
    return path


def write_r3d(
    path: Path,
    frames: list,
    K_integer: np.ndarray,
    conf: list[np.ndarray] | None = None,
    with_depth_size: bool = True,
    rgb_scale: int = 1,
    lossless: bool = False,
) -> Path:
    """A Record3D capture of ``frames``: colour as JPEG (``rgb_scale`` times the depth size), depth and
    confidence LZFSE-compressed, poses converted to ARKit's axes, K (of the colour size) column-major.
    ``lossless``: colour as PNG under the same ``N.jpg`` names (readers decode by content), so that a test can
    compare maps without JPEG's loss."""
    from ogscene3d.datasets.record3d import lzfse_module

    liblzfse = lzfse_module()
    h, w = frames[0].depth.shape
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    poses = []
    for f in frames:
        T = flip @ np.asarray(f.pose, dtype=np.float64) @ flip
        poses.append([*_quat(T[:3, :3]).tolist(), *T[:3, 3].tolist()])
    K_rgb = K_integer.astype(np.float64).copy()
    K_rgb[:2] *= rgb_scale
    K_rgb[:2, 2] += 0.5 * (rgb_scale - 1)
    meta = {
        "w": w * rgb_scale,
        "h": h * rgb_scale,
        "K": K_rgb.T.reshape(-1).tolist(),
        "fps": 30,
        "poses": poses,
    }
    if with_depth_size:
        meta.update(dw=w, dh=h)
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("metadata", json.dumps(meta))
        for i, f in enumerate(frames):
            rgb = cv2.resize(f.rgb, (w * rgb_scale, h * rgb_scale), interpolation=cv2.INTER_NEAREST)
            if lossless:
                ok, buf = cv2.imencode(".png", rgb[:, :, ::-1])
            else:
                ok, buf = cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
            z.writestr(f"rgbd/{i}.jpg", buf.tobytes())
            z.writestr(f"rgbd/{i}.depth", liblzfse.compress(f.depth.astype(np.float32).tobytes()))
            c = conf[i] if conf is not None else np.full((h, w), 2, np.uint8)
            z.writestr(f"rgbd/{i}.conf", liblzfse.compress(c.astype(np.uint8).tobytes()))
    return path


def _rs_intrinsics(rs, K: np.ndarray, w: int, h: int):
    intr = rs.intrinsics()
    intr.width, intr.height = w, h
    intr.fx, intr.fy = float(K[0, 0]), float(K[1, 1])
    intr.ppx, intr.ppy = float(K[0, 2]), float(K[1, 2])
    intr.model, intr.coeffs = rs.distortion.none, [0.0] * 5
    return intr


def write_realsense_recording(
    path: Path, frames: list, K_integer: np.ndarray, depth_units: float = 0.001, depth_half: bool = False
) -> Path:
    """A librealsense recording (``.db3``) of ``frames``, made with pyrealsense2's software device and
    recorder: a z16 depth and an rgb8 colour stream with ``K_integer``, at one place (identity extrinsics).
    ``depth_half``: depth at half the size (every other pixel, K halved), so that it needs aligning to colour,
    as a D400's depth does; otherwise depth is registered to colour already. Frame i is stamped
    1 s + i / 30 s. Played back, the recording may lack a frame or two, more on a loaded machine
    (librealsense's recorder misses them)."""
    import time

    import pyrealsense2 as rs

    h, w = frames[0].depth.shape
    step = 2 if depth_half else 1
    K_depth = K_integer.astype(np.float64).copy()
    K_depth[:2] /= step  # pixel (u, v) of the half image is pixel (2u, 2v) of the full one
    dev = rs.software_device()
    sensors = {"depth": dev.add_sensor("Depth"), "color": dev.add_sensor("Color")}
    profiles = {}
    streams = [
        ("depth", rs.stream.depth, rs.format.z16, 2, _rs_intrinsics(rs, K_depth, w // step, h // step)),
        ("color", rs.stream.color, rs.format.rgb8, 3, _rs_intrinsics(rs, K_integer, w, h)),
    ]
    for uid, (name, stream, fmt, bpp, intr) in enumerate(streams):
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid, vs.fps, vs.bpp, vs.fmt = stream, 0, uid, 30, bpp, fmt
        vs.width, vs.height, vs.intrinsics = intr.width, intr.height, intr
        profiles[name] = sensors[name].add_video_stream(vs)
    sensors["depth"].add_read_only_option(rs.option.depth_units, depth_units)
    same_place = rs.extrinsics()
    same_place.rotation = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    same_place.translation = [0.0, 0.0, 0.0]
    profiles["depth"].register_extrinsics_to(profiles["color"], same_place)
    recorder = rs.recorder(str(path), dev)
    for name in sensors:
        sensors[name].open(profiles[name])
        sensors[name].start(lambda f: None)
    time.sleep(1.0)  # the recorder starts on its own thread; frames sent before it runs are lost
    for i, f in enumerate(frames):
        raw = np.ascontiguousarray(np.round(f.depth[::step, ::step] / depth_units).astype(np.uint16))
        for name, arr, bpp in (("depth", raw, 2), ("color", np.ascontiguousarray(f.rgb), 3)):
            vf = rs.software_video_frame()
            vf.pixels, vf.stride, vf.bpp = arr, arr.shape[1] * bpp, bpp
            vf.timestamp, vf.domain, vf.frame_number = (
                1000.0 + i * 1000.0 / 30,
                rs.timestamp_domain.hardware_clock,
                i + 1,
            )
            vf.profile = profiles[name].as_video_stream_profile()
            if name == "depth":
                vf.depth_units = depth_units
            sensors[name].on_video_frame(vf)
        time.sleep(0.1)  # the recorder writes on its own thread
    for s in sensors.values():
        s.stop()
        s.close()
    del recorder  # closes the file
    return path
