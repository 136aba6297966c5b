"""Run configuration: nested dataclasses loaded from YAML (``yaml.safe_load``) with ``key=value`` overrides.

Every section has the paper's defaults (Sec. IV-A.4); ``configs/*.yaml`` only state what differs per dataset.
Unknown keys are errors, so a typo in a YAML file never silently falls back to a default.

Each setting carries its own rules on the field: the type (a ``Literal`` lists the allowed choices), the
allowed range of a number and the check of a numeric list as field metadata, and a doc string
(:func:`setting`). :func:`check_config` walks the fields; ``ogscene3d config`` prints them (:func:`settings`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import numbers
import types
import typing
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from .atomic import atomic_write_text
from .errors import ConfigError
from .shipped_configs import resolve_config_path, shipped_configs


# --------------------------------------------------------------------------------------------------- rules
@dataclass(frozen=True)
class Range:
    """The allowed values of one numeric setting: ``lo``/``hi`` (None: unbounded), open or closed. Floats must
    also be finite (NaN and inf fail every float setting); ``optional`` settings (typed ``... | None``) also
    take None."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False
    optional: bool = False
    note: str = ""  # what a special value means, e.g. "0 = no limit"

    def contains(self, value: Any) -> bool:
        if value is None:
            return self.optional
        if isinstance(value, bool):
            return False
        if self.integer:
            if not isinstance(value, numbers.Integral):
                return False
        elif not isinstance(value, numbers.Real) or not math.isfinite(value):
            return False
        # written so that NaN fails every comparison
        if self.lo is not None and not (value > self.lo if self.lo_open else value >= self.lo):
            return False
        if self.hi is not None and not (value < self.hi if self.hi_open else value <= self.hi):
            return False
        return True

    def describe(self) -> str:
        what = "an integer" if self.integer else "a finite number"
        lo, hi = (None if b is None else f"{b:g}" for b in (self.lo, self.hi))
        if lo is not None and hi is not None:  # a float in bounds is finite: no need to say so
            text = f"{'(' if self.lo_open else '['}{lo}, {hi}{')' if self.hi_open else ']'}"
            text = f"{what} in {text}" if self.integer else f"in {text}"
        elif lo is not None:
            text = f"{what} {'>' if self.lo_open else '>='} {lo}"
        elif hi is not None:
            text = f"{what} {'<' if self.hi_open else '<='} {hi}"
        else:
            text = what
        if self.optional:
            text += " or null"
        return f"{text} ({self.note})" if self.note else text


def _int(lo: int, hi: int | None = None, note: str = "") -> Range:
    return Range(lo, hi, integer=True, note=note)


def _float(
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    hi_open: bool = False,
    note: str = "",
) -> Range:
    return Range(lo, hi, lo_open, hi_open, note=note)


_UNIT = _float(0.0, 1.0)  # probabilities, ratios, thresholds on scores
_NONNEG = _float(0.0)
_POS = _float(0.0, lo_open=True)


def _numbers(value: Any, count: int | None = None, integer: bool = False) -> list | None:
    """``value`` as a list of finite numbers (integers), or None when it is not one (of ``count`` items)."""
    if not isinstance(value, list | tuple) or (count is not None and len(value) != count):
        return None
    kind = numbers.Integral if integer else numbers.Real
    if not all(isinstance(v, kind) and not isinstance(v, bool) for v in value):
        return None
    if not all(math.isfinite(v) for v in value):
        return None
    return list(value)


# the checks of the numeric list settings (``check=`` on their fields): what is wrong, None when fine
def _check_intrinsics(v: Any) -> str | None:
    if v is None:
        return None
    vals = _numbers(v, 4)
    if vals is None or not (vals[0] > 0 and vals[1] > 0):
        return "must be null or [fx, fy, cx, cy]: 4 finite numbers with fx, fy > 0"
    return None


def _check_score_range(v: Any) -> str | None:
    vals = _numbers(v, 2)
    if vals is None or not vals[0] < vals[1]:
        return "must be [low, high]: 2 finite numbers with low < high"
    return None


def _check_conf_range(v: Any) -> str | None:
    vals = _numbers(v, 2)
    if vals is None or not all(0 <= c <= 1 for c in vals):
        return "must be [low, high]: 2 confidences in [0, 1]"
    return None


def _check_up_axis(v: Any) -> str | None:
    if v == "auto":
        return None
    vals = _numbers(v, 3)
    if vals is None or not math.hypot(*vals) > 1e-9:
        return "must be auto or a finite non-zero 3-vector"
    return None


def _check_iterations(v: Any) -> str | None:
    vals = _numbers(v, integer=True)
    if not vals or not all(n >= 1 for n in vals):
        return "must be a non-empty list of integers >= 1 (one per pyramid level)"
    return None


def setting(
    default: Any,
    doc: str,
    range: Range | None = None,
    check: Callable[[Any], str | None] | None = None,
) -> Any:
    """A config field with its rules: ``range`` for an int / float setting (each follows what the setting's
    consumer does with it: where 0 means "off" or "no limit" it stays allowed), ``check`` for a numeric list
    (returns what is wrong, None when fine), ``doc`` printed by ``ogscene3d config``. Choices come from the
    field's ``Literal`` type. A list default is copied per instance."""
    metadata = {"doc": doc, "range": range, "check": check}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=metadata)
    return field(default=default, metadata=metadata)


def section(cls: type, doc: str) -> Any:
    """A nested config section (its own dataclass), documented like a setting."""
    return field(default_factory=cls, metadata={"doc": doc})


# ------------------------------------------------------------------------------------------------- sections
DatasetKind = Literal[
    "auto",
    "replica",
    "semantic_nerf",
    "scannet",
    "tum",
    "sevenscenes",
    "labelfusion",
    "synthetic",
    "rosbag",
    "record3d",
]
# low / default / high err like SAM (objects absorbed into their support, merged with it, cut in two); the
# legacy-* levels are the earlier simulation (small objects dropped, only small objects merged)
NoiseLevel = Literal["none", "low", "default", "high", "legacy-low", "legacy-default", "legacy-high"]
ExecutionProvider = Literal["auto", "cpu", "cuda"]
_LLM_KEY_DOC = "environment variable holding the endpoint's API key (the key itself never goes in a config)"


def _component_model(what: str) -> Any:
    """A language-model component's own ``model`` setting (``""``: the shared ``graph.endpoint.model``)."""
    return setting("", f'model name for {what}; "" = graph.endpoint.model')


def _max_tokens(default: int) -> Any:
    """A language-model component's ``max_tokens`` setting, ``default`` tokens per request."""
    return setting(default, "max_tokens of a request", _int(0, note="0 = no max_tokens in the request"))


