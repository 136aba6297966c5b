"""One RGB-D frame as the mapper consumes it."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from .camera import Camera

# metres: RGB-D cameras see up to about 10 m, so a median outside this range means a wrong depth scale,
# unit or format (a room in km or mm, or a bit-shifted encoding read as linear)
PLAUSIBLE_MEDIAN_DEPTH = (0.05, 20.0)

log = logging.getLogger(__name__)


def implausible_median_depth(depth: np.ndarray) -> float | None:
    """The median of the valid (> 0) depths when it lies outside what an RGB-D camera sees, else None
    (also when no pixel has depth)."""
    valid = depth[depth > 0]
    if valid.size == 0:
        return None
    median = float(np.median(valid))
    return None if PLAUSIBLE_MEDIAN_DEPTH[0] <= median <= PLAUSIBLE_MEDIAN_DEPTH[1] else median


def warn_implausible_depth(frame: Frame) -> bool:
    """Warn when ``frame``'s median depth is implausible for an RGB-D camera (a dataset's frame is left
    alone: the dataset has warned already, naming the setting to fix). Returns whether the frame had depth
    to judge (False: ask again with the next frame)."""
    if not np.any(frame.depth > 0):
        return False
    median = None if frame.depth_scale_checked else implausible_median_depth(frame.depth)
    if median is not None:
        log.warning(
            "frame %d (%s): median depth %.3g m is implausible for an RGB-D camera; Frame.depth "
            "must be in metres (0 = invalid), or the map will be empty or wrong",
            frame.index,
            frame.name or "unnamed",
            median,
        )
    return True


def check_pose(pose: np.ndarray, what: str = "pose", tol: float = 1e-3) -> np.ndarray:
    """Return ``pose`` as float64 4x4 or raise ValueError if it is not a finite rigid transform."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"{what}: expected a 4x4 matrix, got shape {pose.shape}")
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"{what}: contains NaN or inf")
    R = pose[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > tol or abs(np.linalg.det(R) - 1.0) > tol:
        raise ValueError(f"{what}: rotation part is not orthonormal with det +1 (non-rigid pose)")
    if np.abs(pose[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > tol:
        raise ValueError(f"{what}: last row is not [0, 0, 0, 1]")
    return pose


@dataclass
class Frame:
    """One RGB-D frame, as datasets and camera streams give it to the mapper.

    Attributes:
        index: the frame's index in its sequence.
        rgb: colour image. uint8 [H, W, 3]
        depth: depth in metres, 0 = invalid. float32 [H, W]
        K: pinhole intrinsics, pixel centres at +0.5. float32 [3, 3]
        pose: camera-to-world (OpenCV axes), or None when it must be tracked. float64 [4, 4]
        timestamp: seconds, where the sequence records it.
        name: the colour file's stem; precomputed segments are looked up by it.
        segments: an int id map, 0 or negative = no segment; None: none given. [H, W]
        segment_scores: {segment id: SAM predicted IoU}.
        segment_names: {segment id: detector class}, where known.
        gt_instances: ground-truth instance map, where the dataset has one (synthetic scenes). [H, W]
        gt_classes: ground-truth class map (synthetic scenes; label-fusion's segm images and ScanNet's
            label-filt, in NYU40 ids). [H, W]
        depth_scale_checked: the frame's reader checked its sequence's depth scale and warned about an
            implausible one (datasets do, naming their ``data.depth_scale``), so the mapper does not warn
            again.
    """

    index: int
    rgb: np.ndarray  # uint8 [H, W, 3]
    depth: np.ndarray  # float32 [H, W], metres, 0 = invalid
    K: np.ndarray  # float32 [3, 3]
    pose: np.ndarray | None = None  # float64 [4, 4] c2w
    timestamp: float = 0.0
    name: str = ""  # the rgb file stem; precomputed segments are looked up by it
    segments: np.ndarray | None = None
    segment_scores: dict[int, float] = field(default_factory=dict)
    segment_names: dict[int, str] = field(default_factory=dict)  # detector class of a segment, where known
    gt_instances: np.ndarray | None = None
    gt_classes: np.ndarray | None = None
    depth_scale_checked: bool = False

    def __post_init__(self) -> None:
        if self.rgb.ndim != 3 or self.rgb.shape[2] != 3 or self.rgb.dtype != np.uint8:
            raise ValueError(
                f"frame {self.index}: rgb must be uint8 HxWx3, got {self.rgb.dtype} {self.rgb.shape}"
            )
        if self.depth.shape != self.rgb.shape[:2]:
            raise ValueError(
                f"frame {self.index}: depth shape {self.depth.shape} "
                f"differs from rgb shape {self.rgb.shape[:2]}"
            )
        if self.segments is not None and self.segments.shape != self.rgb.shape[:2]:
            raise ValueError(
                f"frame {self.index}: segments shape {self.segments.shape} "
                f"differs from rgb {self.rgb.shape[:2]}"
            )
        self.K = np.asarray(self.K, dtype=np.float32)
        if self.pose is not None:
            self.pose = check_pose(self.pose, f"frame {self.index} pose")

    @property
    def height(self) -> int:
        return int(self.rgb.shape[0])

    @property
    def width(self) -> int:
        return int(self.rgb.shape[1])

    @property
    def camera(self) -> Camera:
        return Camera.from_K(self.K, self.width, self.height)
