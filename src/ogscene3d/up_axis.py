"""The world's up direction (``graph.up_axis``): chosen for a dataset, or estimated from its cameras.

``graph.up_axis: auto`` (the default) takes, in order:

1. the dataset reader's convention, where the format defines one and the frames carry the format's own
   poses (ScanNet, Replica, Semantic-NeRF's Replica and TUM worlds are z-up; a ROS bag's tf world is z-up by
   REP 103; Record3D's ARKit world, turned to OpenCV axes, is -y up; a synthetic scene says its own in
   ``gt/instances.json``), unless the cameras' own up direction is more than :data:`AGREE_DEG` away from it
   (a folder in a format's layout whose poses are another world's);
2. else the cameras' up direction over the first frames (:class:`CameraUp`), from the dataset's poses when
   it is opened, or from the tracked poses at the mapper's first scene-graph update (a recording without
   poses, a live camera).

The choice is logged once. An explicit ``graph.up_axis`` vector wins; the mapper warns when the cameras
disagree with it (``mapping/graph_feed.py``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

AUTO = "auto"
#: the up direction used until an ``auto`` one is chosen: an upright OpenCV camera's (a world anchored at the
#: first camera, as odometry's is)
PROVISIONAL_UP = (0.0, -1.0, 0.0)
#: degrees between a chosen up direction and the cameras' beyond which the two disagree; room for cameras
#: pitched down at a table (the cameras' estimate is the mean of their up vectors when their x axes do not
#: span the horizontal plane)
AGREE_DEG = 75.0
#: an estimate this close to a world axis is taken as that axis (worlds are usually axis-aligned)
SNAP_DEG = 10.0
#: poses read from a dataset when it opens to estimate the cameras' up (the first frames of the selection)
OPEN_FRAMES = 100


def is_auto(value: Any) -> bool:
    """Whether ``value`` (a ``graph.up_axis`` setting) is ``"auto"``."""
    return isinstance(value, str) and value == AUTO


def up_vector(value: Any, default: Iterable[float] = PROVISIONAL_UP) -> tuple[float, float, float]:
    """``value`` (a ``graph.up_axis`` setting) as a tuple of 3 floats; ``default`` while it is ``auto``."""
    v = default if is_auto(value) else value
    x, y, z = (float(c) for c in v)
    return x, y, z


def unit_up(up: np.ndarray | Iterable[float]) -> np.ndarray:
    """An up vector (a ``graph.up_axis`` vector, a graph's ``up``) as a float64 unit 3-vector.

    Raises:
        ValueError: it is not a finite non-zero 3-vector.
    """
    u = np.asarray(up, dtype=np.float64).reshape(-1)
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) < 1e-9:
        raise ValueError(f"graph.up_axis must be a finite non-zero 3-vector, got {np.asarray(up).tolist()}")
    return u / np.linalg.norm(u)


def angle_deg(a: Iterable[float], b: Iterable[float]) -> float:
    """Degrees between two non-zero 3-vectors."""
    u, v = np.asarray(list(a), dtype=np.float64), np.asarray(list(b), dtype=np.float64)
    c = float(u @ v / (np.linalg.norm(u) * np.linalg.norm(v)))
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def axis_name(up: Iterable[float]) -> str:
    """``"z"``, ``"-y"``, ... for an axis-aligned vector; the rounded vector otherwise."""
    u = np.asarray(list(up), dtype=np.float64)
    k = int(np.argmax(np.abs(u)))
    if abs(u[k]) >= 0.999 * np.linalg.norm(u):
        return ("" if u[k] > 0 else "-") + "xyz"[k]
    return str(np.round(u / np.linalg.norm(u), 3).tolist())


def snap(up: np.ndarray, max_deg: float = SNAP_DEG) -> np.ndarray:
    """``up`` (unit) replaced by the nearest world axis when within ``max_deg`` of it."""
    k = int(np.argmax(np.abs(up)))
    axis = np.zeros(3)
    axis[k] = 1.0 if up[k] > 0 else -1.0
    return axis if angle_deg(up, axis) <= max_deg else up


class CameraUp:
    """The up direction of cameras, accumulated pose by pose (OpenCV camera-to-world: a camera's up is -y).

    A handheld or robot camera rolls little but pitches (down at a table, up at a shelf): its x axis stays
    nearly horizontal. So when the cameras' x axes span a plane (they turned about the vertical), up is that
    plane's normal, on the side the cameras' up vectors point to; when they do not (a camera that kept one
    heading), it is the mean of the up vectors. An estimate within :data:`SNAP_DEG` of a world axis is that
    axis."""

    def __init__(self) -> None:
        self.up_sum = np.zeros(3)
        self.x_scatter = np.zeros((3, 3))
        self.count = 0

    def add(self, pose: np.ndarray) -> None:
        """Count one camera (a 4x4 or 3x4 camera-to-world pose)."""
        R = np.asarray(pose, dtype=np.float64)[:3, :3]
        self.up_sum -= R[:, 1]
        self.x_scatter += np.outer(R[:, 0], R[:, 0])
        self.count += 1

    def estimate(self) -> np.ndarray | None:
        """The cameras' up direction (a unit float64 3-vector), or None before any camera was counted."""
        norm = float(np.linalg.norm(self.up_sum))
        if self.count == 0 or norm < 1e-9:
            return None
        mean_up = self.up_sum / norm
        w, V = np.linalg.eigh(self.x_scatter / self.count)  # ascending: V[:, 0] is the normal of the x axes
        # the x axes spread within a plane (w[1]) more than out of it (w[0]: roll); rendered cameras do not
        # roll at all, and then a turn of a degree tells the plane
        if w[1] > 1e-6 and w[0] <= 0.2 * w[1]:
            normal = V[:, 0] * (1.0 if V[:, 0] @ mean_up >= 0 else -1.0)
            if angle_deg(normal, mean_up) < 60.0:  # cameras pitched more than that are not upright ones
                return snap(normal)
        return snap(mean_up)


def layout_up(ds: Any) -> tuple[tuple[float, float, float], str] | None:
    """(up, what says so) of an opened dataset's format, or None where it defines none or its frames carry no
    poses (tracked poses start from the first camera's frame, whatever the format's world is)."""
    up = getattr(ds, "up_axis", None)
    records = getattr(ds, "records", None) or []
    if up is None or not any(r.pose is not None or r.pose_path is not None for r in records[:1]):
        return None
    return up_vector(up), str(getattr(ds, "up_axis_source", f"the {getattr(ds, 'kind', '?')} layout"))


def dataset_camera_up(ds: Any, frames: int = OPEN_FRAMES) -> tuple[np.ndarray | None, int]:
    """(the cameras' up, the poses counted) over the first ``frames`` frames of an opened dataset, from its
    poses alone (no pixels are read); frames without a readable pose are passed over."""
    cams = CameraUp()
    for i in range(min(frames, len(ds))):
        try:
            pose = ds.pose(i)
        except Exception:  # noqa: BLE001 - a bad pose is that frame's error, reported when it is read
            continue
        if pose is not None:
            cams.add(pose)
    return cams.estimate(), cams.count


def choose_up_axis(graph_config: Any, ds: Any) -> None:
    """Set ``graph_config.up_axis`` when it is ``auto`` and the dataset ``ds`` tells it (see the module doc),
    logging the choice once; left ``auto`` when only tracked cameras can tell (the mapper chooses then).

    Args:
        graph_config: a :class:`~ogscene3d.config.GraphConfig`, changed in place.
        ds: the opened dataset of the run.
    """
    if not is_auto(graph_config.up_axis):
        return
    convention = layout_up(ds)
    cam_up, count = dataset_camera_up(ds)
    if convention is not None:
        up, source = convention
        if cam_up is None or angle_deg(up, cam_up) <= AGREE_DEG:
            graph_config.up_axis = list(up)
            log.info("graph.up_axis auto: %s (%s)", axis_name(up), source)
            return
        log.info(
            "%s says the world is %s-up, but the cameras' up direction over the first %d frames is %.0f deg "
            "from it: their poses are another world's; graph.up_axis auto takes the cameras' (%s; set "
            "graph.up_axis to choose)",
            source, axis_name(up), count, angle_deg(up, cam_up), axis_name(cam_up),
        )  # fmt: skip
    if cam_up is not None:
        graph_config.up_axis = [float(v) for v in cam_up]
        what = f"the cameras' up direction over the first {count} frames"
        log.info("graph.up_axis auto: %s (%s)", axis_name(cam_up), what)
        return
    log.info("graph.up_axis auto: chosen from the tracked cameras at the first scene-graph update")
