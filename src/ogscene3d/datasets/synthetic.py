"""Synthetic indoor scenes with ground truth: the generator and the reader.

:func:`make_synthetic_scene` builds a procedural furnished room (:mod:`.procedural`), ray casts it
with Warp (``kernels/raycast.py``) along a smooth exploring trajectory and writes it to disk. It is
the built-in default scene (no dataset can be downloaded in every setting) and it comes with exact
ground truth for evaluation.

World frame: metres, **up is -y** (``gt/instances.json``'s ``up``, which ``graph.up_axis: auto`` takes),
floor at y = 0, the room centred on x = z = 0. Poses are camera-to-world 4x4 with OpenCV camera axes, as
everywhere in ogscene3d.

Layout of a scene folder (the Replica NICE-SLAM layout plus ``gt/`` and ``segments/``)::

    cam_params.json            {"camera": {"w", "h", "fx", "fy", "cx", "cy", "scale": 6553.5}}
    traj.txt                   one row-major 4x4 c2w per line (with pose noise if it was asked for)
    results/frame%06d.jpg      RGB (JPEG quality 95)
    results/depth%06d.png      uint16, metres = value / 6553.5, 0 = invalid (with depth noise if asked)
    segments/frame%06d.png     simulated SAM segments fused with a simulated detector's named masks
                               (segmentation/simulated_detector.py), precomputed format (uint16 ids, 0 = none)
    segments/frame%06d.json    {"scores": {"<id>": float}, "names": {"<id>": detector class}}
    gt/instance%06d.png        uint16 ground-truth instance id per pixel (0 = no surface)
    gt/traj.txt                the true poses (equal to traj.txt without pose noise)
    gt/instances.json          see below
    gt/points.ply              labelled point cloud sampled on the surfaces (see below)
    gt/mesh.ply                the scene mesh (see below)
    gt/first_views.json        long scans only: the first-view merge plan (datasets/long_scan.py)
    scene.json                 generator parameters; written last, so it marks a complete scene

``gt/instances.json``::

    {"version": 1,
     "up": [0, -1, 0],
     "classes": {"<class id>": "<class name>", ...},          # class ids from 1; 0 = no surface
     "instances": {"<instance id>": {
         "class": "table", "class_id": 5, "structural": false,   # floor / ceiling / wall are structural
         "color": [r, g, b],                                     # albedo, 0-255
         "bbox_min": [x, y, z], "bbox_max": [x, y, z], "center": [x, y, z],   # world, metres
         "num_points": 1234,                                     # its points in gt/points.ply
         "support": 1 | null, "support_relation": "on" | "in" | "attached to" | null,
         "room": 2}},                                            # apartments only: the instance's room
     "rooms": {"<room id>": {"type": "kitchen", "floor": 0,     # apartments only (layout "apartment")
         "bbox_min": [x, y, z], "bbox_max": [x, y, z],           # the interior, world, metres
         "first_frame": 57 | null}},                             # the first frame whose camera is inside
     "relations": [[subject_id, "on", object_id], ...],
     "relation_vocabulary": ["on", "under", "above", "below", "next to", "in", "attached to"],
     "inverse_relations": {"on": "under", "under": "on", "above": "below", "below": "above"},
     "symmetric_relations": ["next to"]}

Relations are stored once per pair: "A on B" (A rests on B's top), "A in B" (a book on a shelf
board), "A attached to B" (wall decorations, the ceiling lamp), "A above B" (the ceiling lamp over
the table, pictures over furniture). "under"/"below" never appear; they are the inverses of
"on"/"above" ("B under A" == "A on B"). "next to" is symmetric (stored with the smaller id first).

``gt/points.ply`` (binary little-endian) vertex properties: ``x y z`` float32 (world, metres),
``red green blue`` uint8 (albedo), ``instance`` int32, ``class`` int32 (class id as above),
``observed`` uint8 (1 when some frame of the sequence sees the point: it projects into the image onto a
pixel of its own instance whose ray-cast depth agrees within ``OBSERVED_TOLERANCE`` plus two pixel
footprints). The evaluation leaves unobserved points out by default, as a scanned GT mesh does: a
ceiling no frame looks at cannot be mapped by any method, and counting it only adds noise.
Points are sampled uniformly on the surfaces (``POINTS_PER_M2`` per square metre, at least
``MIN_POINTS_PER_INSTANCE`` per instance). ``gt/mesh.ply``: vertices ``x y z red green blue`` and
faces ``vertex_indices`` plus ``instance`` / ``class`` int32 per face.

The segments in ``segments/`` are picked up automatically by :func:`open_dataset` when
``segments_dir`` is None. Everything is seeded: the same arguments give the same files.
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..atomic import atomic_write_bytes, atomic_write_text
from ..config import DataConfig, SyntheticConfig
from ..errors import DataError
from ..progress import progress as progress_bar
from ..segmentation.precomputed import write_segments
from ..segmentation.simulated import NOISE_LEVELS, SimulatedSegmenter
from ..segmentation.simulated_detector import SIMULATED_DETECTOR_VERSION, SimulatedDetector
from .apartment import Apartment, apartment_camera, build_apartment, rooms_entered
from .base import FrameRecord, read_label_png
from .long_scan import (
    build_scan_room,
    merge_partners,
    merges_by_frame,
    plan_first_view_merges,
    scan_trajectory,
)
from .procedural import (
    INVERSE_RELATIONS,
    RELATION_VOCABULARY,
    STRUCTURAL_CLASSES,
    WORLD_FROM_ZUP,
    Room,
    build_room,
)
from .replica import ReplicaDataset

log = logging.getLogger(__name__)

REPLICA_DEPTH_SCALE = 6553.5
POINTS_PER_M2 = 1000.0
MIN_POINTS_PER_INSTANCE = 300
OBSERVED_TOLERANCE = 0.02  # metres, plus two pixel footprints (see ``observed_in_frame``)
HFOV_DEG = 75.0
SWEEP = 1.6 * np.pi  # radians the camera walks around the room (given enough frames, see _sweep)
# the largest step between consecutive frames: well inside the mapper's default pose-jump limits
# (mapping.max_pose_step 0.5 m, max_pose_step_deg 30), leaving room for the pitch and height wobble
MAX_STEP_DEG = 20.0
MAX_STEP_M = 0.35
GENERATOR_VERSION = 2  # 2: gt/points.ply carries the per-point "observed" flag
LAYOUTS = ("room", "scan", "apartment")  # synthetic.layout: what make_synthetic_scene builds


# --------------------------------------------------------------------------------------- trajectory


def intrinsics_for(width: int, height: int, hfov_deg: float = HFOV_DEG) -> np.ndarray:
    """Pinhole K with square pixels, the principal point at the image centre (pixel centres at +0.5)."""
    fx = 0.5 * width / np.tan(np.deg2rad(hfov_deg) / 2.0)
    return np.array([[fx, 0.0, width / 2.0], [0.0, fx, height / 2.0], [0.0, 0.0, 1.0]], dtype=np.float32)


def _look_rotation_zup(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """Camera-to-world rotations [N, 3, 3] (OpenCV camera axes) in the z-up frame."""
    f = np.stack([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)], -1)
    r = np.cross(f, np.array([0.0, 0.0, 1.0]))
    r /= np.linalg.norm(r, axis=-1, keepdims=True)
    down = np.cross(f, r)
    return np.stack([r, down, f], axis=-1)


def exploration_trajectory(room: Room, frames: int, seed: int) -> np.ndarray:
    """[frames, 4, 4] c2w poses (world frame) along an ellipse inside the room, looking across it.

    The camera walks ~290 degrees around the room (less for few frames, see ``_sweep``) at about 1.45 m
    height, looking at the opposite side with a slight lead in the walking direction and ~20 degrees down,
    so the walls and the furniture come into view one after the other.
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7EA]))
    W, D, _ = room.size
    theta0 = rng.uniform(0.0, 2.0 * np.pi)
    direction = 1.0 if rng.uniform() < 0.5 else -1.0
    height = rng.uniform(1.35, 1.55)
    s = np.linspace(0.0, 1.0, frames) if frames > 1 else np.zeros(1)
    boxes = [p.aabb for o in room.zup_objects if o.class_name not in STRUCTURAL_CLASSES for p in o.parts]
    for shrink in (1.0, 0.85, 0.7, 0.55, 0.4):
        ax, ay = max(W / 2 - 1.05, 0.3) * shrink, max(D / 2 - 1.05, 0.3) * shrink
        theta = theta0 + direction * _sweep(frames, max(ax, ay)) * s
        pos = np.stack([ax * np.cos(theta), ay * np.sin(theta), height + 0.08 * np.sin(3.0 * np.pi * s)], -1)
        clear = all(
            not np.any(np.all((pos > lo - 0.3) & (pos < hi + 0.3), axis=1)) for lo, hi in boxes
        )  # keep 0.3 m from every object
        if clear:
            break
    else:
        log.warning("synthetic trajectory (seed %d) passes within 0.3 m of an object", seed)
    yaw = theta + np.pi - direction * 0.45
    pitch = -0.35 + 0.08 * np.sin(4.0 * np.pi * s)
    R = _look_rotation_zup(yaw, pitch)
    poses = np.tile(np.eye(4), (len(s), 1, 1))
    poses[:, :3, :3] = WORLD_FROM_ZUP @ R
    poses[:, :3, 3] = pos @ WORLD_FROM_ZUP.T
    return poses