@dataclass
class DataConfig:
    kind: DatasetKind = setting("auto", "dataset layout; auto detects it from the folder")
    path: str | None = setting(None, "dataset folder (the commands' --data sets it)")
    segments_dir: str | None = setting(
        None,
        "folder of precomputed 2D segments (`ogscene3d segment`); null: a synthetic scene's own segments/",
    )
    stride: int = setting(1, "use every stride-th frame of the folder", _int(1))
    start: int = setting(0, "index of the first frame used", _int(0))
    max_frames: int | None = setting(None, "at most this many frames", _int(1, note="null = all frames"))
    depth_scale: float | None = setting(
        None,
        "raw depth units per metre",
        _float(0.0, lo_open=True, note="null = the dataset's own"),
    )
    depth_format: Literal["auto", "linear", "shift3"] = setting(
        "auto",
        "how raw depth values become metres: auto (the layout's) | linear (raw / scale) | "
        "shift3 (APC: (raw >> 3) / scale)",
    )
    intrinsics: list[float] | None = setting(
        None, "[fx, fy, cx, cy] overriding the dataset's", check=_check_intrinsics
    )
    scale: float = setting(
        1.0,
        "resize factor of the frames (colour, depth, segments and intrinsics alike, as read): 0.5 halves "
        "width and height, a quarter of the pixels to map (large images on a CPU)",
        _float(0.0, 1.0, lo_open=True),
    )
    pixel_centers: Literal["auto", "integer", "half"] = setting(
        "auto",
        "where the intrinsics read (files, data.intrinsics) put the centre of pixel (0, 0): auto (the "
        "layout's: integer for ScanNet, TUM, 7-Scenes, label-fusion; half for Replica, synthetic, "
        "Semantic-NeRF) | integer (OpenCV, ROS calibrations: (0, 0)) | half (COLMAP, gsplat: (0.5, 0.5), "
        "ogscene3d's own K). Integer values are shifted by +0.5 on reading.",
    )
    min_depth: float = setting(
        0.0, "metres; nearer depth is invalid", _float(0.0, note="0 = the dataset's own")
    )
    max_depth: float = setting(0.0, "metres; farther depth is invalid", _float(0.0, note="0 = no limit"))
    on_bad_frame: Literal["error", "skip"] = setting(
        "error", "a frame that cannot be read: stop with an error naming the file, or skip it with a warning"
    )
    # robot input: ROS bags (data.kind rosbag) and Record3D captures (data.kind record3d); topics are found by
    # message type when the bag has one candidate, these choose among several
    ros_rgb_topic: str | None = setting(
        None, "ROS bag: the sensor_msgs/Image or CompressedImage colour topic"
    )
    ros_depth_topic: str | None = setting(
        None, "ROS bag: the depth topic registered to colour (e.g. .../aligned_depth_to_color/image_raw)"
    )
    ros_camera_info_topic: str | None = setting(
        None, "ROS bag: the colour camera's sensor_msgs/CameraInfo topic"
    )
    ros_pose_topic: str | None = setting(
        None, "ROS bag: a PoseStamped / PoseWithCovarianceStamped / Odometry topic used instead of /tf"
    )
    ros_world_frame: str | None = setting(
        None, "ROS bag: the tf world frame; null = the root of the camera frame's tf tree"
    )
    ros_camera_frame: str | None = setting(
        None, "ROS bag: the tf camera (optical) frame; null = the colour images' header.frame_id"
    )
    ros_sync_tolerance: float = setting(
        0.02,
        "ROS bag: seconds; the largest colour/depth stamp difference of a pair, and how far a pose is held "
        "beyond the first/last transform sample",
        _NONNEG,
    )
    r3d_min_confidence: int = setting(
        1, "Record3D: depth of lower confidence (0 low, 1 medium, 2 high) is left out", _int(0, 2)
    )

    def cross_check(self) -> str | None:
        if self.max_depth > 0 and not self.min_depth < self.max_depth:
            return (
                f"data.min_depth must be < data.max_depth when data.max_depth > 0 (0 = no limit), got "
                f"{self.min_depth!r} >= {self.max_depth!r}"
            )
        return None


@dataclass
class SyntheticConfig:
    seed: int = setting(0, "seed of the procedural room", _int(0))
    frames: int = setting(60, "frames of the camera path (layout apartment: per room)", _int(1))
    width: int = setting(160, "image width in pixels", _int(8))
    height: int = setting(120, "image height in pixels", _int(8))
    noise: NoiseLevel = setting("default", "how far the simulated SAM segments err")
    depth_noise: float = setting(0.0, "std of the depth noise in metres", _NONNEG)
    pose_noise: float = setting(0.0, "std of the translation noise of the given poses in metres", _NONNEG)
    layout: Literal["room", "scan", "apartment"] = setting(
        "room",
        "the scene: room (one furnished room, a smooth walk around it) | scan (a long scan like a real "
        "ScanNet one: a larger room whose large furniture stands side by side, a walk that leaves places and "
        "comes back, irregular frame gaps up to 1.5 m / 60 degrees, objects merged with the floor or their "
        "neighbour in their first views; give it 300 frames or more) | apartment (2-5 rooms of distinct "
        "types joined by doorways, walked through room by room; gt/instances.json gives every instance's "
        "room)",
    )


@dataclass
class SegmentationConfig:
    backend: Literal["precomputed", "sam", "sam+detector", "classical", "simulated", "none"] = setting(
        "precomputed",
        "the 2D segmenter for frames that carry no precomputed segments: precomputed (-> classical, with a "
        "warning) | sam | sam+detector | classical | simulated | none (map geometry only, every Gaussian "
        "unlabelled)",
    )
    sam_encoder: str | None = setting(None, "ONNX file of the SAM image encoder")
    sam_decoder: str | None = setting(None, "ONNX file of the SAM prompt decoder")
    detector: str | None = setting(None, "ONNX file of the open-vocabulary detector (YOLO-World style)")
    detector_classes: list[str] = setting([], "class names the detector is prompted with")
    points_per_side: int = setting(32, "SAM automatic masks: grid prompts per image side", _int(1))
    pred_iou_thresh: float = setting(0.88, "SAM: masks with a lower predicted IoU are dropped", _UNIT)
    stability_score_thresh: float = setting(
        0.92, "SAM: masks with a lower stability score are dropped", _UNIT
    )
    box_nms_thresh: float = setting(
        0.7, "SAM: box IoU above which the lower-scored mask is suppressed", _UNIT
    )
    min_region_area: int = setting(
        100, "regions and holes smaller than this many pixels are removed", _int(0, note="0 = no clean-up")
    )
    tau_m: float = setting(
        0.7,
        "fusion (paper tau_m): overlap ratio below which a SAM grid segment is kept beside the detector's",
        _UNIT,
    )
    sam_score_range: list[float] = setting(
        [0.88, 1.0], "SAM scores mapped linearly onto segmentation.conf_range", check=_check_score_range
    )
    conf_range: list[float] = setting(
        [0.5, 1.0], "confidence range a segment's rescaled SAM score is mapped to", check=_check_conf_range
    )
    execution_provider: ExecutionProvider = setting("auto", "onnxruntime device for the segmentation models")
    sam_input_size: int = setting(
        1024, "encoder side length, used only when the ONNX input has no fixed size", _int(1)
    )
    points_per_batch: int = setting(
        16, "grid prompts per decoder call (1 when the export fixes the batch to 1)", _int(1)
    )
    stability_score_offset: float = setting(1.0, "SAM: logit offset of the stability score", _NONNEG)
    mask_threshold: float = setting(0.0, "logit threshold that binarises decoder masks", _float())
    detector_input_size: int = setting(
        640, "detector letterbox side, used only when the ONNX input has no fixed size", _int(1)
    )
    detector_score_thresh: float = setting(0.25, "detections scoring lower are dropped", _UNIT)
    detector_nms_thresh: float = setting(0.5, "detector box IoU of non-maximum suppression", _UNIT)
    detector_max_detections: int = setting(100, "at most this many detections per image", _int(1))
    detector_box_format: Literal["xyxy", "cxcywh"] = setting(
        "xyxy", "box layout of exports with separate boxes/scores/labels outputs"
    )
    classical_k: float = setting(
        100.0, "classical segmenter: Felzenszwalb scale (CIELAB dE units); larger -> larger regions", _POS
    )
    classical_min_size: int = setting(
        60, "classical: smallest region in pixels at the working resolution", _int(0)
    )
    classical_max_side: int = setting(
        320, "classical: images are segmented at most this large, labels upsampled", _int(8)
    )
    classical_depth_weight: float = setting(
        300.0, "classical: dE per unit of relative depth discontinuity", _NONNEG
    )
    classical_normal_weight: float = setting(
        100.0, "classical: dE per unit of (1 - cos) between neighbouring normals", _NONNEG
    )
    depth_snap: float = setting(
        0.05,
        "metres: a segment's border pixel whose depth continues a neighbouring segment's surface within "
        "this, and not its own, moves to that segment (segmentation/depth_edges.py); 0 = off",
        _NONNEG,
    )
    simulated_noise: NoiseLevel = setting(
        "default", "simulated SAM from ground-truth instances (synthetic scenes only): how far it errs"
    )
    simulated_seed: int = setting(0, "seed of the simulated SAM's errors", _int(0))


