"""Camera tracking for RGB-D sequences without poses: Open3D's multi-scale RGB-D odometry, keyframe-to-frame.

The paper tracks with DROID-SLAM, whose weights are not available here. This module gives a tracker that
needs no learned weights: Open3D's tensor RGB-D odometry (``open3d.t.pipelines.odometry``) on a
coarse-to-fine image pyramid, on CPU or CUDA, with the point-to-plane (geometric), intensity (photometric)
or hybrid (both) objective.

Algorithm (``Tracker.step``):

* The first frame that has enough valid depth is the anchor: its pose is ``frame.pose`` when given, else the
  identity; it becomes the first keyframe. Poses given for later frames are ignored.
* Every later frame is aligned to the current *keyframe* (not to the previous frame), so the odometry
  error accumulates once per keyframe rather than once per frame.
* Objective (``method``): "auto" (default) uses point-to-plane when the keyframe's geometry constrains all
  six degrees of freedom (``geometric_conditioning`` >= ``min_conditioning``) and hybrid where it does not
  (a single wall, a corridor), or when point-to-plane finds no acceptable result. Point-to-plane is the
  default because it was the most accurate on every sample here (docs/results.md, "Odometry": the
  photometric term pulls a converged estimate off at these resolutions), while the texture term is what
  makes planar views trackable at all.
* Dense odometry starts from the motion prior (constant velocity). An objective can converge to a wrong
  local minimum that still has a high overlap, but then with a clearly larger residual; so unless the
  result looks like the recent good ones (overlap >= ``keyframe_fitness`` and residual <= 1.5x the median
  of the last accepted residuals) the odometry is also run from an ORB + RANSAC initial guess
  (``feature_init``: ORB features with depth matched to the keyframe's, a rigid 3-point RANSAC over their
  3D positions) and, if nothing passed yet, from the last good pose. Among the results that pass the checks
  below and have nearly the best overlap, the lowest residual wins. The feature guess is what keeps large
  inter-frame motions tracked (7-Scenes every 20th frame loses frames without it: docs/results.md,
  "Odometry").
* The frame becomes the new keyframe when its overlap with the keyframe (Open3D's fitness, the fraction of
  pixels with an inlier correspondence) drops below ``keyframe_fitness``, when it is further than
  ``keyframe_translation`` / ``keyframe_rotation_deg`` from the keyframe, or after ``keyframe_every`` frames.
* A step is rejected, and the frame skipped (``step`` returns None and logs a warning), when Open3D fails
  (e.g. a singular system), when the fitness is below ``min_fitness`` (too few correspondences, e.g. a frame
  far outside the keyframe's view), when the residual exceeds ``max_inlier_rmse``, when the result is not a
  finite rigid transform, or when the motion since the last good frame exceeds ``max_translation`` /
  ``max_rotation_deg`` per elapsed frame of the folder (``frame_step``: a run at ``data.stride`` n steps n
  folder frames per call; checked on the selected alignment: a better-aligned but
  implausible result is not swapped for a worse one that happens to move less), or, for the first frame
  after skipped ones, when its residual exceeds ``max_residual_ratio`` x the median of the last accepted
  residuals (a wrong re-acquisition). The keyframe is kept, so the next good frame re-anchors to it.
  With ``max_lost_frames > 0``, after that many consecutive failures tracking restarts: the next usable
  frame is re-anchored at the last good pose (a discontinuity in the trajectory, logged as a warning).
  There is no loop closure or relocalisation against older keyframes.

Every returned pose is a finite rigid c2w 4x4 float64 matrix in the OpenCV convention (checked with
``ogscene3d.frame.check_pose`` and re-orthonormalised), so mapping never receives a NaN or non-rigid pose.

Images wider than ``max_width`` are tracked at a resolution reduced by an integer factor (colour: block mean;
depth: block mean of valid pixels, or their minimum where the block straddles a depth edge) with the
intrinsics scaled to match; ORB features use the input resolution. ``K`` follows the project convention
(pixel centres at +0.5); it is shifted by half a pixel for Open3D, whose pixel centres are at integers.

Use by the mapper (``config.tracking.poses == "odometry"``)::

    from ogscene3d.tracking import Tracker

    tracker = Tracker(config.tracking, device=None, frame_step=config.data.stride)  # None: CUDA if Open3D can
    for frame in dataset:
        pose = tracker.step(frame)  # c2w float64 [4, 4], or None when the frame could not be tracked
        if pose is None:
            continue  # skip the frame: do not map it (tracker.last.reason says why)
        frame.pose = pose
        mapper.process(frame)

With ``poses == "gt"`` the mapper uses ``frame.pose`` from the dataset and never builds a Tracker. For a
whole sequence at once use ``track`` (poses only) or ``track_sequence`` (poses + validity + per-frame info).
A command that maps offers ``--poses`` (``ogscene3d.commands.options.add_poses_argument``) and then does
``if args.poses: cfg.tracking.poses = args.poses``. ``ogscene3d track --data DIR --out OUT`` writes
``OUT/traj.txt`` and ``OUT/tracking.json`` (per-frame status, ATE against the dataset's poses if any).

Accuracy on the sample sequences (ATE after SE(3) alignment, ``ogscene3d track``): docs/results.md,
"Odometry".
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence, Sized
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from .camera import Camera
from .config import TrackingConfig, check_section, choices
from .errors import OGSceneError
from .frame import Frame, check_pose
from .progress import progress as progress_bar

log = logging.getLogger(__name__)

_METHODS = {"hybrid": "Hybrid", "color": "Intensity", "point_to_plane": "PointToPlane"}
METHODS = choices("tracking.method")
POSE_SOURCES = choices("tracking.poses")
_FITNESS_TIE = 0.05  # candidates within this overlap of the best are ranked by residual
_RMSE_GATE = 1.5  # a prior-initialised result with a residual above this x the recent ones gets a second try
_RECENT = 5  # accepted residuals remembered for that gate and the re-acquisition check
_ORB_SMALL_WIDTH = 480  # ORB features of narrower images are detected at twice the resolution


@dataclass
class StepInfo:
    """What ``Tracker.step`` did with one frame.

    ``status`` is "anchor" (first frame or a restart), "tracked" or "skipped"; ``reason`` says why a frame
    was skipped or made a keyframe. ``fitness`` (fraction of pixels with an inlier correspondence) and
    ``inlier_rmse`` are Open3D's figures for the accepted (or last tried) alignment, NaN when none ran.
    ``reference`` is the frame index of the keyframe the frame was aligned to (-1 for an anchor);
    ``method`` the objective that produced the accepted pose ("point_to_plane", "hybrid" or "color").
    """

    index: int
    pose: np.ndarray | None
    status: str
    reason: str = ""
    fitness: float = math.nan
    inlier_rmse: float = math.nan
    keyframe: bool = False
    reference: int = -1
    method: str = ""  # the odometry objective of the accepted alignment


@dataclass
class TrackResult:
    """Result of ``track_sequence``.

    ``poses[i]`` is the c2w float64 [4, 4] pose of frame i. A skipped frame holds the last good pose
    before it (the anchor pose for frames skipped before the anchor) and has ``valid[i] == False``: it is a
    safe finite rigid pose, but not an estimate for that frame, so a mapper must not integrate it.
    """

    poses: list[np.ndarray]
    valid: np.ndarray  # bool [N]
    infos: list[StepInfo]


def validate_tracking_config(cfg: TrackingConfig) -> None:
    """Raise ConfigError naming the ``tracking.*`` key when a value breaks its rule (written on the field)."""
    check_section(cfg, "tracking")


def open3d_device(device: Any = "cpu") -> Any:
    """``"cpu"``, ``"cuda"``, ``"cuda:N"``, a torch.device or None (CUDA if Open3D has it) -> Open3D Device.

    Raises ValueError when CUDA is asked for but this Open3D build or machine has none.
    """
    import open3d as o3d

    if device is None:
        return o3d.core.Device("CUDA:0" if o3d.core.cuda.is_available() else "CPU:0")
    text = str(device).lower()
    kind, _, idx = text.partition(":")
    if kind == "cpu":
        return o3d.core.Device("CPU:0")
    if kind == "cuda":
        if not o3d.core.cuda.is_available():
            raise ValueError(f"device={device!r}: this Open3D build sees no CUDA device; use device='cpu'")
        return o3d.core.Device(f"CUDA:{int(idx) if idx else 0}")
    raise ValueError(f"device={device!r} is not supported: use 'cpu', 'cuda' or 'cuda:N'")


def _open3d_message(e: Exception) -> str:
    """The human part of an Open3D error: no ANSI colours, no C++ signature and source path."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", str(e)).strip()
    m = re.search(r"\.(?:cpp|h|cu):\d+:\s*(.*)", text, re.S)
    return (m.group(1) if m else text).strip()


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a 3x3 rotation in degrees (robust to round-off outside [-1, 1])."""
    c = (float(np.trace(R)) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _orthonormalize(pose: np.ndarray) -> np.ndarray:
    """Project the rotation block onto SO(3) so that composed poses do not drift away from rigidity."""
    U, _, Vt = np.linalg.svd(pose[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = pose[:3, 3]
    return out


def _best_candidate(
    passing: list[tuple[float, float, np.ndarray]],
) -> tuple[float, float, np.ndarray]:
    """Of the passing (fitness, rmse, pose) alignments, the lowest residual among those within
    ``_FITNESS_TIE`` of the best overlap, its pose re-orthonormalised."""
    top = max(c[0] for c in passing)
    fitness, rmse, pose = min((c for c in passing if c[0] >= top - _FITNESS_TIE), key=lambda c: c[1])
    return fitness, rmse, _orthonormalize(pose)


def _downsample_depth(depth: np.ndarray, f: int, edge: float) -> np.ndarray:
    """Block-reduce a depth map (0 = invalid) by ``f``: mean of valid pixels, min where they span > ``edge``.

    Averaging across a depth discontinuity would create points floating between foreground and background,
    so such blocks keep their nearest valid depth instead.
    """
    h, w = depth.shape[0] // f, depth.shape[1] // f
    blocks = depth[: h * f, : w * f].reshape(h, f, w, f).transpose(0, 2, 1, 3).reshape(h, w, f * f)
    valid = blocks > 0
    n = valid.sum(-1)
    mean = np.where(n > 0, np.where(valid, blocks, 0).sum(-1) / np.maximum(n, 1), 0.0)
    lo = np.where(valid, blocks, np.inf).min(-1)
    hi = np.where(valid, blocks, -np.inf).max(-1)
    out = np.where(hi - lo > edge, lo, mean)
    return np.where(n > 0, out, 0.0).astype(np.float32)


def _downsample_rgb(rgb: np.ndarray, f: int) -> np.ndarray:
    h, w = rgb.shape[0] // f, rgb.shape[1] // f
    blocks = rgb[: h * f, : w * f].reshape(h, f, w, f, 3).astype(np.float32)
    return np.clip(blocks.mean(axis=(1, 3)) + 0.5, 0, 255).astype(np.uint8)


def geometric_conditioning(depth: np.ndarray, K: np.ndarray, edge: float = 0.1) -> float:
    """How well a depth map's surfaces constrain point-to-plane alignment in all 6 degrees of freedom.

    Builds the 6x6 point-to-plane information matrix sum J^T J, J = [(p x n)^T, n^T] with points centred
    and scaled to unit RMS radius (so rotation and translation are commensurate), normals from central
    differences of the back-projected depth [H, W] (metres, 0 = invalid; pairs spanning more than ``edge``
    metres are depth edges and skipped) and K [3, 3]. Returns min/max eigenvalue: 0 for a single plane
    or a corridor (a direction the geometry does not constrain), about 0.02-0.3 for rooms.
    """
    depth = np.asarray(depth, dtype=np.float64)
    h, w = depth.shape
    if h < 3 or w < 3:
        return 0.0
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    P = np.stack([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth], axis=-1)
    dx = P[1:-1, 2:] - P[1:-1, :-2]
    dy = P[2:, 1:-1] - P[:-2, 1:-1]
    ok = (depth[1:-1, 1:-1] > 0) & (depth[1:-1, 2:] > 0) & (depth[1:-1, :-2] > 0)
    ok &= (depth[2:, 1:-1] > 0) & (depth[:-2, 1:-1] > 0)
    ok &= (np.abs(dx[..., 2]) < edge) & (np.abs(dy[..., 2]) < edge)
    n = np.cross(dx, dy)[ok]
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    keep = norm[:, 0] > 0
    if keep.sum() < 6:
        return 0.0
    n = n[keep] / norm[keep]
    p = P[1:-1, 1:-1][ok][keep]
    p = p - p.mean(axis=0)
    p /= max(float(np.sqrt((p**2).sum(axis=1).mean())), 1e-9)
    J = np.concatenate([np.cross(p, n), n], axis=1)
    ev = np.linalg.eigvalsh(J.T @ J)
    return float(max(ev[0], 0.0) / ev[-1]) if ev[-1] > 0 else 0.0


def _kabsch(P: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched least-squares rigid fit (Kabsch): R [B, 3, 3], t [B, 3] minimising |R P_b + t - Q_b|.

    P, Q: [B, n, 3] corresponding point sets.
    """
    mp, mq = P.mean(1), Q.mean(1)
    H = np.einsum("bni,bnj->bij", P - mp[:, None], Q - mq[:, None])
    U, _, Vt = np.linalg.svd(H)
    V, Ut = Vt.transpose(0, 2, 1), U.transpose(0, 2, 1)
    D = np.tile(np.eye(3), (len(P), 1, 1))
    D[:, 2, 2] = np.sign(np.linalg.det(V @ Ut))  # reflections -> proper rotations
    R = V @ D @ Ut
    return R, mq - np.einsum("bij,bj->bi", R, mp)