def apartment_trajectory(apt: Apartment, frames_per_room: int, seed: int) -> np.ndarray:
    """[frames_per_room x rooms, 4, 4] c2w poses (world frame) of :func:`~.apartment.apartment_camera`: from
    room to room, turning once around in each, steps within :data:`MAX_STEP_M` and :data:`MAX_STEP_DEG`."""
    xyz, yaw, pitch = apartment_camera(apt, frames_per_room, seed, MAX_STEP_M, MAX_STEP_DEG)
    poses = np.tile(np.eye(4), (len(xyz), 1, 1))
    poses[:, :3, :3] = WORLD_FROM_ZUP @ _look_rotation_zup(yaw, pitch)
    poses[:, :3, 3] = xyz @ WORLD_FROM_ZUP.T
    return poses


def _sweep(frames: int, radius: float) -> float:
    """The angle (radians) the camera walks around the room: :data:`SWEEP`, or less where ``frames`` are too
    few for it, so that no step between consecutive frames exceeds :data:`MAX_STEP_DEG` of turn or
    :data:`MAX_STEP_M` along an ellipse of largest semi-axis ``radius`` (the mapper's pose-jump check would
    otherwise flag the generator's own sequence)."""
    if frames < 2:
        return SWEEP
    step = min(np.deg2rad(MAX_STEP_DEG), 2.0 * np.arcsin(min(1.0, MAX_STEP_M / (2.0 * radius))))
    return float(min(SWEEP, (frames - 1) * step))