@dataclass
class InitConfig:
    """New Gaussians from a keyframe's unexplained pixels (mapping/init.py; Sec. III-B.2)."""

    pixels_per_gaussian: int = setting(4, "subsampling of back-projected pixels per segment", _int(1))
    opacity: float = setting(
        0.9, "opacity of newly added Gaussians", _float(0.0, 1.0, lo_open=True, hi_open=True)
    )
    dense_below: int = setting(
        16,
        "a segment with fewer grid probes than this gets a probe at every pixel (a book, a light switch: "
        "a few Gaussians could not be told from what surrounds them in later views), which becomes a "
        "Gaussian wherever no Gaussian centre lies within its footprint; the paper takes every pixel",
        _int(0, note="0 = off"),
    )
    alpha_thresh: float = setting(0.5, "rendered alpha below this: unexplained pixel -> new Gaussian", _UNIT)
    depth_margin: float = setting(0.1, "metres; depth this far before the render -> new Gaussian", _NONNEG)


@dataclass
class AssociationConfig:
    """Local 3D optimisation: KNN association of a keyframe's segments with the map, Eq. 5 (local.py)."""

    knn_k: int = setting(
        1,
        "neighbours per probe in the association (the paper gives no k). Each probe votes once, for its "
        "nearest labelled Gaussian: with more, the few boundary matches of a mostly new segment (a door in a "
        "wall) draw votes from every neighbouring object, r(m) >= tau_valid, and the object stays unlabelled "
        "(see mapping/local.py)",
        _int(1),
    )
    knn_radius: float = setting(0.05, "metres; a probe's neighbours lie within this distance", _POS)
    knn_radius_spacing: float = setting(
        0.0,
        "> 0: per-probe KNN radius max(knn_radius, this x probe grid spacing)",
        _float(0.0, note="0 = off"),
    )
    novel_before_ambiguous: bool = setting(
        True,
        "case (iii) before case (i): a segment that hardly overlaps the labelled map (p < tau_p) is novel "
        "whatever its few border matches give r; false = the paper's order (see mapping/local.py)",
    )
    eq5_skip_edges: bool = setting(
        False,
        "Eq. 5 updates come only from probes off their segment's boundary. A table segment's probes around a "
        "cup's base have the cup's Gaussians as nearest match and lower them at every view, which over a "
        "long run lets refinement give the cup the table's label; but the same boundary updates also lower "
        "wrongly labelled rims that refinement then fixes. Measured trade-off: docs/deviations.md",
    )
    tau_valid: float = setting(
        0.25, "paper tau_valid: label ratio r(m) at or above which a segment is ambiguous", _UNIT
    )
    tau_p: float = setting(0.15, "paper tau_p: overlap p(m) below which a segment is a new object", _UNIT)
    fill_unlabeled: bool = setting(True, "unlabelled Gaussians under a labelled segment take its label")


@dataclass
class MergeConfig:
    """Merging duplicate scene labels, beyond the paper (mapping/merge.py)."""

    enabled: bool = setting(
        True,
        "an ambiguous segment that contains two labels' whole visible extent (>= contain each) with SAM "
        "score >= min_score merges them (one object, two labels)",
    )
    contain: float = setting(0.8, "share of each label's visible extent the segment must contain", _UNIT)
    min_score: float = setting(0.95, "SAM score a merging segment needs at least", _UNIT)
    min_part: float = setting(
        0.1,
        "share of a merging segment's mapped Gaussians that each of the two labels must hold (less: a detail "
        "the mask took in, not half of one object)",
        _UNIT,
    )
    novel: bool = setting(
        True,
        "duplicate merging also judges a confident would-be novel segment (p < tau_p): over two mapped "
        "labels (r >= tau_valid) it may merge them (a surface cut in an earlier view, seen further); "
        "holding the whole visible extent of its most matched label, it takes that label",
    )


@dataclass
class OptimizeConfig:
    """Geometry / appearance optimisation per keyframe and pruning (mapping/optimize.py)."""

    iters: int = setting(
        10, "geometry / appearance optimisation steps per keyframe", _int(0, note="0 = no optimisation")
    )
    memory_frames: int = setting(2, "memory frames optimised together with each keyframe", _int(0))
    lr_means: float = setting(
        0.0001,
        "metres per Adam step (the paper gives none; SplaTAM's value). Adam moves every visible centre by "
        "about lr per step whatever its gradient; a larger one moves centres off the surfaces, and the "
        "distance-based association then splits objects into new labels (docs/deviations.md)",
        _NONNEG,
    )
    lr_scales: float = setting(0.001, "learning rate of the scales (paper)", _NONNEG)
    lr_quats: float = setting(
        0.001,
        "learning rate of the rotations; the paper gives none (only scales, opacity, colour): 3DGS's",
        _NONNEG,
    )
    lr_opacities: float = setting(0.05, "learning rate of the opacities (paper)", _NONNEG)
    lr_colors: float = setting(0.0001, "learning rate of the colours (paper)", _NONNEG)
    lambda_c: float = setting(1.0, "paper lambda_c: weight of the colour loss", _NONNEG)
    lambda_d: float = setting(0.1, "paper lambda_d: weight of the depth loss", _NONNEG)
    ssim_lambda: float = setting(0.2, "paper lambda: SSIM share of the colour loss", _UNIT)
    prune_opacity: float = setting(
        0.005,
        "Gaussians less opaque are pruned",
        _float(0.0, 1.0, hi_open=True, note="1 would prune every Gaussian"),
    )
    prune_scale: float = setting(0.5, "metres; Gaussians larger are pruned", _float(0.0, note="0 = off"))


@dataclass
class LongtermConfig:
    """The long-term memory and its Eq. 16 update (mapping/longterm.py; Sec. III-C)."""

    tau_long: float = setting(
        0.5, "paper tau_long: viewpoint-distinctiveness and overlap threshold of the long-term memory", _UNIT
    )
    every: int = setting(6, "keyframes between long-term optimisations", _int(0, note="0 = off"))
    views: int = setting(
        2,
        "memory views judged per long-term optimisation (the paper's N_view, which it does not give): the "
        "step's cost a keyframe is this many views' renders every `every` keyframes once the memory holds "
        "them. Measured effect: docs/consistency.md (cost along a scan)",
        _int(1),
    )
    memory_max: int = setting(64, "long-term memory buffer capacity (frames)", _int(1))
    memory_point_step: int = setting(
        4, "pixel grid step of the memory point clouds (overlap criterion)", _int(1)
    )
    pixel_step: int = setting(2, "pixel grid step of the long-term pixel-to-Gaussian association", _int(1))
    knn_k: int = setting(
        5, "Gaussians associated with each back-projected memory pixel (within knn_radius)", _int(1)
    )
    skip_edges: bool = setting(True, "long-term: leave out pixels on segment / rendered-label boundaries")
    same_class: bool = setting(
        True,
        "beyond the paper (which takes a pixel's nearest Gaussians, whatever their label): a memory pixel is "
        "associated only with Gaussians of the label rendered there, the ones that can have produced it "
        "(near a boundary the nearest include the neighbouring object's). Measured effect: "
        "docs/deviations.md",
    )


