"""Data types of the scene graph: nodes, edges, observation sets and caption requests.

Units: world metres, world frame of the map (camera-to-world poses, OpenCV camera axes). Node ids are the
scene labels of the Gaussian map (int >= 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geometry import Shape, oriented_box, shape_of

#: ``caption_source`` values of captions written by a VLM.
VLM_CAPTION_SOURCES: frozenset[str] = frozenset({"vlm", "vlm-text"})
#: ``caption_source`` values of the offline captioner's captions: refreshed at every update, and asked for
#: again from a VLM captioner whose request failed.
OFFLINE_SOURCES: frozenset[str] = frozenset({"heuristic", "detector"})


@dataclass
class Crop:
    """One stored image of a node: uint8 RGB [h, w, 3] (already downscaled), the keyframe it came from and
    the node's projected area in that keyframe (pixels at full resolution)."""

    image: np.ndarray
    keyframe: int
    area: int


@dataclass
class ObservationSet:
    """O_i of paper Eq. 17: the context crop with the largest projected area (entity plus surroundings)
    and up to ``max_masked`` masked views (only the entity's pixels kept) from distinct keyframes, largest
    projected area first."""

    context: Crop | None = None
    masked: list[Crop] = field(default_factory=list)

    def images(self) -> list[np.ndarray]:
        """Context crop first, then masked views: the order the VLM prompt describes."""
        out = [self.context.image] if self.context is not None else []
        return out + [m.image for m in self.masked]

    def wants(self, keyframe: int, area: int, max_masked: int) -> tuple[bool, bool]:
        """Whether an observation of ``area`` pixels at ``keyframe`` would replace (context, masked)."""
        want_ctx = self.context is None or area > self.context.area
        same = [m for m in self.masked if m.keyframe == keyframe]
        if same:
            want_mask = area > same[0].area
        else:
            want_mask = len(self.masked) < max_masked or area > min(m.area for m in self.masked)
        return want_ctx, want_mask

    def add(
        self, keyframe: int, area: int, context: np.ndarray | None, masked: np.ndarray | None, max_masked: int
    ):
        if context is not None:
            self.context = Crop(context, keyframe, area)
        if masked is not None:
            kept = [m for m in self.masked if m.keyframe != keyframe]
            kept.append(Crop(masked, keyframe, area))
            kept.sort(key=lambda c: -c.area)
            self.masked = kept[:max_masked]

    def copy(self) -> ObservationSet:
        return ObservationSet(self.context, list(self.masked))


def node_geometry(
    label: int,
    points: np.ndarray,
    colors: np.ndarray | None = None,
    confidences: np.ndarray | None = None,
    max_points: int = 4096,
    voxel: float = 0.05,
) -> dict:
    """Geometry fields of a :class:`SceneNode` from its Gaussians: ``points`` [N,3] means (metres),
    ``colors`` [N,3] in [0, 1], ``confidences`` [N].

    The stored point set keeps one mean per ``voxel``-metre cell (0: no thinning), so dense and sparse
    parts of a node weigh alike and a large node (a floor) is not left too sparse for the theta_e
    proximity test; beyond ``max_points`` a subsample is drawn with a per-label seed (a stable node
    keeps the same subsample across updates)."""
    P = np.asarray(points, dtype=np.float64)
    n = len(P)
    if P.ndim != 2 or P.shape[1] != 3 or n == 0:
        raise ValueError(f"node {label}: points must be [N>=1, 3], got {P.shape}")
    obb_c, obb_a, obb_e = oriented_box(P)
    conf = np.asarray(confidences if confidences is not None else np.zeros(0), dtype=np.float64)
    conf = conf[np.isfinite(conf)]
    col = np.asarray(colors, dtype=np.float64) if colors is not None else np.full((1, 3), 0.5)
    sub = P
    if voxel > 0:
        cells = np.floor((P - P.min(axis=0)) / voxel).astype(np.int64)
        dims = cells.max(axis=0) + 1
        keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
        _, first = np.unique(keys, return_index=True)
        sub = P[np.sort(first)]
    if len(sub) > max_points:
        sub = sub[np.random.default_rng(label).choice(len(sub), max_points, replace=False)]
    return dict(
        center=P.mean(axis=0),
        bbox_min=P.min(axis=0),
        bbox_max=P.max(axis=0),
        obb_center=obb_c,
        obb_axes=obb_a,
        obb_extent=obb_e,
        num_gaussians=n,
        color=np.clip(np.nanmedian(col, axis=0), 0.0, 1.0),
        mean_confidence=float(np.clip(conf.mean(), 0.0, 1.0)) if len(conf) else 0.0,
        points=sub.astype(np.float32),
    )