def perturb_poses(poses: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """I.i.d. pose noise: translation N(0, sigma) metres and a rotation of N(0, sigma / 2) radians."""
    if sigma <= 0:
        return poses.copy()
    out = poses.copy()
    out[:, :3, 3] += rng.normal(0.0, sigma, (len(poses), 3))
    axis = rng.normal(size=(len(poses), 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.normal(0.0, sigma / 2.0, len(poses))
    for i in range(len(poses)):  # a handful of 3x3 Rodrigues rotations, one per frame
        Rn, _ = cv2.Rodrigues(axis[i] * angle[i])
        out[i, :3, :3] = Rn @ poses[i, :3, :3]
    return out


# --------------------------------------------------------------------------------------- rendering


class MeshRenderer:
    """Ray casts a :class:`Room` with Warp: RGB (uint8), depth (float32 m) and instance (int32) images."""

    def __init__(
        self,
        room: Room,
        device: str | None = "cpu",
        supersample: int = 2,
        shadows: bool = True,
        light_range: float = 4.0,
    ):
        # Warp and torch only where a scene is rendered: open_dataset imports this module to read scenes
        import warp as wp

        from ..device import resolve_device, warp_device
        from ..kernels import raycast

        self._wp = wp
        self._kernel = raycast.raycast_rgbd
        self.torch_device = resolve_device(device)
        self.device = warp_device(self.torch_device)
        self.supersample = int(supersample)
        self.shadows = shadows
        self.light_range = float(light_range)  # metres at which the light's falloff halves its diffuse term
        self.room = room
        self.mesh = wp.Mesh(
            points=wp.array(room.vertices, dtype=wp.vec3, device=self.device),
            indices=wp.array(room.triangles.reshape(-1), dtype=wp.int32, device=self.device),
        )
        self.tri_color = wp.array(room.tri_color, dtype=wp.vec3, device=self.device)
        self.tri_texture = wp.array(room.tri_texture, dtype=wp.int32, device=self.device)
        self.tri_texture_scale = wp.array(room.tri_texture_scale, dtype=float, device=self.device)
        self.tri_instance = wp.array(room.tri_instance, dtype=wp.int32, device=self.device)
        self.light = wp.vec3(*[float(v) for v in room.light])

    def _cast(self, pose: np.ndarray, K: np.ndarray, width: int, height: int, sub: int):
        wp = self._wp
        h, w = height * sub, width * sub
        rgb = wp.empty((h, w), dtype=wp.vec3, device=self.device)
        depth = wp.empty((h, w), dtype=float, device=self.device)
        inst = wp.empty((h, w), dtype=wp.int32, device=self.device)
        R = pose[:3, :3].astype(np.float32)
        wp.launch(
            self._kernel,
            dim=(h, w),
            inputs=[
                self.mesh.id,
                wp.mat33(*R.reshape(-1).tolist()),
                wp.vec3(*[float(v) for v in pose[:3, 3]]),
                float(K[0, 0]),
                float(K[1, 1]),
                float(K[0, 2]),
                float(K[1, 2]),
                sub,
                100.0,
                self.tri_color,
                self.tri_texture,
                self.tri_texture_scale,
                self.tri_instance,
                self.light,
                self.light_range,
                0.35,
                int(self.shadows),
            ],
            outputs=[rgb, depth, inst],
            device=self.device,
        )
        return rgb.numpy(), depth.numpy(), inst.numpy()

    def instances(self, pose: np.ndarray, K: np.ndarray, width: int, height: int) -> np.ndarray:
        """The instance map int32 [H, W] of a c2w pose (one ray per pixel centre, as in :meth:`render`)."""
        return self._cast(pose, K, width, height, 1)[2].astype(np.int32)

    def render(self, pose: np.ndarray, K: np.ndarray, width: int, height: int) -> tuple[np.ndarray, ...]:
        """(rgb uint8 [H, W, 3], depth float32 [H, W] metres, instance int32 [H, W]) for a c2w pose.

        Depth and instances are sampled at pixel centres; RGB is the mean of ``supersample``^2
        sub-pixel rays (anti-aliased edges, like a real camera's).
        """
        rgb, depth, inst = self._cast(pose, K, width, height, 1)
        if self.supersample > 1:
            s = self.supersample
            hi, _, _ = self._cast(pose, K, width, height, s)
            rgb = hi.reshape(height, s, width, s, 3).mean(axis=(1, 3))
        rgb8 = np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)
        return rgb8, depth.astype(np.float32), inst.astype(np.int32)


# --------------------------------------------------------------------------------------- ground truth


def class_table(room: Room) -> dict[str, int]:
    """Class name -> class id (from 1, in order of first appearance by instance id)."""
    out: dict[str, int] = {}
    for obj in room.objects:
        out.setdefault(obj.class_name, len(out) + 1)
    return out


def sample_surface_points(room: Room, seed: int, density: float = POINTS_PER_M2) -> dict[str, np.ndarray]:
    """Area-uniform points on every instance's surface: xyz float32 [N, 3], rgb uint8, instance int32."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x9017]))
    v = room.vertices.astype(np.float64)
    tri = v[room.triangles]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    xyz, rgb, inst = [], [], []
    for obj in room.objects:
        faces = np.nonzero(room.tri_instance == obj.instance_id)[0]
        a = area[faces]
        n = max(MIN_POINTS_PER_INSTANCE, int(round(a.sum() * density)))
        pick = faces[rng.choice(len(faces), size=n, p=a / a.sum())]
        r1 = np.sqrt(rng.uniform(size=(n, 1)))
        r2 = rng.uniform(size=(n, 1))
        t = tri[pick]
        pts = (1 - r1) * t[:, 0] + r1 * (1 - r2) * t[:, 1] + r1 * r2 * t[:, 2]
        xyz.append(pts.astype(np.float32))
        rgb.append(np.clip(room.tri_color[pick] * 255.0, 0, 255).astype(np.uint8))
        inst.append(np.full(n, obj.instance_id, dtype=np.int32))
    return {"xyz": np.concatenate(xyz), "rgb": np.concatenate(rgb), "instance": np.concatenate(inst)}


def _write_ply(path: Path, elements: list) -> None:
    from plyfile import PlyData

    data = PlyData(elements, text=False, byte_order="<")
    with io.BytesIO() as buf:
        data.write(buf)
        atomic_write_bytes(path, buf.getvalue())


def observed_in_frame(
    xyz: np.ndarray,
    instance: np.ndarray,
    pose: np.ndarray,
    K: np.ndarray,
    depth: np.ndarray,
    inst: np.ndarray,
) -> np.ndarray:
    """Bool [M]: the points ``xyz`` (world) that the frame (c2w ``pose``, clean ray-cast ``depth`` and
    instance map ``inst``) sees: in the image, on a pixel of their own instance, at the pixel's depth."""
    h, w = depth.shape
    w2c = np.linalg.inv(pose)
    p = xyz @ w2c[:3, :3].T + w2c[:3, 3]
    z = p[:, 2]
    front = z > 1e-6
    zs = np.where(front, z, 1.0)
    u = np.floor(K[0, 0] * p[:, 0] / zs + K[0, 2]).astype(np.int64)
    v = np.floor(K[1, 1] * p[:, 1] / zs + K[1, 2]).astype(np.int64)
    ok = front & (u >= 0) & (v >= 0) & (u < w) & (v < h)
    seen = np.zeros(len(xyz), dtype=bool)
    uu, vv, zz = u[ok], v[ok], z[ok]
    # a pixel spans z / f metres: surfaces seen at a grazing angle differ by about that much in depth
    tol = OBSERVED_TOLERANCE + 2.0 * zz / K[0, 0]
    seen[ok] = (inst[vv, uu] == instance[ok]) & (np.abs(depth[vv, uu] - zz) < tol)
    return seen


def write_points_ply(
    path: Path, pts: dict[str, np.ndarray], classes_of: np.ndarray, observed: np.ndarray | None = None
) -> None:
    from plyfile import PlyElement

    n = len(pts["xyz"])
    arr = np.empty(
        n,
        dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
               ("instance", "<i4"), ("class", "<i4"), ("observed", "u1")],
    )  # fmt: skip
    arr["x"], arr["y"], arr["z"] = pts["xyz"].T
    arr["red"], arr["green"], arr["blue"] = pts["rgb"].T
    arr["instance"] = pts["instance"]
    arr["class"] = classes_of[pts["instance"]]
    arr["observed"] = 1 if observed is None else observed.astype(np.uint8)
    _write_ply(path, [PlyElement.describe(arr, "vertex")])


def write_mesh_ply(path: Path, room: Room, classes_of: np.ndarray) -> None:
    from plyfile import PlyElement

    nv = len(room.vertices)
    vcol = np.zeros((nv, 3), dtype=np.float32)
    vcol[room.triangles.reshape(-1)] = np.repeat(room.tri_color, 3, axis=0)
    verts = np.empty(
        nv, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    )
    verts["x"], verts["y"], verts["z"] = room.vertices.T
    c8 = np.clip(vcol * 255.0, 0, 255).astype(np.uint8)
    verts["red"], verts["green"], verts["blue"] = c8.T
    nf = len(room.triangles)
    faces = np.empty(nf, dtype=[("vertex_indices", "i4", (3,)), ("instance", "<i4"), ("class", "<i4")])
    faces["vertex_indices"] = room.triangles
    faces["instance"] = room.tri_instance
    faces["class"] = classes_of[room.tri_instance]
    _write_ply(path, [PlyElement.describe(verts, "vertex"), PlyElement.describe(faces, "face")])


def instances_json(room: Room, classes: dict[str, int], num_points: np.ndarray) -> dict:
    inst = {}
    for obj in room.objects:
        lo = np.min([p.vertices.min(0) for p in obj.parts], axis=0)
        hi = np.max([p.vertices.max(0) for p in obj.parts], axis=0)
        tri = room.tri_instance == obj.instance_id
        color = np.clip(room.tri_color[tri].mean(0) * 255.0, 0, 255)
        inst[str(obj.instance_id)] = {
            "class": obj.class_name,
            "class_id": classes[obj.class_name],
            "structural": obj.class_name in STRUCTURAL_CLASSES,
            "color": [int(round(c)) for c in color],
            "bbox_min": [round(float(x), 5) for x in lo],
            "bbox_max": [round(float(x), 5) for x in hi],
            "center": [round(float(x), 5) for x in (lo + hi) / 2],
            "num_points": int(num_points[obj.instance_id]),
            "support": obj.support,
            "support_relation": obj.support_relation,
        }
    return {
        "version": 1,
        "up": [0.0, -1.0, 0.0],
        "classes": {str(v): k for k, v in classes.items()},
        "instances": inst,
        "relations": [[int(s), r, int(o)] for s, r, o in room.relations],
        "relation_vocabulary": list(RELATION_VOCABULARY),
        "inverse_relations": INVERSE_RELATIONS,
        "symmetric_relations": ["next to"],
    }


def add_rooms(doc: dict, apt: Apartment, entered: dict[int, int]) -> None:
    """Add an apartment's rooms to an ``instances.json`` document: ``"room"`` per instance and the
    ``"rooms"`` table (type, storey, interior box in the world, the first frame inside it)."""
    for key, inst in doc["instances"].items():
        inst["room"] = apt.instance_room[int(key)]
    doc["rooms"] = {
        str(r.id): {
            "type": r.type,
            "floor": r.floor,
            "bbox_min": [round(float(v), 5) for v in r.bbox_min],
            "bbox_max": [round(float(v), 5) for v in r.bbox_max],
            "first_frame": entered.get(r.id),
        }
        for r in apt.rooms
    }


def load_instances(path: str | Path) -> dict:
    """Read and check ``gt/instances.json``; instance ids become ints: {"instances": {id: {...}}, ...}."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: ground-truth instances file is missing")
    try:
        data = json.loads(path.read_text())
        data["instances"] = {int(k): v for k, v in data["instances"].items()}
        data["classes"] = {int(k): v for k, v in data["classes"].items()}
        for k, v in data["instances"].items():
            if not isinstance(v["class"], str) or int(v["class_id"]) not in data["classes"]:
                raise ValueError(f"instance {k} has a bad class")
        data["relations"] = [(int(s), str(r), int(o)) for s, r, o in data["relations"]]
        data["rooms"] = {int(k): v for k, v in data.get("rooms", {}).items()}
        for k, v in data["instances"].items():
            if v.get("room") is not None and int(v["room"]) not in data["rooms"]:
                raise ValueError(f"instance {k} is in room {v['room']}, which is not in 'rooms'")
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as e:
        raise DataError(f"{path}: malformed ground-truth instances ({e})") from e
    return data


# --------------------------------------------------------------------------------------- writer


def _encode(path: Path, img: np.ndarray, params: list[int] | None = None) -> None:
    ok, buf = cv2.imencode(path.suffix, img, params or [])
    if not ok:
        raise DataError(f"{path}: could not encode image")
    atomic_write_bytes(path, buf.tobytes())


def _pose_lines(poses: np.ndarray) -> str:
    return "".join(" ".join(f"{v:.9e}" for v in p.reshape(-1)) + "\n" for p in poses)


def scene_params(
    seed: int,
    frames: int,
    width: int,
    height: int,
    noise: str,
    depth_noise: float,
    pose_noise: float,
    layout: str = "room",
) -> dict[str, Any]:
    """The generator parameters a scene made with these arguments of :func:`make_synthetic_scene` records in
    its ``scene.json``: two scenes with the same ones are the same scene (see :func:`holds_scene`)."""
    # the default layout is left out, so that scenes written before layouts existed are still reused
    extra = {} if layout == "room" else {"layout": str(layout)}
    return {
        "detector": SIMULATED_DETECTOR_VERSION,  # named segments: a scene made without them is made again
        "generator": "ogscene3d.synthetic",
        "version": GENERATOR_VERSION,
        "seed": int(seed),
        "frames": int(frames),
        "width": int(width),
        "height": int(height),
        "noise": str(noise),
        "depth_noise": float(depth_noise),
        "pose_noise": float(pose_noise),
        **extra,
    }


def make_synthetic_scene(
    out_dir: str | Path,
    seed: int = 0,
    frames: int = 60,
    width: int = 160,
    height: int = 120,
    noise: str = "default",
    depth_noise: float = 0.0,
    pose_noise: float = 0.0,
    *,
    layout: str = "room",
    overwrite: bool = False,
    device: str | None = "cpu",
    progress: Callable[[Iterator], Iterator] | bool = False,
    remedy: str = "choose another folder or pass overwrite=True",
) -> Path:
    """Generate (or reuse) a synthetic scene in ``out_dir`` and return its path.

    If ``out_dir`` already holds a complete scene made with the same arguments it is reused as is; a folder
    holding anything else is an error unless ``overwrite``.

    Args:
        out_dir: the scene folder (Replica layout, with ``gt/`` and ``segments/``).
        seed: seed of the procedural room (or apartment) and of every noise.
        frames: frames of the camera path (``layout="apartment"``: per room).
        width: image width in pixels (at least 8).
        height: image height in pixels (at least 8).
        noise: simulated-SAM noise level (none | low | default | high | legacy-*).
        depth_noise: std of additive Gaussian depth noise in metres.
        pose_noise: std of the translation noise of the poses written to traj.txt in metres (rotation noise:
            half that in radians; gt/traj.txt keeps the true poses).
        overwrite: replace what ``out_dir`` holds.
        device: Warp device of the ray caster.
        progress: True for a tqdm bar, or a wrapper ``iterable -> iterable``.
        remedy: what the error for a folder holding something else tells the user to do (a command names
            its own options).
        layout: "room" (one furnished room, :func:`~.procedural.build_room`, a smooth walk around it),
            "scan" (a long scan like a real ScanNet one, :mod:`.long_scan`; its first-view merge plan in
            ``gt/first_views.json``) or "apartment" (2-5 rooms joined by doorways,
            :func:`~.apartment.build_apartment`; ``gt/instances.json`` gives every instance's room).

    Returns:
        ``out_dir`` as a path.

    Raises:
        ValueError: an argument out of its range.
        DataError: ``out_dir`` holds something else and ``overwrite`` is false.
    """
    _check_scene_args(frames, layout, width, height, noise, depth_noise, pose_noise)
    out = Path(out_dir)
    params = scene_params(seed, frames, width, height, noise, depth_noise, pose_noise, layout)
    if _reuse_or_clear(out, params, overwrite, remedy):
        log.info("reusing synthetic scene %s", out)
        return out
    K = intrinsics_for(width, height)
    room, poses, renderer = _scene_and_path(layout, seed, frames, device)
    merges = _first_view_merges(out, layout, renderer, room, poses, K, (width, height), noise, seed)
    noise_rng = np.random.default_rng(np.random.SeedSequence([seed, 0xD0152]))
    written_poses = perturb_poses(poses, pose_noise, noise_rng)
    cam = {"camera": {"w": width, "h": height, "fx": float(K[0, 0]), "fy": float(K[1, 1]),
                      "cx": float(K[0, 2]), "cy": float(K[1, 2]), "scale": REPLICA_DEPTH_SCALE}}  # fmt: skip
    atomic_write_text(out / "cam_params.json", json.dumps(cam, indent=2))
    atomic_write_text(out / "traj.txt", _pose_lines(written_poses))
    atomic_write_text(out / "gt" / "traj.txt", _pose_lines(poses))
    classes = class_table(room)
    classes_of = np.zeros(len(room.objects) + 1, dtype=np.int32)
    for obj in room.objects:
        classes_of[obj.instance_id] = classes[obj.class_name]
    pts = sample_surface_points(room, seed)
    noises = (noise, seed, depth_noise, noise_rng)
    observed = _write_frames(out, room, renderer, poses, K, (width, height), pts, noises, merges, progress)
    write_points_ply(out / "gt" / "points.ply", pts, classes_of, observed)
    write_mesh_ply(out / "gt" / "mesh.ply", room, classes_of)
    num_points = np.bincount(pts["instance"], minlength=len(room.objects) + 1)
    doc = instances_json(room, classes, num_points)
    if isinstance(room, Apartment):
        add_rooms(doc, room, rooms_entered(room, poses))
    atomic_write_text(out / "gt" / "instances.json", json.dumps(doc, indent=1))
    atomic_write_text(out / "scene.json", json.dumps(params, indent=2))
    return out


def _check_scene_args(frames, layout, width, height, noise, depth_noise, pose_noise) -> None:
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    if width < 8 or height < 8:
        raise ValueError(f"image size must be at least 8x8, got {width}x{height}")
    if noise not in NOISE_LEVELS:
        raise ValueError(f"noise must be one of {sorted(NOISE_LEVELS)}, got {noise!r}")
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {list(LAYOUTS)}, got {layout!r}")
    for name, val in (("depth_noise", depth_noise), ("pose_noise", pose_noise)):
        if not np.isfinite(val) or val < 0:
            raise ValueError(f"{name} must be a finite number >= 0, got {val}")


def holds_scene(out_dir: str | Path, params: dict[str, Any]) -> bool:
    """Whether ``out_dir`` holds a complete synthetic scene made with ``params`` (:func:`scene_params`): its
    ``scene.json``, written last, records them (an unreadable one: no)."""
    marker = Path(out_dir) / "scene.json"
    if not marker.is_file():
        return False
    try:
        return json.loads(marker.read_text()) == params
    except (OSError, json.JSONDecodeError):
        return False


def _reuse_or_clear(out: Path, params: dict, overwrite: bool, remedy: str) -> bool:
    """True when ``out`` holds a complete scene made with ``params`` (and no ``overwrite``); else ``out`` is
    made ready for a new scene (emptied of an earlier one with ``overwrite``; an error when it holds
    something else)."""
    marker = out / "scene.json"
    if not overwrite and holds_scene(out, params):
        return True
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise DataError(f"{out}: folder is not empty and holds no synthetic scene made with these arguments "
                        f"(an earlier one?); {remedy}")  # fmt: skip
    if overwrite:
        marker.unlink(missing_ok=True)
        for sub in ("results", "segments", "gt"):
            if (out / sub).is_dir():
                shutil.rmtree(out / sub)
    for sub in ("results", "segments", "gt"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    return False


def _scene_and_path(layout: str, seed: int, frames: int, device: str | None):
    """The procedural room or apartment, the camera path through it ([N, 4, 4]) and its renderer."""
    if layout == "apartment":
        room = build_apartment(seed)
        poses = apartment_trajectory(room, frames, seed)
        # one light for several rooms: no shadows (walls would leave the rooms beyond them dark) and a long
        # falloff (the rooms far from the middle stay lit)
        return room, poses, MeshRenderer(room, device=device, shadows=False, light_range=12.0)
    if layout == "scan":
        room = build_scan_room(seed)
        return room, scan_trajectory(room, frames, seed), MeshRenderer(room, device=device)
    room = build_room(seed)
    return room, exploration_trajectory(room, frames, seed), MeshRenderer(room, device=device)


def _first_view_merges(out: Path, layout: str, renderer, room, poses, K, size, noise: str, seed: int) -> dict:
    """A long scan's first-view merge plan, written to ``gt/first_views.json``, as {frame: {instance:
    partner}} for the simulated SAM ({} for other layouts and levels without first-view merges)."""
    level = NOISE_LEVELS[noise]
    if layout != "scan" or level.first_view_merge_prob <= 0:
        return {}
    plan = _first_view_plan(renderer, room, poses, K, *size, level, seed)
    atomic_write_text(out / "gt" / "first_views.json", json.dumps(_plan_json(plan), indent=1))
    return merges_by_frame(plan)


def _write_frames(
    out: Path,
    room,
    renderer: MeshRenderer,
    poses: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    pts: dict[str, np.ndarray],
    noises: tuple[str, int, float, np.random.Generator],
    merges: dict,
    progress: Callable[[Iterator], Iterator] | bool,
) -> np.ndarray:
    """Render every pose and write its colour, depth, instance map and simulated segments (``noises``:
    the SAM noise level, the seed, the depth noise and its generator; ``merges``: a long scan's first-view
    plan). -> which surface points some frame observed."""
    width, height = size
    noise, seed, depth_noise, noise_rng = noises
    frames = len(poses)
    # support relations let the simulated SAM merge an object with what it stands or hangs on
    segmenter = SimulatedSegmenter(noise, seed=seed, support={o.instance_id: o.support for o in room.objects},
                                   first_view_merges=merges)  # fmt: skip
    # the detector errs at the matching level (the legacy SAM levels change only how SAM errs)
    detector = SimulatedDetector({o.instance_id: o.class_name for o in room.objects},
                                 noise=noise.removeprefix("legacy-"), seed=seed,
                                 min_area=NOISE_LEVELS[noise].min_area)  # fmt: skip
    steps: Iterator = iter(range(frames))
    bars = contextlib.ExitStack()
    if progress is True:
        steps = iter(bars.enter_context(progress_bar(range(frames), desc="synth", total=frames)))
    elif callable(progress):
        steps = iter(progress(range(frames)))
    max_depth = 65535.0 / REPLICA_DEPTH_SCALE
    observed = np.zeros(len(pts["xyz"]), dtype=bool)
    with bars:  # the bar's log routing ends with the loop
        for i in steps:
            rgb, depth, inst = renderer.render(poses[i], K, width, height)
            todo = np.nonzero(~observed)[0]  # a point seen once is observed: only the others are tested
            xyz, owner = pts["xyz"][todo], pts["instance"][todo]
            observed[todo] = observed_in_frame(xyz, owner, poses[i], K, depth, inst)
            valid = depth > 0
            if depth_noise > 0:
                depth = depth + noise_rng.normal(0.0, depth_noise, depth.shape).astype(np.float32)
                depth[~valid] = 0.0
                depth = np.maximum(depth, 0.0)
            depth[depth > max_depth] = 0.0
            seg = segmenter(rgb, depth, gt_instances=inst, frame_index=i)
            stem = f"{i:06d}"
            _encode(
                out / "results" / f"frame{stem}.jpg",
                cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                [cv2.IMWRITE_JPEG_QUALITY, 95],
            )
            raw_depth = np.rint(depth * REPLICA_DEPTH_SCALE).astype(np.uint16)
            _encode(out / "results" / f"depth{stem}.png", raw_depth)
            _encode(out / "gt" / f"instance{stem}.png", inst.astype(np.uint16))
            seg = detector(seg, inst, frame_index=i)  # fused with named detector masks, as sam+detector does
            write_segments(out / "segments", f"frame{stem}", seg.ids, seg.scores, seg.names)
    return observed


def _first_view_plan(
    renderer: MeshRenderer, room: Room, poses, K, width, height, level, seed
) -> dict[int, dict]:
    """A long scan's first-view merge plan (:func:`.long_scan.plan_first_view_merges`): which objects the
    views that first show them merge with the floor or a neighbour. The instance maps come from one ray per
    pixel, as the written ones do."""
    areas = np.zeros((len(poses), len(room.objects) + 1), np.int64)
    for i, pose in enumerate(poses):
        inst = renderer.instances(pose, K, width, height)
        areas[i] = np.bincount(inst.reshape(-1), minlength=areas.shape[1])[: areas.shape[1]]
    return plan_first_view_merges(merge_partners(room), areas, level.first_view_merge_prob, seed)


def _plan_json(plan: dict[int, dict]) -> dict:
    return {"version": 1, "first_views": {str(k): v for k, v in sorted(plan.items())}}


def load_first_views(scene_dir: str | Path) -> dict[int, dict]:
    """A long scan's first-view merge plan ({instance: {"partner", "frames"}}; {} for a scene without one)."""
    path = Path(scene_dir) / "gt" / "first_views.json"
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text())
        return {int(k): {"partner": int(v["partner"]), "frames": [int(f) for f in v["frames"]]}
                for k, v in doc["first_views"].items()}  # fmt: skip
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as e:
        raise DataError(f"{path}: malformed first-view plan ({e})") from e