@dataclass
class RefineConfig:
    """Global 3D refinement, Algorithm 1 (mapping/refine.py; Sec. III-B.2)."""

    tau_high: float = setting(
        0.7, "paper tau_high: confidence above which a Gaussian's label is reliable", _UNIT
    )
    tau_low: float = setting(0.3, "paper tau_low: confidence below which a label is refined", _UNIT)
    r_search: float = setting(
        0.1, "paper r_search: metres searched for a reliable neighbour in refinement", _POS
    )
    every: int = setting(6, "keyframes between global refinements", _int(0, note="0 = off"))
    cluster_radius: float = setting(0.3, "metres; search radius of the cluster-level refinement", _POS)
    graph_k: int = setting(8, "same-label neighbours linked per Gaussian when building clusters", _int(1))
    unlabeled: bool = setting(False, "individual refinement also labels unlabelled Gaussians (confidence 0)")

    def cross_check(self) -> str | None:
        if not self.tau_low <= self.tau_high:
            return (
                f"mapping.refine.tau_low must be <= mapping.refine.tau_high, got {self.tau_low!r} > "
                f"{self.tau_high!r}"
            )
        return None


@dataclass
class EvidenceConfig:
    """The views' co-segmentation evidence, beyond the paper (mapping/evidence.py, docs/consistency.md)."""

    # enabled: false = the paper's long-term step and Algorithm 1 (with the extensions of the other
    # sections). docs/consistency.md has the model and each threshold's measured effect.
    enabled: bool = setting(
        True,
        "the views' co-segmentation evidence decides merges and splits of labels at the global refinement, "
        "guards Algorithm 1 against relabelling across a clear separation, and lowers disputed Gaussians in "
        "the long-term step; false = the paper's refinement and long-term step",
    )
    cell: float = setting(
        0.05, "metres; the voxel size of the evidence's cells (a part's Gaussians in one voxel)", _POS
    )
    separation: float = setting(
        0.5,
        "two groups of parts merge only when the views separated them in at most this share of the views "
        "that held them firmly together (and never, when no view held them firmly together)",
        _NONNEG,
    )
    split_ratio: float = setting(
        0.5,
        "a group of a part's cells becomes a part of its own when this share of its views across the cut "
        "put it apart from the rest of the part (a group at most a fifth of its part: when about two views "
        "did, however many absorbed it)",
        _float(0.0, 1.0, lo_open=True),
    )
    dispute_views: int = setting(
        2, "judged views a Gaussian needs before the views can dispute its label", _int(1)
    )


@dataclass
class MappingConfig:
    ablation: Literal["naive", "local", "local+global", "full"] = setting(
        "full",
        "which stages run: naive | local (+ local 3D optimisation) | local+global (+ global refinement) "
        "| full (+ long-term optimisation)",
    )
    keyframe_every: int = setting(
        1, "every n-th frame is a keyframe", _int(0, note="0 = by camera motion only")
    )
    keyframe_translation: float = setting(
        0.0, "metres of camera motion since the last keyframe that make one", _float(0.0, note="0 = unused")
    )
    keyframe_rotation_deg: float = setting(
        0.0,
        "degrees of camera rotation since the last keyframe that make a keyframe",
        _float(0.0, note="0 = unused"),
    )
    max_pose_step: float = setting(
        0.5,
        "pose-jump check (mapping/pose_jump.py): the most a camera may move between two consecutive "
        "frames of the folder in metres, times data.stride and the selected frames since the last "
        "accepted one; about twice the largest steps of the sample data (docs/results.md)",
        _float(0.0, note="0 = no limit"),
    )
    max_pose_step_deg: float = setting(
        30.0,
        "pose-jump check: the most a camera may turn between consecutive frames, degrees",
        _float(0.0, note="0 = no limit"),
    )
    on_pose_jump: Literal["warn", "skip", "error"] = setting(
        "warn", "a pose jump: warn (map it anyway) | skip (leave the frame out) | error (stop, map saved)"
    )
    checkpoint_every: int = setting(0, "keyframes between checkpoints", _int(0, note="0 = only at the end"))
    init: InitConfig = section(
        InitConfig, "new Gaussians from a keyframe's unexplained pixels (mapping/init.py; Sec. III-B.2)"
    )
    association: AssociationConfig = section(
        AssociationConfig,
        "local 3D optimisation: KNN association of a keyframe's segments with the map, Eq. 5 (local.py)",
    )
    merge: MergeConfig = section(
        MergeConfig, "merging duplicate scene labels, beyond the paper (mapping/merge.py)"
    )
    optimize: OptimizeConfig = section(
        OptimizeConfig, "geometry / appearance optimisation per keyframe and pruning (mapping/optimize.py)"
    )
    longterm: LongtermConfig = section(
        LongtermConfig, "the long-term memory and its Eq. 16 update (mapping/longterm.py; Sec. III-C)"
    )
    refine: RefineConfig = section(
        RefineConfig, "global 3D refinement, Algorithm 1 (mapping/refine.py; Sec. III-B.2)"
    )
    evidence: EvidenceConfig = section(
        EvidenceConfig,
        "the views' co-segmentation evidence, beyond the paper (mapping/evidence.py, docs/consistency.md)",
    )

    def cross_check(self) -> str | None:
        if self.keyframe_every == 0 and self.keyframe_translation == 0 and self.keyframe_rotation_deg == 0:
            return (
                "mapping.keyframe_every is 0 and so are mapping.keyframe_translation and "
                "mapping.keyframe_rotation_deg: no frame would become a keyframe; set one of them > 0"
            )
        return None


@dataclass
class EndpointConfig:
    """The OpenAI-compatible endpoint that every language-model component of the graph calls (captioner
    ``openai``, relations ``llm``, rooms typer ``llm``, query ``llm``, ``query_embedding: openai``); a
    component's own ``model`` replaces ``model`` here."""

    base_url: str = setting(
        "http://127.0.0.1:8000/v1",
        "the OpenAI-compatible API root, with its version (OpenAI, vLLM, Ollama: /v1)",
    )
    model: str = setting(
        "", "model name every component asks for, unless its own section names one (its model setting)"
    )
    api_key_env: str = setting("OPENAI_API_KEY", _LLM_KEY_DOC)
    timeout_s: float = setting(30.0, "seconds per request", _POS)
    max_retries: int = setting(2, "retries of a failed request", _int(0))


@dataclass
class CaptionerConfig:
    kind: Literal["heuristic", "openai", "groundtruth"] = setting(
        "heuristic",
        "node captions: heuristic (from labels and geometry) | openai (a vision-language model at "
        "an OpenAI-compatible endpoint) | groundtruth (synthetic scenes' instance names)",
    )
    model: str = _component_model("the captions (a vision model)")
    max_tokens: int = _max_tokens(300)
    concurrency: int = setting(4, "parallel per-node caption requests", _int(1))