def ransac_rigid(
    src: np.ndarray, dst: np.ndarray, threshold: float, iterations: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Robust rigid transform T (float64 [4, 4], dst ~ T src) from putative 3D matches src, dst [n, 3].

    All minimal 3-point hypotheses are fitted and scored at once (vectorised); the best one's inliers
    (residual < ``threshold`` metres) are refitted. Returns (T, inlier mask [n]).
    """
    n = len(src)
    if n < 3:
        raise ValueError(f"ransac_rigid needs at least 3 matches, got {n}")
    idx = np.argsort(rng.random((iterations, n)), axis=1)[:, :3]
    R, t = _kabsch(src[idx], dst[idx])
    diff = np.einsum("bij,nj->bni", R, src) + t[:, None] - dst[None]
    res2 = np.einsum("bni,bni->bn", diff, diff)
    thr2 = threshold * threshold
    best = int(np.argmax((res2 < thr2).sum(1)))
    inliers = res2[best] < thr2
    if inliers.sum() >= 3:
        R1, t1 = _kabsch(src[inliers][None], dst[inliers][None])
        inliers = np.linalg.norm(src @ R1[0].T + t1[0] - dst, axis=-1) < threshold
        R, t = R1, t1
    else:  # too few inliers to refit: the best hypothesis itself, which the mask describes
        R, t = R[best : best + 1], t[best : best + 1]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R[0], t[0]
    return T, inliers


@dataclass
class _Prepared:
    """A frame converted for Open3D: RGBD image on the tracking device + intrinsics at tracking resolution.

    ``gray``/``depth_full``/``K_full`` keep the input resolution for ORB features, computed lazily, and
    with ``rgb`` for ``Tracker.state``.
    """

    index: int
    rgbd: Any  # open3d.t.geometry.RGBDImage
    intrinsics: Any  # open3d.core.Tensor float64 [3, 3], integer pixel-centre convention, on CPU
    K: np.ndarray  # float64 [3, 3] at tracking resolution (project convention)
    depth: np.ndarray  # float32 [h, w] metres at tracking resolution, 0 = invalid
    shape: tuple[int, int]
    valid_fraction: float
    gray: np.ndarray  # uint8 [H, W] at input resolution
    depth_full: np.ndarray  # float32 [H, W] metres, 0 = invalid
    K_full: np.ndarray  # float64 [3, 3]
    rgb: np.ndarray  # uint8 [H, W, 3] at input resolution
    features: tuple[np.ndarray, np.ndarray] | None = None  # (points [M, 3], ORB descriptors [M, 32])


class Tracker:
    """Incremental keyframe-to-frame RGB-D odometry (the algorithm: :mod:`ogscene3d.tracking`).

    ``step(frame)`` returns the frame's c2w pose (float64 [4, 4], OpenCV axes) or None when the frame was
    skipped; ``last`` holds the ``StepInfo`` of the latest call. All frames of a sequence must share one
    image size and intrinsics.

    Args:
        config: the ``tracking`` config section; None: its defaults.
        device: where Open3D runs the odometry: "cpu", "cuda", "cuda:N", or None (CUDA if Open3D can).
        frame_step: folder frames per ``step`` call (the data stride): the jump limits are per folder
            frame.
    """

    def __init__(
        self, config: TrackingConfig | None = None, device: Any = "cpu", frame_step: int = 1
    ) -> None:
        import open3d as o3d
        from open3d.t.pipelines import odometry as o3d_odometry

        self.config = config if config is not None else TrackingConfig()
        validate_tracking_config(self.config)
        if int(frame_step) < 1:
            raise ValueError(f"frame_step must be >= 1 (the data stride), got {frame_step}")
        # The jump limits are per folder frame: strided frames may move proportionally further.
        self.frame_step = int(frame_step)
        self.device = open3d_device(device)
        self._o3d = o3d
        self._od = o3d_odometry
        cfg = self.config
        self._criteria = [o3d_odometry.OdometryConvergenceCriteria(int(n)) for n in cfg.iterations]
        self._params = o3d_odometry.OdometryLossParams(
            cfg.depth_outlier_trunc, cfg.depth_huber_delta, cfg.intensity_huber_delta
        )
        self.last: StepInfo | None = None
        self.reset()

    def reset(self, anchor_pose: np.ndarray | None = None) -> None:
        """Forget the keyframe: the next usable frame is anchored at ``anchor_pose`` (None: its own pose)."""
        self._kf: _Prepared | None = None
        self._kf_pose: np.ndarray | None = None
        self._kf_age = 0  # frames tracked against the current keyframe
        self._last_pose: np.ndarray | None = None
        self._velocity = np.eye(4)  # last good inter-frame motion, in the camera frame
        self._since_good = 0  # step() calls since the last good frame
        self._failures = 0  # consecutive skipped frames
        self._recent_rmse: list[tuple[str, float]] = []  # (method, residual) of the last accepted steps
        self._kf_method = "hybrid" if self.config.method == "auto" else self.config.method
        self._anchor_override = None if anchor_pose is None else check_pose(anchor_pose, "anchor pose")

    def state(self) -> dict[str, np.ndarray]:
        """What a resumed run needs to go on in the same trajectory, as arrays for an npz checkpoint: the
        keyframe's image, depth, intrinsics and pose, the last pose, the motion prior and the recent
        residuals (or, right after a restart, the pose to re-anchor at; nothing before the first anchor).
        ``load_state`` restores it."""
        if self._kf is None:
            if self._anchor_override is None:
                return {}
            return {"trk_anchor_pose": self._anchor_override.copy()}
        assert self._kf_pose is not None and self._last_pose is not None
        kf = self._kf
        return {
            "trk_kf_index": np.array(kf.index),
            "trk_kf_rgb": kf.rgb,
            "trk_kf_depth": kf.depth_full,
            "trk_kf_K": kf.K_full,
            "trk_kf_pose": self._kf_pose.copy(),
            "trk_kf_age": np.array(self._kf_age),
            "trk_last_pose": self._last_pose.copy(),
            "trk_velocity": self._velocity.copy(),
            "trk_since_good": np.array(self._since_good),
            "trk_failures": np.array(self._failures),
            "trk_recent_methods": np.array([m for m, _ in self._recent_rmse], dtype=str),
            "trk_recent_rmse": np.array([r for _, r in self._recent_rmse], dtype=np.float64),
        }

    def load_state(self, state: Mapping[str, np.ndarray]) -> None:
        """Continue from ``state()`` of a tracker with the same configuration (a resumed run): the next
        frame is aligned to the saved keyframe, so the trajectory goes on in the saved one's coordinates."""
        self.reset()
        if "trk_kf_rgb" not in state:
            if "trk_anchor_pose" in state:
                self._anchor_override = check_pose(state["trk_anchor_pose"], "saved tracker anchor pose")
            return
        try:
            frame = Frame(
                int(state["trk_kf_index"]),
                np.ascontiguousarray(state["trk_kf_rgb"], dtype=np.uint8),
                np.ascontiguousarray(state["trk_kf_depth"], dtype=np.float32),
                state["trk_kf_K"],
            )
            self._accept_keyframe(
                self._prepare(frame), check_pose(state["trk_kf_pose"], "saved keyframe pose")
            )
            self._kf_age = int(state["trk_kf_age"])
            self._last_pose = check_pose(state["trk_last_pose"], "saved last pose")
            self._velocity = check_pose(state["trk_velocity"], "saved motion prior")
            self._since_good = int(state["trk_since_good"])
            self._failures = int(state["trk_failures"])
            rmse = np.asarray(state["trk_recent_rmse"], dtype=np.float64)
            self._recent_rmse = list(zip(np.asarray(state["trk_recent_methods"]).tolist(), rmse.tolist()))
        except KeyError as e:
            raise OGSceneError(f"saved tracker state is incomplete (missing {e})") from e

    @property
    def keyframe_pose(self) -> np.ndarray | None:
        """c2w pose of the current keyframe (None before the anchor)."""
        return None if self._kf_pose is None else self._kf_pose.copy()

    @property
    def keyframe_index(self) -> int | None:
        return None if self._kf is None else self._kf.index

    # ------------------------------------------------------------------ frame preparation
    def _prepare(self, frame: Frame) -> _Prepared:
        o3d = self._o3d
        cfg = self.config
        h, w = frame.rgb.shape[:2]
        cam = Camera.from_K(frame.K, w, h)  # validates K
        depth = np.asarray(frame.depth, dtype=np.float32)
        if depth.shape != (h, w):
            raise ValueError(
                f"frame {frame.index}: depth shape {depth.shape} differs from rgb shape {(h, w)}"
            )
        # Non-finite depth is treated as missing (0), like the sensor's own holes.
        depth = np.where(np.isfinite(depth) & (depth >= cfg.depth_min), depth, 0.0).astype(np.float32)
        depth_full = depth
        rgb = np.asarray(frame.rgb)
        f = max(1, math.ceil(w / cfg.max_width)) if cfg.max_width > 0 else 1
        if f > 1:
            if h // f < 8 or w // f < 8:
                raise ValueError(f"frame {frame.index}: {w}x{h} is too small to downsample by {f}")
            rgb = _downsample_rgb(rgb, f)
            depth = _downsample_depth(depth, f, 2.0 * cfg.depth_outlier_trunc)
            cam = Camera(cam.fx / f, cam.fy / f, cam.cx / f, cam.cy / f, w // f, h // f)
        K = cam.K.astype(np.float64)
        K_o3d = K.copy()
        K_o3d[0, 2] -= 0.5
        K_o3d[1, 2] -= 0.5
        valid_fraction = float(np.count_nonzero((depth > 0) & (depth < cfg.depth_max))) / depth.size
        color_t = o3d.core.Tensor(np.ascontiguousarray(rgb)).to(self.device)
        depth_t = o3d.core.Tensor(np.ascontiguousarray(depth)[..., None]).to(self.device)
        rgbd = o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(color_t), o3d.t.geometry.Image(depth_t))
        intrinsics = o3d.core.Tensor(K_o3d, dtype=o3d.core.float64)
        gray = cv2.cvtColor(np.ascontiguousarray(frame.rgb), cv2.COLOR_RGB2GRAY)
        K_full = np.asarray(frame.K, dtype=np.float64)
        return _Prepared(
            frame.index,
            rgbd,
            intrinsics,
            K,
            depth,
            depth.shape,
            valid_fraction,
            gray,
            depth_full,
            K_full,
            np.asarray(frame.rgb),
        )

    def _features(self, prep: _Prepared) -> tuple[np.ndarray, np.ndarray]:
        """ORB keypoints with valid depth, back-projected: (points [M, 3] metres, descriptors [M, 32])."""
        if prep.features is None:
            # Small images (e.g. 160x120) give too few ORB corners with the default 31-pixel patch: detect
            # on a 2x upsampled image with a 15-pixel patch and a lower FAST threshold instead.
            small = prep.gray.shape[1] < _ORB_SMALL_WIDTH
            up = 2 if small else 1
            gray = (
                cv2.resize(prep.gray, None, fx=up, fy=up, interpolation=cv2.INTER_LINEAR)
                if small
                else prep.gray
            )
            patch = 15 if small else 31
            orb = cv2.ORB_create(
                nfeatures=int(self.config.orb_features),
                edgeThreshold=patch,
                patchSize=patch,
                fastThreshold=10 if small else 20,
            )
            kps, des = orb.detectAndCompute(gray, None)
            if des is None or not kps:
                prep.features = (np.zeros((0, 3)), np.zeros((0, 32), np.uint8))
                return prep.features
            # OpenCV keypoints have pixel centres at integers; map back to the input image's pixel indices.
            uv = (cv2.KeyPoint_convert(kps).astype(np.float64) + 0.5) / up - 0.5
            h, w = prep.depth_full.shape
            ui = np.clip(np.rint(uv[:, 0]).astype(np.int64), 0, w - 1)
            vi = np.clip(np.rint(uv[:, 1]).astype(np.int64), 0, h - 1)
            z = prep.depth_full[vi, ui].astype(np.float64)
            ok = (z > 0) & (z < self.config.depth_max)
            K = prep.K_full
            x = (uv[:, 0] + 0.5 - K[0, 2]) / K[0, 0] * z
            y = (uv[:, 1] + 0.5 - K[1, 2]) / K[1, 1] * z
            prep.features = (np.stack([x, y, z], axis=1)[ok], des[ok])
        return prep.features

    def _feature_guess(self, src: _Prepared, dst: _Prepared) -> tuple[np.ndarray | None, str]:
        """Source-to-target transform from ORB matches + RANSAC, or (None, why not)."""
        cfg = self.config
        ps, ds = self._features(src)
        pt, dt = self._features(dst)
        if len(ps) < cfg.min_feature_inliers or len(pt) < cfg.min_feature_inliers:
            return None, f"too few ORB features with depth ({len(ps)}, {len(pt)})"
        matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(ds, dt)
        if len(matches) < cfg.min_feature_inliers:
            return None, f"only {len(matches)} ORB matches"
        a = ps[[m.queryIdx for m in matches]]
        b = pt[[m.trainIdx for m in matches]]
        rng = np.random.default_rng(src.index)  # reproducible per frame
        T, inliers = ransac_rigid(a, b, cfg.ransac_threshold, 256, rng)
        if inliers.sum() < cfg.min_feature_inliers:
            return None, f"only {int(inliers.sum())} RANSAC inliers among {len(matches)} ORB matches"
        return T, ""

    # ------------------------------------------------------------------ odometry + checks
    def _odometry(
        self, src: _Prepared, dst: _Prepared, init: np.ndarray, method: str
    ) -> tuple[np.ndarray, float, float]:
        """Source-to-target transform (p_dst = T @ p_src), fitness and inlier RMSE from Open3D."""
        o3d = self._o3d
        res = self._od.rgbd_odometry_multi_scale(
            src.rgbd,
            dst.rgbd,
            src.intrinsics,
            o3d.core.Tensor(np.ascontiguousarray(init), dtype=o3d.core.float64),
            1.0,  # depth is already in metres
            float(self.config.depth_max),
            self._criteria,
            getattr(self._od.Method, _METHODS[method]),
            self._params,
        )
        return res.transformation.cpu().numpy().astype(np.float64), float(res.fitness), float(res.inlier_rmse)

    def _reject_reason(self, pose: np.ndarray, fitness: float, rmse: float) -> str | None:
        cfg = self.config
        if not (math.isfinite(fitness) and math.isfinite(rmse)):
            return "odometry returned a non-finite fitness/residual"
        try:
            check_pose(pose, "tracked pose")
        except ValueError as e:
            return str(e)
        if fitness < cfg.min_fitness:
            return f"too few correspondences (fitness {fitness:.3f} < min_fitness {cfg.min_fitness})"
        if rmse > cfg.max_inlier_rmse:
            return f"residual too large (inlier rmse {rmse:.4f} > max_inlier_rmse {cfg.max_inlier_rmse})"
        return None

    def _jump_reason(self, pose: np.ndarray) -> str | None:
        """Why the motion since the last good frame is implausible, or None.

        Applied to the selected alignment only: a better-aligned but implausible result must not be
        replaced by a worse-aligned candidate that merely happens to move less.
        """
        cfg = self.config
        assert self._last_pose is not None
        rel = np.linalg.inv(self._last_pose) @ pose
        gap = max(1, self._since_good) * self.frame_step
        dt, dr = float(np.linalg.norm(rel[:3, 3])), rotation_angle_deg(rel[:3, :3])
        if dt > cfg.max_translation * gap or dr > cfg.max_rotation_deg * gap:
            return (
                f"implausible jump of {dt:.3f} m / {dr:.1f} deg over {gap} frame(s) "
                f"(limits {cfg.max_translation} m / {cfg.max_rotation_deg} deg per folder frame)"
            )
        return None

    # ------------------------------------------------------------------ public step
    def step(self, frame: Frame) -> np.ndarray | None:
        """Track one frame.

        Args:
            frame: the next frame of the sequence (same image size and intrinsics as the ones before);
                ``frame.pose`` is read for the anchor frame only.

        Returns:
            The frame's c2w pose (float64 [4, 4], OpenCV axes), or None when it is skipped (a warning is
            logged; ``self.last`` says why).
        """
        if not isinstance(frame, Frame):
            raise TypeError(f"Tracker.step expects an ogscene3d.frame.Frame, got {type(frame).__name__}")
        prep = self._prepare(frame)
        self._since_good += 1
        if self._kf is None:
            return self._anchor(frame, prep)
        kf = self._kf
        self._check_same_camera(frame, prep, kf)
        if prep.valid_fraction < self.config.min_fitness:
            return self._skip(
                frame,
                f"only {prep.valid_fraction:.1%} valid depth pixels "
                f"(< tracking.min_fitness {self.config.min_fitness})",
            )
        method, passing, reason, fitness, rmse = self._candidates(prep, kf)
        if not passing:
            return self._skip(frame, reason, fitness, rmse)
        fitness, rmse, pose = _best_candidate(passing)
        reason = self._jump_reason(pose) or self._reacquisition_reason(method, rmse)
        if reason:
            return self._skip(frame, reason, fitness, rmse)
        self._accept_step(pose, method, rmse)
        why = self._keyframe_reason(pose, fitness)
        info = StepInfo(frame.index, pose.copy(), "tracked", why, fitness, rmse, bool(why), kf.index, method)
        if why:
            self._accept_keyframe(prep, pose)
        self.last = info
        return pose.copy()

    def _anchor(self, frame: Frame, prep: _Prepared) -> np.ndarray | None:
        """Start the trajectory at ``frame`` (the first usable frame, or the first after a restart): its pose
        is the restart pose, else its own, else the identity."""
        cfg = self.config
        if prep.valid_fraction < cfg.min_fitness:
            return self._skip(
                frame,
                f"only {prep.valid_fraction:.1%} valid depth pixels (< tracking.min_fitness "
                f"{cfg.min_fitness}; tracking.depth_min/depth_max and data.min_depth bound them), "
                "cannot anchor",
            )
        if self._anchor_override is not None:
            pose = self._anchor_override
        elif frame.pose is not None:
            pose = check_pose(frame.pose, f"frame {frame.index} pose")
        else:
            pose = np.eye(4)
        self._accept_keyframe(prep, pose)
        self._last_pose = pose
        self._velocity = np.eye(4)
        self._since_good = 0
        self._failures = 0
        self._anchor_override = None
        self.last = StepInfo(frame.index, pose.copy(), "anchor", "first usable frame", keyframe=True)
        return pose.copy()

    @staticmethod
    def _check_same_camera(frame: Frame, prep: _Prepared, kf: _Prepared) -> None:
        if prep.shape != kf.shape or not np.allclose(prep.K, kf.K):
            raise ValueError(
                f"frame {frame.index}: image size {prep.shape[::-1]} / intrinsics differ from the keyframe's "
                f"{kf.shape[::-1]}; a Tracker follows one camera (call reset() for a new one)"
            )

    def _candidates(
        self, prep: _Prepared, kf: _Prepared
    ) -> tuple[str, list[tuple[float, float, np.ndarray]], str, float, float]:
        """Align ``prep`` to the keyframe from the motion prior, the ORB guess and the last pose (see the
        module docstring) with the keyframe's objective, and with hybrid when "auto" chose point-to-plane
        and nothing passed. -> (objective, passing candidates, reason, last fitness, last rmse)."""
        assert self._last_pose is not None and self._kf_pose is not None
        last = np.linalg.inv(self._kf_pose) @ self._last_pose
        prior = last
        if self._since_good == 1 and not np.allclose(self._velocity, np.eye(4)):
            prior = prior @ self._velocity
        method = self._kf_method
        passing, reason, fitness, rmse = self._align(prep, kf, prior, last, method)
        if not passing and self.config.method == "auto" and method != "hybrid":
            # Geometry looked well-conditioned but nothing passed: let the photometric term help.
            method = "hybrid"
            passing, reason2, fitness, rmse = self._align(prep, kf, prior, last, method)
            reason = f"point_to_plane: {reason}; hybrid: {reason2}"
        return method, passing, reason, fitness, rmse

    def _reacquisition_reason(self, method: str, rmse: float) -> str | None:
        """Why the first good-looking frame after skipped ones is not trusted, or None.

        Re-acquiring after skipped frames: no motion prior, often little overlap. A wrong alignment shows up
        as a residual far above the recent good ones (good and wrong steps' ratios on the samples:
        docs/results.md, "Odometry"). Residual scales differ between objectives, so a result from an
        objective with no recent history cannot be validated and is not trusted.
        """
        cfg = self.config
        if not (self._since_good > 1 and self._recent_rmse and cfg.max_residual_ratio > 0):
            return None
        recent = [r for m, r in self._recent_rmse if m == method]
        if not recent:
            return f"re-acquisition by {method} cannot be checked against recent residuals"
        ref = float(np.median(recent))
        if rmse > cfg.max_residual_ratio * ref:
            return (
                f"re-acquisition residual {rmse:.2e} is {rmse / ref:.1f}x the recent median "
                f"(max_residual_ratio {cfg.max_residual_ratio})"
            )
        return None

    def _accept_step(self, pose: np.ndarray, method: str, rmse: float) -> None:
        """Move the trajectory on to ``pose``: the motion prior, the failure counts, the recent residuals."""
        assert self._last_pose is not None
        if self._since_good == 1:
            self._velocity = np.linalg.inv(self._last_pose) @ pose
        else:
            self._velocity = np.eye(4)
        self._last_pose = pose
        self._since_good = 0
        self._failures = 0
        self._kf_age += 1
        self._recent_rmse = [*self._recent_rmse[1 - _RECENT :], (method, rmse)]

    def _keyframe_reason(self, pose: np.ndarray, fitness: float) -> str:
        """Why the frame at ``pose`` becomes the new keyframe ("" when it does not)."""
        cfg = self.config
        assert self._kf_pose is not None
        rel = np.linalg.inv(self._kf_pose) @ pose
        if fitness < cfg.keyframe_fitness:
            return f"overlap with keyframe {fitness:.2f} < {cfg.keyframe_fitness}"
        if np.linalg.norm(rel[:3, 3]) > cfg.keyframe_translation:
            return "translation from keyframe"
        if rotation_angle_deg(rel[:3, :3]) > cfg.keyframe_rotation_deg:
            return "rotation from keyframe"
        if self._kf_age >= cfg.keyframe_every:
            return f"{self._kf_age} frames since keyframe"
        return ""

    def _align(
        self, prep: _Prepared, kf: _Prepared, prior: np.ndarray, fallback: np.ndarray, method: str
    ) -> tuple[list[tuple[float, float, np.ndarray]], str, float, float]:
        """Run the odometry from the prior, the ORB guess and the fallback (see ``step``).

        Returns the passing (fitness, rmse, c2w pose) candidates, the last rejection reason and the last
        fitness / rmse figures.
        """
        cfg = self.config
        assert self._kf_pose is not None
        recent = [r for m, r in self._recent_rmse if m == method]
        guesses: list[np.ndarray | None] = [prior, None, fallback]  # None: the ORB guess
        passing: list[tuple[float, float, np.ndarray]] = []
        reason, fitness, rmse, feature_why = "", math.nan, math.nan, ""
        for k, guess in enumerate(guesses):
            if k == 1:
                if passing and recent:
                    f0, r0, _ = passing[0]
                    if f0 >= cfg.keyframe_fitness and r0 <= _RMSE_GATE * float(np.median(recent)):
                        break
                if not cfg.feature_init:
                    continue
                guess, feature_why = self._feature_guess(prep, kf)
                if guess is None:
                    continue
            if k == 2 and (passing or np.allclose(guess, prior)):
                break
            try:
                T, fitness, rmse = self._odometry(prep, kf, guess, method)
            except RuntimeError as e:  # Open3D raises on degenerate systems (e.g. a single plane)
                reason = f"Open3D odometry failed: {_open3d_message(e)}"
                continue
            candidate = self._kf_pose @ T
            reason = self._reject_reason(candidate, fitness, rmse) or ""
            if not reason:
                passing.append((fitness, rmse, candidate))
        if not passing and feature_why:
            reason = f"{reason}; feature initialisation failed: {feature_why}"
        return passing, reason, fitness, rmse

    def _accept_keyframe(self, prep: _Prepared, pose: np.ndarray) -> None:
        self._kf = prep
        self._kf_pose = pose.copy()
        self._kf_age = 0
        if self.config.method == "auto":
            c = geometric_conditioning(prep.depth, prep.K)
            self._kf_method = "point_to_plane" if c >= self.config.min_conditioning else "hybrid"
            log.debug("tracking: keyframe %d conditioning %.3g -> %s", prep.index, c, self._kf_method)
        else:
            self._kf_method = self.config.method

    def _skip(self, frame: Frame, reason: str, fitness: float = math.nan, rmse: float = math.nan) -> None:
        self._failures += 1
        ref = -1 if self._kf is None else self._kf.index
        self.last = StepInfo(frame.index, None, "skipped", reason, fitness, rmse, False, ref)
        log.warning("tracking: frame %d skipped: %s", frame.index, reason)
        cfg = self.config
        if cfg.max_lost_frames > 0 and self._failures >= cfg.max_lost_frames and self._last_pose is not None:
            log.warning(
                "tracking: lost for %d frames; restarting at the last good pose (trajectory discontinuity)",
                self._failures,
            )
            self.reset(anchor_pose=self._last_pose)
        return None


def track_frames(
    tracker: Tracker, frames: Iterable[Frame], progress: bool = False, total: int | None = None
) -> Iterator[tuple[Frame, np.ndarray | None, StepInfo]]:
    """(frame, pose or None, step info) for each of ``frames`` in turn, tracked by ``tracker``.
    ``progress``: a progress bar (odometry takes a second or more per frame on a CPU) with log lines routed
    through it; ``total`` its length (default: ``len(frames)`` where there is one)."""
    if total is None and isinstance(frames, Sized):
        total = len(frames)
    tracked = 0
    with progress_bar(frames, desc="track", total=total, disable=not progress) as bar:
        for frame in bar:
            pose = tracker.step(frame)
            assert tracker.last is not None
            tracked += pose is not None
            if progress:
                bar.set_postfix(tracked=tracked, refresh=False)
            yield frame, pose, tracker.last


def track_sequence(
    frames: Iterable[Frame],
    config: TrackingConfig | None = None,
    device: Any = "cpu",
    frame_step: int = 1,
    progress: bool = False,
) -> TrackResult:
    """Track a whole sequence, with each frame's validity and what the tracker did with it.

    Args:
        frames: the sequence's frames in order (one camera); the first frame's ``pose``, if any, anchors
            the trajectory.
        config: the ``tracking`` config section; None: its defaults.
        device: where Open3D runs: "cpu", "cuda", "cuda:N", or None (CUDA if Open3D can).
        frame_step: folder frames per frame given (the data stride).
        progress: show a progress bar.

    Returns:
        A :class:`TrackResult`: one c2w pose per frame (a skipped frame holds the last good pose), the
        validity flags and the per-frame :class:`StepInfo`.

    Raises:
        OGSceneError: ``frames`` is empty, or no frame could be anchored (no usable depth anywhere).
    """
    tracker = Tracker(config, device, frame_step=frame_step)
    raw: list[np.ndarray | None] = []
    infos: list[StepInfo] = []
    for _, pose, info in track_frames(tracker, frames, progress):
        raw.append(pose)
        infos.append(info)
    if not raw:
        raise OGSceneError("track: no frames given")
    poses = hold_last_good(raw)
    if not poses:
        raise OGSceneError(f"track: none of the {len(raw)} frames could be tracked ({infos[0].reason})")
    valid = np.array([p is not None for p in raw], dtype=bool)
    return TrackResult(poses, valid, infos)


def hold_last_good(poses: Sequence[np.ndarray | None]) -> list[np.ndarray]:
    """Every pose, an untracked one (None) replaced by the last good pose before it (by the first good one
    before any); [] when none is good. One pose per frame, as trajectory files and ATE need them."""
    held = next((p for p in poses if p is not None), None)
    if held is None:
        return []
    out = []
    for p in poses:
        if p is not None:
            held = p
        out.append(np.array(held, dtype=np.float64))
    return out


def track(
    frames: Iterable[Frame],
    config: TrackingConfig | None = None,
    device: Any = "cpu",
    frame_step: int = 1,
    progress: bool = False,
) -> list[np.ndarray]:
    """Camera poses for every frame of a sequence, estimated by RGB-D odometry.

    The first frame's pose is its given ``frame.pose`` or the identity; later given poses are ignored.
    A frame that could not be tracked holds the last good pose before it; use :func:`track_sequence` to
    get the validity flags.

    Args:
        frames: the sequence's frames in order (one camera).
        config: the ``tracking`` config section; None: its defaults.
        device: where Open3D runs: "cpu", "cuda", "cuda:N", or None (CUDA if Open3D can).
        frame_step: folder frames per frame given (the data stride).
        progress: show a progress bar.

    Returns:
        One c2w pose per frame, float64 [4, 4], OpenCV axes.
    """
    return track_sequence(frames, config, device, frame_step, progress).poses


def trajectory_text(poses: Iterable[np.ndarray]) -> str:
    """One row-major c2w 4x4 per line (the Replica ``traj.txt`` format read by eval.read_trajectory)."""
    return "".join(
        " ".join(f"{v:.9e}" for v in np.asarray(p, dtype=np.float64).reshape(-1)) + "\n" for p in poses
    )