@dataclass
class SceneNode:
    """A node n_i: the Gaussians sharing scene label ``id``.

    ``center`` is the mean of the Gaussian means; ``bbox_min``/``bbox_max`` their axis-aligned bounds;
    ``obb_center``/``obb_axes`` (rows = unit axes)/``obb_extent`` (full side lengths) the PCA-oriented box.
    ``caption_source`` says where the caption came from: "vlm", "vlm-text" (a VLM reply in prose instead
    of the requested JSON), "heuristic" (also the fallback after a failed VLM request: such nodes are
    asked for again at later updates), "groundtruth" or "" (none yet). ``confidence`` is C_i (paper
    Eq. 19, or the documented fallback). ``first_seen`` is the keyframe index of the graph update that
    created the node, ``last_updated`` the one that last re-captioned and re-scored it (selective update;
    heuristic captions additionally follow the geometry at every update). ``room``: the room node it is in.
    ``points`` (not serialised) is the thinned set of the node's Gaussian means used for edges,
    ``color`` the median Gaussian colour in [0, 1], ``mean_confidence`` the mean Gaussian confidence.
    """

    id: int
    center: np.ndarray
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    obb_center: np.ndarray
    obb_axes: np.ndarray
    obb_extent: np.ndarray
    num_gaussians: int
    first_seen: int
    last_updated: int
    caption: str = ""
    tag: str = ""
    caption_source: str = ""
    confidence: float = 0.0
    color: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    mean_confidence: float = 0.0
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    # graph.json's "extent", for a node read back from the file (which does not store ``points``)
    stored_extent: np.ndarray | None = field(default=None, repr=False)
    room: int | None = None  # the id of the room node the node is "in" (None: none, or rooms are off)
    _shape: Shape | None = field(default=None, repr=False)
    _shape_up: tuple[float, ...] | None = field(default=None, repr=False)

    @classmethod
    def from_points(
        cls,
        node_id: int,
        points: np.ndarray,
        colors: np.ndarray | None = None,
        confidences: np.ndarray | None = None,
        keyframe: int = 0,
        max_points: int = 4096,
        voxel: float = 0.05,
    ) -> SceneNode:
        """A node built directly from Gaussian means [N,3] (and optional colours / confidences)."""
        g = node_geometry(node_id, points, colors, confidences, max_points, voxel)
        return cls(id=int(node_id), first_seen=keyframe, last_updated=keyframe, **g)

    @property
    def label(self) -> int:
        """The scene label of the node's Gaussians (``label`` in gaussians.ply and graph.json): a node is
        the set of Gaussians sharing one label, so it is the node's id."""
        return int(self.id)

    def shape(self, up: np.ndarray) -> Shape:
        """The node's up-aware :class:`Shape` (cached per up vector)."""
        key = tuple(np.asarray(up, dtype=np.float64).round(9).tolist())
        if self._shape is None or self._shape_up != key:
            pts = self.points if len(self.points) else self.center[None]
            self._shape = shape_of(pts, np.asarray(up, dtype=np.float64))
            self._shape_up = key
        return self._shape

    def extent(self) -> np.ndarray | None:
        """The node's size: robust (2nd-98th percentile) extents along its principal axes (the axis of
        largest spread first), in metres; the heuristic caption's "about ..." is the first
        (:attr:`Shape.extent`, which does not depend on the up vector). None for a node read from a file
        that does not store it."""
        if len(self.points):
            shape = self._shape if self._shape is not None else self.shape(np.array([0.0, 0.0, 1.0]))
            return np.asarray(shape.extent, dtype=np.float64)
        return self.stored_extent

    def to_dict(self) -> dict:
        """The node as graph.json stores it (README "File formats")."""
        extent = self.extent()
        return {
            "id": int(self.id),
            "label": int(self.id),
            "caption": self.caption,
            "tag": self.tag,
            "confidence": float(self.confidence),
            "center": [float(v) for v in self.center],
            "bbox_min": [float(v) for v in self.bbox_min],
            "bbox_max": [float(v) for v in self.bbox_max],
            "num_gaussians": int(self.num_gaussians),
            "first_seen": int(self.first_seen),
            "last_updated": int(self.last_updated),
            "obb_center": [float(v) for v in self.obb_center],
            "obb_axes": [[float(v) for v in row] for row in self.obb_axes],
            "obb_extent": [float(v) for v in self.obb_extent],
            "caption_source": self.caption_source,
            **({"extent": [float(v) for v in extent]} if extent is not None else {}),
            **({"room": int(self.room)} if self.room is not None else {}),
        }


@dataclass
class SceneEdge:
    """A directed relation: "<source> <relation> <target>" (e.g. cup on table). ``score`` is the proximity
    interaction ratio R_ij (paper Eq. 21) that made the pair a candidate; ``predictor`` names what chose the
    relation ("geometric" or "llm")."""

    source: int
    target: int
    relation: str
    score: float
    predictor: str = "geometric"

    def to_dict(self) -> dict:
        return {
            "source": int(self.source),
            "target": int(self.target),
            "relation": self.relation,
            "score": float(self.score),
            "predictor": self.predictor,
        }


@dataclass
class SceneContext:
    """What a captioner may need beyond one node: the world up vector and the height range (along up)
    of the whole mapped scene, in metres."""

    up: np.ndarray
    h_lo: float
    h_hi: float


@dataclass
class CaptionRequest:
    """Everything a :class:`~ogscene3d.graph.captioner.Captioner` gets for one node."""

    node: SceneNode
    observations: ObservationSet
    context: SceneContext
    gt_class_votes: dict[int, int] = field(default_factory=dict)
    gt_instance_votes: dict[int, int] = field(default_factory=dict)
    # {class name: pixels} of the segments a detector named that were given this node's label
    detector_name_votes: dict[str, int] = field(default_factory=dict)
    # the node's label's pixels in the same keyframes, named or not (0: not counted)
    label_pixels: int = 0


@dataclass
class Description:
    """A captioner's answer for one node. ``source``: "vlm", "vlm-text" (prose reply, not the requested
    JSON), "heuristic", "detector" (the offline caption named by the detector's class) or "groundtruth"."""

    caption: str
    tag: str
    source: str