@dataclass
class RelationsConfig:
    kind: Literal["geometric", "llm"] = setting(
        "geometric",
        "edge relations: geometric (rules on boxes and points) | llm (a language model, with the "
        "geometric rules as per-pair fallback)",
    )
    model: str = _component_model("the relations")
    max_tokens: int = _max_tokens(2000)
    contact_tol: float = setting(0.05, 'metres; vertical gap still counted as contact ("on")', _POS)
    cell_size: float = setting(0.05, "metres; horizontal grid for per-column stacking tests", _POS)
    overlap_ratio: float = setting(
        0.3,
        "shared footprint cells (of the smaller node) for on/above/under/below",
        _float(0.0, 1.0, lo_open=True),
    )
    inside_ratio: float = setting(
        0.8, 'fraction of points inside the other\'s box for "in"', _float(0.0, 1.0, lo_open=True)
    )
    under_gap: float = setting(
        0.5, 'metres; a lower, smaller node closer than this is "under", else "below"', _POS
    )
    attach_elevation: float = setting(
        0.1, 'metres; min height above a wall\'s bottom for "attached to"', _NONNEG
    )


@dataclass
class NodeConfidenceConfig:
    kind: Literal["mean", "clip"] = setting(
        "mean", "node confidence: mean (of its Gaussians' confidences) | clip (image-text similarity)"
    )
    clip_image: str | None = setting(None, "ONNX file of the CLIP image encoder")
    clip_text: str | None = setting(None, "ONNX file of the CLIP text encoder")
    clip_vocab: str | None = setting(
        None, "OpenAI bpe_simple_vocab_16e6.txt(.gz), or HF vocab.json (+ clip_merges)"
    )
    clip_merges: str | None = setting(None, "HF merges.txt, only with a vocab.json")
    clip_image_size: int | None = setting(
        None,
        "the image encoder's input size when its export leaves it dynamic (e.g. 336 for ViT-L/14-336); a "
        "static export's own size is used, and must agree if this is set",
        _int(1, note="null = the export's own, or 224"),
    )
    execution_provider: ExecutionProvider = setting("auto", "onnxruntime device for the CLIP models")


@dataclass
class RoomsConfig:
    enabled: bool = setting(
        True, "segment storeys and rooms from the map and make them graph nodes (objects 'in' rooms)"
    )
    update_every: int = setting(
        4, "keyframes between room updates (rooms also update with every graph update)", _int(1)
    )
    cell_size: float = setting(0.1, "metres per cell of the bird's-eye floor plan", _POS)
    wall_low: float = setting(
        1.0,
        "metres above the floor from which Gaussians are walls in the floor plan (above most furniture)",
        _NONNEG,
    )
    wall_high: float = setting(
        1.9,
        "metres above the floor up to which Gaussians are walls (below door lintels: doorways stay open)",
        _POS,
    )
    door_width: float = setting(
        1.0, "metres: openings up to this wide separate rooms (where free space is wider lies a room)", _POS
    )
    min_room_area: float = setting(
        1.5, "square metres below which a segment is no room (its Gaussians go to the nearest room)", _NONNEG
    )
    storey_height: float = setting(2.0, "metres: the least height between two storeys' floors", _POS)
    max_points: int = setting(
        200_000, "Gaussians a room update reads at most (a fixed random subset of a larger map)", _int(1000)
    )
    assign_radius: float = setting(
        0.5, "metres outside every room's outline beyond which a Gaussian or object is in no room", _NONNEG
    )
    typer: Literal["rule", "llm"] = setting(
        "rule",
        "room types: rule (from the tags of the objects in the room) | llm (a language model at an "
        "OpenAI-compatible endpoint, with the rule as fallback)",
    )
    model: str = _component_model("room types")
    max_tokens: int = _max_tokens(200)

    def cross_check(self) -> str | None:
        if not self.wall_low < self.wall_high:
            return f"graph.rooms.wall_low must be < wall_high, got {self.wall_low!r} >= {self.wall_high!r}"
        return None


@dataclass
class QueryConfig:
    kind: Literal["offline", "llm"] = setting(
        "offline",
        "queries (ogscene3d graph -q, the viewer's Find): offline (a parser of object, relation and room "
        "terms) | llm (a language model at an OpenAI-compatible endpoint picks node ids from a compact "
        "graph; offline when it fails)",
    )
    model: str = _component_model("queries")
    max_tokens: int = _max_tokens(500)
    max_nodes: int = setting(500, "objects sent to the LLM at most (the largest first)", _int(1))


@dataclass
class GraphConfig:
    enabled: bool = setting(
        True, "build the 3D scene graph; false: the graph.* settings are neither used nor checked"
    )
    init_keyframes: int = setting(12, "keyframes before the first graph update", _int(1))
    update_every: int = setting(12, "keyframes between graph updates", _int(1))
    tau_update: float = setting(
        0.3, "paper tau_update: nodes with a lower confidence are re-described", _UNIT
    )
    theta_e: float = setting(0.1, "paper theta_e: metres within which two nodes' points are proximate", _POS)
    tau_e: float = setting(
        0.2,
        "paper tau_e: proximate-point ratio R_ij above which two nodes get an edge",
        _float(0.0, 1.0, hi_open=True),
    )
    min_gaussians: int = setting(20, "labels with fewer Gaussians make no node", _int(1))
    up_axis: Literal["auto"] | list[float] = setting(
        "auto",
        "the world's up direction (on/under relations, floor/wall/ceiling tags): auto (the dataset format's "
        "world up where it defines one, else the cameras' up over the first frames; logged) or a 3-vector",
        check=_check_up_axis,
    )
    edge_voxel: float = setting(
        0.0,
        "a node's points for edges and relations: its Gaussian means thinned to one per voxel of this many "
        "metres, then at most max_points_per_node (seeded random)",
        _float(0.0, note="0 = theta_e / 2"),
    )
    max_points_per_node: int = setting(4096, "at most this many points per node for edges", _int(1))
    support_edges: bool = setting(
        True,
        "extension of Eqs. 20-21 (false = the paper's rule only): a pair is also a candidate when the bottom "
        "(or top) band of one node lies mostly within theta_e of the other (furniture on the floor, lamp on "
        "a ceiling), which R_ij misses because it normalises by the whole node",
    )
    support_band: float = setting(0.05, "metres along up of the bottom / top band", _POS)
    support_ratio: float = setting(
        0.5, "share of the band within theta_e that makes a support edge", _float(0.0, 1.0, lo_open=True)
    )
    background: bool = setting(False, "run graph updates on a worker thread (never blocks mapping)")
    max_masked_views: int = setting(3, "views stored per node for captioning", _int(1))
    crop_max_side: int = setting(
        256, "stored crops are downscaled to this many pixels on the long side", _int(1)
    )
    context_pad: float = setting(
        0.25, "context crop: bbox grown by this fraction of its size on each side", _NONNEG
    )
    min_obs_pixels: int = setting(50, "smaller projections are not stored as observations", _int(0))
    query_embedding: Literal["none", "clip", "openai"] = setting(
        "none",
        "text embedding of `ogscene3d graph -q`: none (words only) | clip | openai (the captioner's "
        "endpoint, /embeddings)",
    )
    embedding_model: str = setting("", "model name for query_embedding=openai")
    query_min_similarity: float = setting(
        0.25, "cosine similarity below which a node does not answer a query", _float(-1.0, 1.0)
    )
    endpoint: EndpointConfig = section(
        EndpointConfig,
        "the OpenAI-compatible endpoint of the captioner, relations, room typer, queries, query embeddings",
    )
    captioner: CaptionerConfig = section(CaptionerConfig, "node captions")
    relations: RelationsConfig = section(RelationsConfig, "edge relations")
    confidence: NodeConfidenceConfig = section(NodeConfidenceConfig, "node confidence")
    rooms: RoomsConfig = section(RoomsConfig, "storeys and rooms")
    query: QueryConfig = section(QueryConfig, "queries over objects, relations and rooms")


