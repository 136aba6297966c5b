"""What the viewer shows: a :class:`MapSnapshot` (plain numpy arrays + dicts) and how to build one.

The viewer never reads the mapper directly. Whoever produces data (the live mapping thread, a saved
run, a test) builds snapshots and hands them to :meth:`ogscene3d.viewer.app.LiveViewer.publish`.
``snapshot_from_mapper`` reads a :class:`~ogscene3d.mapping.mapper.Mapper`'s public state; it is
called on the mapping thread between two frames, so the map it reads is consistent.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

# Per-Gaussian arrays of a snapshot and their trailing shapes.
GAUSSIAN_FIELDS: dict[str, tuple[int, ...]] = {
    "means": (3,),
    "quats": (4,),
    "scales": (3,),
    "opacities": (),
    "colors": (3,),
    "labels": (),
    "confidences": (),
}


@dataclass
class MapSnapshot:
    """The state of a map as the viewer draws it. All arrays are numpy, world frame, metres.

    Gaussians (possibly a decimated subset of ``total_gaussians``): ``means`` [N,3] float32,
    ``quats`` [N,4] float32 wxyz, ``scales`` [N,3] float32 activated standard deviations (m),
    ``opacities`` [N] float32 in [0, 1], ``colors`` [N,3] float32 RGB in [0, 1], ``labels`` [N] int32
    (-1 unlabeled), ``confidences`` [N] float32 in [0, 1].

    Camera: ``trajectory`` [T,4,4] camera-to-world poses so far (OpenCV axes), ``pose`` the current
    one (or None), ``K`` its 3x3 intrinsics, ``image`` its uint8 HxWx3 RGB (or None) and
    ``image_size`` (width, height) in pixels.

    ``graph``: a graph.json document (``{"nodes": [...], "edges": [...]}``) or None. ``counts``: e.g.
    frames, keyframes, gaussians; ``timings``: milliseconds per keyframe per mapping module.
    ``map_rev`` changes whenever the Gaussians change (None = unknown: the viewer then compares
    contents; the graph is always compared by content); ``status`` is shown in the GUI.
    """

    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    colors: np.ndarray
    labels: np.ndarray
    confidences: np.ndarray
    total_gaussians: int | None = None
    trajectory: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    pose: np.ndarray | None = None
    K: np.ndarray | None = None
    image: np.ndarray | None = None
    image_size: tuple[int, int] | None = None
    graph: dict | None = None
    counts: dict[str, float] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    map_rev: int | None = None
    status: str = ""

    def __post_init__(self) -> None:
        self.means = np.asarray(self.means, dtype=np.float32).reshape(-1, 3)
        n = self.means.shape[0]
        dtypes = {"labels": np.int32}
        for name, shape in GAUSSIAN_FIELDS.items():
            arr = np.asarray(getattr(self, name), dtype=dtypes.get(name, np.float32))
            if arr.shape != (n, *shape):
                raise ValueError(f"MapSnapshot: {name} must have shape {(n, *shape)}, got {arr.shape}")
            setattr(self, name, arr)
        if self.total_gaussians is None:
            self.total_gaussians = n
        self.trajectory = np.asarray(self.trajectory, dtype=np.float64).reshape(-1, 4, 4)
        if self.pose is not None:
            self.pose = np.asarray(self.pose, dtype=np.float64)
            if self.pose.shape != (4, 4):
                raise ValueError(f"MapSnapshot: pose must be 4x4, got {self.pose.shape}")
        if self.K is not None:
            self.K = np.asarray(self.K, dtype=np.float64)
            if self.K.shape != (3, 3):
                raise ValueError(f"MapSnapshot: K must be 3x3, got {self.K.shape}")
        if self.image is not None:
            img = np.asarray(self.image)
            if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
                raise ValueError(f"MapSnapshot: image must be uint8 HxWx3, got {img.dtype} {img.shape}")
            self.image = img
            if self.image_size is None:
                self.image_size = (int(img.shape[1]), int(img.shape[0]))

    def __len__(self) -> int:
        return int(self.means.shape[0])

    def subset(self, idx: np.ndarray) -> MapSnapshot:
        """A snapshot with only the Gaussians ``idx`` (indices or a bool mask); everything else shared."""
        return dataclasses.replace(self, **{k: getattr(self, k)[idx] for k in GAUSSIAN_FIELDS})

    def finite(self) -> MapSnapshot:
        """Drop Gaussians with any non-finite value (a diverged optimisation must not break the viewer)."""
        ok = np.ones(len(self), dtype=bool)
        for name in GAUSSIAN_FIELDS:
            arr = getattr(self, name)
            if arr.dtype.kind == "f":
                ok &= np.isfinite(arr.reshape(len(self), int(np.prod(arr.shape[1:])))).all(axis=1)
        if ok.all():
            return self
        log.warning("viewer: dropping %d Gaussians with NaN/inf parameters", int((~ok).sum()))
        return self.subset(ok)


def empty_snapshot(**kwargs: Any) -> MapSnapshot:
    """A snapshot with no Gaussians (keyword arguments set the other fields)."""
    z = np.zeros
    return MapSnapshot(
        means=z((0, 3)),
        quats=z((0, 4)),
        scales=z((0, 3)),
        opacities=z(0),
        colors=z((0, 3)),
        labels=z(0, np.int32),
        confidences=z(0),
        **kwargs,
    )


def decimate_indices(n: int, budget: int, seed: int = 0) -> np.ndarray | None:
    """Indices of ``budget`` of ``n`` items (sorted, unique), or None when n <= budget.

    Stratified: one random index in each of ``budget`` equal strata of [0, n). It costs O(budget), not
    O(n), covers the whole range evenly (the map's Gaussians are ordered by the keyframe that made them,
    so every part of the scene keeps its share) and, being jittered, does not alias with the regular
    pixel grid the Gaussians were seeded from. It depends only on (n, budget, seed): an unchanged map
    gives an unchanged subset, so nothing needs to be re-sent.
    """
    if budget < 1:
        raise ValueError(f"decimation budget must be >= 1, got {budget}")
    if n <= budget:
        return None
    u = np.random.default_rng([seed, n, budget]).random(budget)
    return np.floor((np.arange(budget) + u) * (n / budget)).astype(np.int64).clip(0, n - 1)


def quat_to_rotmat(quats: np.ndarray) -> np.ndarray:
    """[N,4] wxyz (any norm; zero -> identity) -> [N,3,3] rotation matrices."""
    q = np.asarray(quats, dtype=np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 1e-12, q / np.maximum(norm, 1e-12), np.array([1.0, 0.0, 0.0, 0.0]))
    w, x, y, z = q.T
    R = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        1,
    )
    return R


def covariances(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Σ = R S Sᵀ Rᵀ per Gaussian: quats [N,4] wxyz, scales [N,3] std-devs (m) -> [N,3,3] float32 (m²)."""
    R = quat_to_rotmat(quats)
    s2 = np.square(np.asarray(scales, dtype=np.float64))
    return ((R * s2[:, None, :]) @ R.transpose(0, 2, 1)).astype(np.float32)