# --------------------------------------------------------------------------------------- reader


class SyntheticDataset(ReplicaDataset):
    """A synthetic scene: the Replica reader plus ground-truth instance/class maps per frame.

    When ``segments_dir`` is None, the scene's own ``segments/`` folder (simulated SAM) is used.
    """

    kind = "synthetic"

    @staticmethod
    def detect(root: Path) -> bool:
        return ReplicaDataset.detect(root) and (root / "gt" / "instances.json").is_file()

    def __init__(self, root: Path, config: DataConfig, segments_dir: Path | None = None) -> None:
        root = Path(root)
        if segments_dir is None and (root / "segments").is_dir():
            segments_dir = root / "segments"
        self.gt = load_instances(root / "gt" / "instances.json")
        self.up_axis = _scene_up(self.gt, root / "gt" / "instances.json")
        self.up_axis_source = "the synthetic scene's gt/instances.json"
        ids = self.gt["instances"]
        self._class_lut = np.zeros(max(ids, default=0) + 1, dtype=np.int32)
        for k, v in ids.items():
            self._class_lut[k] = int(v["class_id"])
        super().__init__(root, config, segments_dir)
        for rec in self.records:
            rec.extras["instance"] = root / "gt" / f"instance{rec.name[len('frame') :]}.png"

    @property
    def class_names(self) -> dict[int, str]:
        return dict(self.gt["classes"])

    @property
    def has_class_maps(self) -> bool:
        return True

    def _load_gt(
        self, rec: FrameRecord, shape: tuple[int, int]
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        path = rec.extras["instance"]
        inst = read_label_png(path, shape, "ground-truth instance")
        if inst.max(initial=0) >= len(self._class_lut):
            raise DataError(f"{path}: instance id {inst.max()} is not in gt/instances.json")
        return inst, self._class_lut[inst]


def _scene_up(gt: dict, path: Path) -> tuple[float, float, float]:
    """The world up a scene's ``instances.json`` states (the generator's, -y, in older scenes without it)."""
    up = gt.get("up", (0.0, -1.0, 0.0))
    try:
        x, y, z = (float(v) for v in up)
    except (TypeError, ValueError):
        raise DataError(f"{path}: 'up' must be a 3-vector, got {up!r}") from None
    if not np.isfinite([x, y, z]).all() or not np.linalg.norm([x, y, z]) > 0:
        raise DataError(f"{path}: 'up' must be a finite non-zero 3-vector, got {up!r}")
    return x, y, z


def configured_scene(out_dir: str | Path, s: SyntheticConfig, **kwargs: Any) -> Path:
    """:func:`make_synthetic_scene` with the settings of a config's ``synthetic`` section (keyword arguments
    as there: ``overwrite``, ``device``, ``progress``, ``remedy``)."""
    return make_synthetic_scene(
        out_dir,
        s.seed,
        s.frames,
        s.width,
        s.height,
        s.noise,
        s.depth_noise,
        s.pose_noise,
        layout=s.layout,
        **kwargs,
    )