@dataclass
class TrackingConfig:
    poses: Literal["gt", "odometry"] = setting(
        "gt", "camera poses: gt (the dataset's) | odometry (estimated by ogscene3d.tracking)"
    )
    max_translation: float = setting(0.3, "metres per frame beyond which a step is implausible", _POS)
    max_rotation_deg: float = setting(30.0, "degrees per frame beyond which a step is implausible", _POS)
    keyframe_every: int = setting(5, "frames between tracking keyframes", _int(1, note="1 = frame-to-frame"))
    method: Literal["auto", "hybrid", "color", "point_to_plane"] = setting(
        "auto",
        "RGB-D odometry (see ogscene3d.tracking): auto (point_to_plane, hybrid if degenerate) | hybrid "
        "| color | point_to_plane",
    )
    min_conditioning: float = setting(
        0.01,
        "auto: keyframe conditioning below which hybrid replaces point_to_plane",
        _float(0.0, 1.0, hi_open=True),
    )
    iterations: list[int] = setting(
        [20, 10, 5], "iterations per pyramid level, coarse to fine", check=_check_iterations
    )
    max_width: int = setting(
        640,
        "track on images downsampled by an integer factor to at most this width",
        _int(0, note="0 = full resolution"),
    )
    depth_min: float = setting(0.1, "metres; nearer depth is not used", _NONNEG)
    depth_max: float = setting(5.0, "metres; farther depth is not used", _POS)
    depth_outlier_trunc: float = setting(0.07, "metres; larger depth residuals are outliers", _POS)
    depth_huber_delta: float = setting(0.05, "metres; Huber delta of the depth residual", _POS)
    intensity_huber_delta: float = setting(0.1, "Huber delta of the intensity residual (intensity in [0, 1])",
                                           _POS)  # fmt: skip
    min_fitness: float = setting(
        0.25, "fraction of pixels with a valid correspondence below which a step fails", _UNIT
    )
    max_inlier_rmse: float = setting(
        0.02, "Open3D residual above which a step fails (typical good steps: docs/results.md)", _POS
    )
    keyframe_fitness: float = setting(
        0.7, "overlap with the keyframe below which the frame becomes one", _UNIT
    )
    keyframe_translation: float = setting(
        0.1, "metres from the keyframe beyond which the frame becomes a keyframe", _POS
    )
    keyframe_rotation_deg: float = setting(
        10.0, "degrees from the keyframe beyond which the frame becomes a keyframe", _POS
    )
    max_lost_frames: int = setting(
        0,
        "consecutive failures after which tracking restarts at the last pose",
        _int(0, note="0 = never restart"),
    )
    max_residual_ratio: float = setting(
        5.0, "re-acquisition fails above this x the recent residuals", _float(0.0, note="0 = off")
    )
    feature_init: bool = setting(True, "ORB + RANSAC initial guess when the motion prior does not converge")
    orb_features: int = setting(500, "ORB features per image", _int(10))
    ransac_threshold: float = setting(0.05, "metres; RANSAC inlier distance", _POS)
    min_feature_inliers: int = setting(20, "RANSAC inliers a feature guess needs", _int(3))

    def cross_check(self) -> str | None:
        if not self.depth_min < self.depth_max:
            return (
                f"tracking.depth_min must be < tracking.depth_max, "
                f"got {self.depth_min!r} >= {self.depth_max!r}"
            )
        return None


@dataclass
class Config:
    """Every setting of a run: :func:`load_config` reads it from YAML, ``ogscene3d config`` lists each key
    with its default, allowed values and doc.

    Attributes:
        device: ``cpu``, ``cuda`` or ``cuda:N``; None: CUDA when available.
        seed: random seed of the run.
        data: the RGB-D input (:class:`DataConfig`).
        synthetic: the procedural scene of ``--synthetic`` (:class:`SyntheticConfig`).
        segmentation: open-set 2D segmentation (:class:`SegmentationConfig`).
        mapping: semantic mapping (:class:`MappingConfig`).
        graph: the 3D scene graph, its LLM endpoint among its sections (:class:`GraphConfig`).
        tracking: camera poses (:class:`TrackingConfig`).
    """

    device: str | None = setting(None, "cpu | cuda | cuda:N; null: CUDA when available")
    seed: int = setting(0, "random seed of the run", _int(0))
    data: DataConfig = section(DataConfig, "the RGB-D input")
    synthetic: SyntheticConfig = section(SyntheticConfig, "the procedural scene of --synthetic")
    segmentation: SegmentationConfig = section(SegmentationConfig, "open-set 2D segmentation (Sec. III-B.1)")
    mapping: MappingConfig = section(MappingConfig, "semantic mapping (Sec. III-B, III-C)")
    graph: GraphConfig = section(GraphConfig, "the 3D scene graph (Sec. III-D)")
    tracking: TrackingConfig = section(TrackingConfig, "camera poses")


# ---------------------------------------------------------------------------------------------- the walker
@dataclass(frozen=True)
class Setting:
    """One leaf setting of :class:`Config`, as ``ogscene3d config`` prints it and :func:`check_config`
    checks it."""

    key: str  # dotted, e.g. "mapping.association.tau_p"
    type: Any
    default: Any
    doc: str
    choices: tuple[Any, ...] | None  # from a Literal type
    range: Range | None  # numbers; ``optional`` set from the type
    check: Callable[[Any], str | None] | None  # numeric lists

    def describe_type(self) -> str:
        if self.choices is not None:
            return " | ".join(str(c) for c in self.choices)
        return _type_name(self.type)


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_name(a) for a in typing.get_args(tp))
    if origin is list:
        return f"list[{', '.join(_type_name(a) for a in typing.get_args(tp))}]"
    if origin is Literal:
        return " | ".join(str(a) for a in typing.get_args(tp))
    if tp is type(None):
        return "null"
    return getattr(tp, "__name__", str(tp))


def _split_optional(tp: Any) -> tuple[Any, bool]:
    """(the type without None, whether None is allowed)."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) < len(typing.get_args(tp)):
            rest: Any = args[0]
            for a in args[1:]:
                rest = rest | a
            return rest, True
    return tp, False


def _is_dataclass_type(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _default_of(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    return f.default_factory()  # type: ignore[misc]


def settings(cls: type = Config, prefix: str = "") -> Iterator[Setting]:
    """Every leaf setting of the config dataclass ``cls`` (default: :class:`Config`), in field order."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        key = prefix + f.name
        if _is_dataclass_type(tp):
            yield from settings(tp, key + ".")
            continue
        base, optional = _split_optional(tp)
        choices = typing.get_args(base) if typing.get_origin(base) is Literal else None
        rng = f.metadata.get("range")
        if rng is not None:
            rng = dataclasses.replace(rng, optional=optional)
        yield Setting(
            key, tp, _default_of(f), f.metadata.get("doc", ""), choices, rng, f.metadata.get("check")
        )