def rotmat_to_wxyz(R: np.ndarray) -> np.ndarray:
    """A 3x3 rotation matrix -> unit quaternion wxyz (for placing scene nodes)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def timings_ms_per_keyframe(timings: dict) -> dict[str, float]:
    """Milliseconds per keyframe per module from a ``timings.json`` document (or Timings.as_dict())."""
    ms = timings.get("ms_per_keyframe")
    if isinstance(ms, dict):
        return {str(k): float(v) for k, v in ms.items() if isinstance(v, int | float)}
    return {}


def graph_document(graph: Any) -> dict | None:
    """The graph.json document of a scene-graph object (``to_json()``/``to_dict()``) or a dict, else None."""
    if graph is None:
        return None
    if isinstance(graph, dict):
        return copy.deepcopy(graph)  # the producer may keep editing its dict
    for name in ("to_json", "to_dict"):
        fn = getattr(graph, name, None)
        if callable(fn):
            doc = fn()
            if isinstance(doc, dict):
                return doc
    return None


def snapshot_from_mapper(
    mapper: Any,
    budget: int,
    *,
    trajectory: np.ndarray | None = None,
    frame: Any = None,
    map_rev: int | None = None,
    status: str = "",
    seed: int = 0,
) -> MapSnapshot:
    """Build a snapshot from a live :class:`~ogscene3d.mapping.mapper.Mapper` (call on its thread).

    Reads ``mapper.map`` (GaussianMap), ``mapper.timings``, ``mapper.frames_seen``,
    ``mapper.keyframe_count`` and the scene graph (``mapper.graph``).
    At most ``budget`` Gaussians are copied off the device (a stratified random subset), so the cost
    does not grow with the map. ``frame`` (the last Frame) gives the current pose, K and image;
    ``trajectory`` [T,4,4] the poses so far (the mapper keeps none).
    """
    import torch

    gm = mapper.map
    n = len(gm)
    idx = decimate_indices(n, budget, seed)
    with torch.no_grad():
        sel = None if idx is None else torch.as_tensor(idx, device=gm.device)

        def take(t: torch.Tensor, fn=None) -> np.ndarray:
            # Subset and activate on the map's device, then copy: the mapper keeps changing its tensors in
            # place while the viewer reads the snapshot on another thread, so nothing may be shared.
            t = t.detach() if sel is None else t.detach().index_select(0, sel)
            if fn is not None:
                t = fn(t)
            return t.to("cpu", copy=sel is None and fn is None).numpy()

        arrays = {
            "means": take(gm.means),
            "quats": take(gm.quats),
            "scales": take(gm.log_scales, torch.exp),
            "opacities": take(gm.opacity_logits, torch.sigmoid),
            "colors": take(gm.colors),
            "labels": take(gm.labels),
            "confidences": take(gm.confidences),
        }

    timings = mapper.timings.as_dict() if hasattr(mapper.timings, "as_dict") else {}
    graph_obj = getattr(mapper, "graph", None)
    try:
        graph = graph_document(graph_obj)
    except Exception as e:  # noqa: BLE001 - a graph that cannot be read must not stop the viewer
        log.warning("viewer: cannot read the scene graph: %s: %s", type(e).__name__, e)
        graph = None
    counts: dict[str, float] = {
        "frames": int(getattr(mapper, "frames_seen", 0)),
        "keyframes": int(getattr(mapper, "keyframe_count", 0)),
        "gaussians": n,
    }
    for key in ("labels", "memory_size"):
        if key in timings.get("counts", {}):
            counts[key] = timings["counts"][key]
    kwargs: dict[str, Any] = {}
    if frame is not None:
        kwargs = {
            "pose": frame.pose,
            "K": frame.K,
            "image": frame.rgb,
            "image_size": (frame.width, frame.height),
        }
    return MapSnapshot(
        **arrays,
        total_gaussians=n,
        trajectory=trajectory if trajectory is not None else np.zeros((0, 4, 4)),
        graph=graph,
        counts=counts,
        timings=timings_ms_per_keyframe(timings),
        map_rev=map_rev,
        status=status,
        **kwargs,
    )


__all__ = [
    "GAUSSIAN_FIELDS",
    "MapSnapshot",
    "covariances",
    "decimate_indices",
    "empty_snapshot",
    "graph_document",
    "quat_to_rotmat",
    "rotmat_to_wxyz",
    "snapshot_from_mapper",
    "timings_ms_per_keyframe",
]