def sections(cls: type = Config, prefix: str = "") -> Iterator[tuple[str, type, str]]:
    """(dotted key, dataclass, doc) of every nested section of ``cls``."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if _is_dataclass_type(hints[f.name]):
            yield prefix + f.name, hints[f.name], f.metadata.get("doc", "")
            yield from sections(hints[f.name], f"{prefix}{f.name}.")


def choices(key: str) -> tuple[Any, ...]:
    """The allowed values of the ``Literal`` setting ``key`` (e.g. ``choices("mapping.ablation")``), for the
    consumers that check a value given to them directly."""
    for s in settings():
        if s.key == key:
            if s.choices is None:
                raise KeyError(f"{key} is not a setting with choices")
            return s.choices
    raise KeyError(key)


def __getattr__(name: str) -> Any:
    """``RANGES`` (dotted key -> :class:`Range`) and ``LIST_CHECKS`` (dotted key -> check): views of the
    field rules, derived on first use (not at import: ``ogscene3d --help`` imports this module)."""
    if name == "RANGES":
        value: Any = {s.key: s.range for s in settings() if s.range is not None}
    elif name == "LIST_CHECKS":
        value = {s.key: s.check for s in settings() if s.check is not None}
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def _problem(key: str, s: Setting, value: Any) -> str | None:
    if s.choices is not None:
        if value is None and _split_optional(s.type)[1]:
            return None
        if value not in s.choices:
            return f"{key} must be one of {list(s.choices)}, got {value!r}"
    if s.range is not None and not s.range.contains(value):
        return f"{key} must be {s.range.describe()}, got {value!r}"
    if s.check is not None:
        problem = s.check(value)
        if problem is not None:
            return f"{key} {problem}, got {value!r}"
    return None


def check_section(obj: Any, prefix: str) -> None:
    """Raise :class:`ConfigError` for the first setting of the config section ``obj`` (e.g. a
    ``TrackingConfig`` with ``prefix="tracking"``) out of its choices, range or list rule, then for its
    cross-field rule (a section's ``cross_check``); nested sections come after their parent's fields."""
    if getattr(obj, "enabled", True) is False:
        return  # a section switched off: its settings are not used
    nested = []
    for s in settings(type(obj), f"{prefix}." if prefix else ""):
        name = s.key[len(prefix) + 1 :] if prefix else s.key
        if "." in name:
            continue  # a nested section's field: checked below, with its own cross-field rule
        problem = _problem(s.key, s, getattr(obj, name))
        if problem is not None:
            raise ConfigError(problem)
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            nested.append((f"{prefix}.{f.name}" if prefix else f.name, value))
    cross = getattr(obj, "cross_check", None)
    problem = cross() if cross is not None else None
    if problem is not None:
        raise ConfigError(problem)
    for key, value in nested:
        check_section(value, key)


def check_config(cfg: Config) -> None:
    """Raise :class:`ConfigError` naming the key, the value and what is allowed for the first setting of
    ``cfg`` out of its rules (a ``Literal``'s choices, a number's range, a list's check, each written on the
    field), then the sections' cross-field rules.

    ``load_config`` calls it, and so does ``Mapper`` (a ``Config()`` built and changed in Python)."""
    check_section(cfg, "")


def _coerce(value: Any, tp: Any, key: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, key)
            except ConfigError as e:
                errors.append(str(e))
        raise ConfigError(errors[0] if errors else f"{key}: bad value {value!r}")
    if (
        origin is Literal
    ):  # the type of its choices; the choice itself is check_config's (a section may be off)
        return _coerce(value, type(typing.get_args(tp)[0]), key)
    if origin is list:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        (inner,) = typing.get_args(tp) or (Any,)
        return [_coerce(v, inner, f"{key}[{i}]") for i, v in enumerate(value)]
    if _is_dataclass_type(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a mapping, got {value!r}")
        return _build(tp, value, key)
    if tp is Any:
        return value
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{key}: expected true/false, got {value!r}")
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    return value


# Settings that were removed, which the config.yaml of a run made before still holds: dropped on reading
# (with a note of what replaced them) so that such a run can still be resumed and evaluated.
RETIRED: dict[str, str] = {
    "graph.captioner.backoff_s": "the openai client's own retry backoff (it honours Retry-After)",
    "graph.relations.backoff_s": "the openai client's own retry backoff (it honours Retry-After)",
    **{
        f"mapping.{name}": "mapping.evidence, one evidence model (docs/consistency.md)"
        for name in (
            "evidence_split", "evidence_wrong", "evidence_wrong_views", "evidence_split_conf",
            "evidence_partition", "evidence_partition_apart", "evidence_partition_conf",
            "evidence_partition_min", "evidence_revisit", "evidence_merge", "evidence_protect",
            "evidence_protect_views", "evidence_min_views", "evidence_quick_split", "evidence_quick_merge",
            "evidence_confident_score", "evidence_merge_ratio", "evidence_min_group", "evidence_veto",
            "evidence_apart_ratio",
        )
    },
}


# Settings that moved: read at their new key (with one notice naming them) so that the YAML files and run
# folders written before still load. Several old keys can move to one new key (each LLM component of the
# graph had its own endpoint settings): set to different values, they conflict, unless the new key is given.
_ENDPOINT_KEYS = ("base_url", "api_key_env", "timeout_s", "max_retries")
# The flat mapping settings before they were grouped by the component that owns each (mapping.<old> ->
# mapping.<section>.<new>); a run folder's config.yaml written before still loads, and --resume goes on.
_MAPPING_SECTIONS: dict[str, dict[str, str]] = {
    "init": {
        "init_opacity": "opacity",
        "init_dense_below": "dense_below",
        "init_alpha_thresh": "alpha_thresh",
        "init_depth_margin": "depth_margin",
        "pixels_per_gaussian": "pixels_per_gaussian",
    },
    "association": {
        "knn_k": "knn_k",
        "knn_radius": "knn_radius",
        "knn_radius_spacing": "knn_radius_spacing",
        "novel_before_ambiguous": "novel_before_ambiguous",
        "eq5_skip_edges": "eq5_skip_edges",
        "tau_valid": "tau_valid",
        "tau_p": "tau_p",
        "fill_unlabeled": "fill_unlabeled",
    },
    "merge": {
        "merge_duplicates": "enabled",
        "merge_contain": "contain",
        "merge_min_score": "min_score",
        "merge_min_part": "min_part",
        "merge_novel": "novel",
    },
    "optimize": {
        "opt_iters": "iters",
        "opt_memory_frames": "memory_frames",
        "lr_means": "lr_means",
        "lr_scales": "lr_scales",
        "lr_quats": "lr_quats",
        "lr_opacities": "lr_opacities",
        "lr_colors": "lr_colors",
        "lambda_c": "lambda_c",
        "lambda_d": "lambda_d",
        "ssim_lambda": "ssim_lambda",
        "prune_opacity": "prune_opacity",
        "prune_scale": "prune_scale",
    },
    "longterm": {
        "longterm_every": "every",
        "longterm_views": "views",
        "longterm_pixel_step": "pixel_step",
        "longterm_knn_k": "knn_k",
        "longterm_skip_edges": "skip_edges",
        "longterm_same_class": "same_class",
        "tau_long": "tau_long",
        "memory_max": "memory_max",
        "memory_point_step": "memory_point_step",
    },
    "refine": {
        "refine_every": "every",
        "refine_cluster_radius": "cluster_radius",
        "refine_graph_k": "graph_k",
        "refine_unlabeled": "unlabeled",
        "tau_high": "tau_high",
        "tau_low": "tau_low",
        "r_search": "r_search",
    },
    "evidence": {
        "evidence": "enabled",
        "evidence_cell": "cell",
        "evidence_separation": "separation",
        "evidence_split_ratio": "split_ratio",
        "evidence_dispute_views": "dispute_views",
    },
}
MOVED: dict[str, str] = {
    **{
        f"graph.{part}.{key}": f"graph.endpoint.{key}"
        for part in ("captioner", "relations", "rooms", "query")
        for key in _ENDPOINT_KEYS
    },
    **{
        f"mapping.{old}": f"mapping.{section}.{new}"
        for section, names in _MAPPING_SECTIONS.items()
        for old, new in names.items()
    },
}


def _pop_key(values: dict, key: str) -> tuple[dict, Any]:
    """``values`` without the dotted ``key`` (a copy where it changes) and the value it held
    (``dataclasses.MISSING``: none)."""
    head, _, rest = key.partition(".")
    if head not in values:
        return values, dataclasses.MISSING
    if not rest:
        return {k: v for k, v in values.items() if k != head}, values[head]
    if not isinstance(values[head], dict):
        return values, dataclasses.MISSING
    inner, value = _pop_key(values[head], rest)
    return {**values, head: inner}, value


def _put_key(values: dict, key: str, value: Any) -> dict:
    head, _, rest = key.partition(".")
    if not rest:
        return {**values, head: value}
    inner = values.get(head)
    return {**values, head: _put_key(inner if isinstance(inner, dict) else {}, rest, value)}


def _move_keys(values: dict) -> dict:
    """``values`` (a config as nested dicts) with the keys of :data:`MOVED` at their new place."""
    found: dict[str, list[tuple[str, Any]]] = {}
    for old, new in MOVED.items():
        held, value = _pop_key(values, old)
        if value is dataclasses.MISSING or isinstance(value, dict):
            continue  # absent, or today's section of that name (mapping.evidence)
        values = held
        found.setdefault(new, []).append((old, value))
    if not found:
        return values
    defaults = {s.key: s.default for s in settings() if s.key in found}
    for new, olds in found.items():
        values, given = _pop_key(values, new)
        if given is dataclasses.MISSING:
            # the old keys that say something beyond the default must agree
            said: list[tuple[str, Any]] = []
            for k, v in olds:
                if v != defaults[new] and all(v != w for _, w in said):
                    said.append((k, v))
            if len(said) > 1:
                raise ConfigError(
                    f"{' and '.join(f'{k}={v!r}' for k, v in said)} differ, but one endpoint "
                    f"({new.rpartition('.')[0]}) now serves them all: set {new} instead"
                )
            given = said[0][1] if said else defaults[new]
        values = _put_key(values, new, given)
    # one line: the old keys by section (graph.captioner.{base_url,timeout_s}), then where they went
    by_section: dict[str, list[str]] = {}
    for olds in found.values():
        for k, _ in olds:
            head, _, name = k.rpartition(".")
            by_section.setdefault(head, []).append(name)
    old_keys = ", ".join(
        f"{h}.{{{','.join(n)}}}" if len(n) > 1 else f"{h}.{n[0]}" for h, n in by_section.items()
    )
    targets = ", ".join(dict.fromkeys(new.rpartition(".")[0] for new in found))
    logging.getLogger(__name__).info(
        "config keys %s moved to %s (read there; update the file)", old_keys, targets
    )
    return values


def _old_switches(values: dict) -> dict:
    """``values`` with each moved switch that became a section's ``enabled`` (``mapping.evidence: false``)
    written as that section (``mapping.evidence: {enabled: false}``), so that an override of the old key
    merges with the section's other settings instead of replacing them (one notice per key moved)."""
    for old, new in MOVED.items():
        if new != f"{old}.enabled":
            continue
        held, value = _pop_key(values, old)
        if value is not dataclasses.MISSING and not isinstance(value, dict):
            values = _put_key(held, old, {"enabled": value})
            logging.getLogger(__name__).info(
                "config key %s moved to %s (read there; update the file)", old, new
            )
    return values


def _build(cls: type, values: dict, prefix: str = "") -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for name in [n for n in values if n not in names and f"{prefix}.{n}".lstrip(".") in RETIRED]:
        key = f"{prefix}.{name}".lstrip(".")
        logging.getLogger(__name__).info("config key %s is no longer used (now: %s)", key, RETIRED[key])
        values = {k: v for k, v in values.items() if k != name}
    unknown = sorted(set(values) - names)
    if unknown:
        where = prefix or "top level"
        raise ConfigError(f"unknown config key(s) {unknown} in {where}; known: {sorted(names)}")
    kwargs = {}
    for name, value in values.items():
        kwargs[name] = _coerce(value, hints[name], f"{prefix}.{name}" if prefix else name)
    return cls(**kwargs)


def _merge(base: dict, update: dict) -> dict:
    out = dict(base)
    for k, v in update.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def parse_override(text: str) -> dict:
    """``"mapping.refine.tau_low=0.2"`` -> ``{"mapping": {"refine": {"tau_low": 0.2}}}`` (the value is parsed
    as YAML)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r} is not of the form key=value")
    key, raw = text.split("=", 1)
    value = yaml.safe_load(raw) if raw.strip() else None
    out: dict = {}
    node = out
    parts = key.strip().split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value
    return out


def config_from_dict(values: dict) -> Config:
    """A :class:`Config` from nested dicts (a YAML file's), moved keys read at their new place."""
    return _build(Config, _move_keys(values))


def section_values(section: Any, names: Iterable[str], prefix: str = "") -> dict[str, Any]:
    """A component's keyword arguments from its config section: ``{name: section.<prefix><name>}``.

    Args:
        section: the config section (e.g. ``cfg.segmentation``).
        names: the component's parameters that the section holds.
        prefix: what the section's keys add to the parameter names (``"detector_"``), if anything.

    Returns:
        The keyword arguments, in the order of ``names``.
    """
    return {name: getattr(section, prefix + name) for name in names}


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """Load a YAML config and apply ``key=value`` overrides, then check every setting.

    Keys that moved (:data:`MOVED`) are read at their new place, with one notice.

    Args:
        path: a YAML file, a bare name such as ``"replica"`` (the config shipped with the package), or None
            for all defaults.
        overrides: ``key=value`` strings (the value is parsed as YAML), e.g. ``"mapping.refine.tau_low=0.2"``.

    Returns:
        The checked config.

    Raises:
        ConfigError: a missing or unreadable file, an unknown key, or a value outside its rules (the message
            names the key, the value and what is allowed).
    """
    values: dict = {}
    if path is not None:
        p = resolve_config_path(path)
        if not p.is_file():
            shipped = ", ".join(shipped_configs())
            raise ConfigError(f"config file {str(p)!r} does not exist (shipped configs, by name: {shipped})")
        try:
            text = p.read_text(encoding="utf-8")
        except UnicodeDecodeError as e:
            raise ConfigError(
                f"config file {str(p)!r} is not UTF-8 text (byte {e.start} is {e.object[e.start]:#04x}); "
                "save it as UTF-8"
            ) from e
        try:
            loaded = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise ConfigError(f"config file {str(p)!r} is not valid YAML: {e}") from e
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"config file {str(p)!r} must hold a mapping at the top level")
        values = loaded
    for ov in overrides or []:
        values = _merge(_old_switches(values), _old_switches(parse_override(ov)))
    cfg = config_from_dict(values)
    check_config(cfg)
    return cfg


def config_to_dict(cfg: Any) -> dict:
    return dataclasses.asdict(cfg)


def save_config(cfg: Config, path: str | Path) -> None:
    """Write ``cfg`` as YAML (``load_config`` reads it back), atomically."""
    atomic_write_text(path, yaml.safe_dump(config_to_dict(cfg), sort_keys=False))
