"""Run configuration: nested dataclasses loaded from YAML (``yaml.safe_load``) with ``key=value`` overrides.

Every section has the paper's defaults (Sec. IV-A.4); ``configs/*.yaml`` only state what differs per dataset.
Unknown keys are errors, so a typo in a YAML file never silently falls back to a default.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .atomic import atomic_write_text
from .errors import ConfigError


@dataclass
class DataConfig:
    # auto | replica | semantic_nerf | scannet | tum | sevenscenes | labelfusion | synthetic
    kind: str = "auto"
    path: str | None = None
    segments_dir: str | None = None
    stride: int = 1
    start: int = 0
    max_frames: int | None = None
    depth_scale: float | None = None  # raw depth units per metre; None = the dataset's own
    # auto (the layout's) | linear (raw / scale) | shift3 (APC: (raw >> 3) / scale)
    depth_format: str = "auto"
    intrinsics: list[float] | None = None  # [fx, fy, cx, cy] overriding the dataset's
    # Where the intrinsics read (files, data.intrinsics) put the centre of pixel (0, 0): auto (the layout's:
    # integer for ScanNet, TUM, 7-Scenes, label-fusion; half for Replica, synthetic, Semantic-NeRF) |
    # integer (OpenCV, ROS calibrations: (0, 0)) | half (COLMAP, gsplat: (0.5, 0.5), ogscene3d's own K).
    # Integer values are shifted by +0.5 on reading.
    pixel_centers: str = "auto"
    min_depth: float = 0.0
    max_depth: float = 0.0  # 0 = no limit
    on_bad_frame: str = "error"  # error | skip


@dataclass
class SyntheticConfig:
    seed: int = 0
    frames: int = 60
    width: int = 160
    height: int = 120
    noise: str = "default"  # none | low | default | high (SAM-like) | legacy-low | legacy-default | ...-high
    depth_noise: float = 0.0  # std in metres
    pose_noise: float = 0.0  # std of translation in metres


@dataclass
class SegmentationConfig:
    # Used for frames that carry no precomputed segments: precomputed (-> classical, with a warning) |
    # sam | sam+detector | classical | simulated | none (map geometry only, every Gaussian unlabelled)
    backend: str = "precomputed"
    sam_encoder: str | None = None
    sam_decoder: str | None = None
    detector: str | None = None
    detector_classes: list[str] = field(default_factory=list)
    points_per_side: int = 32
    pred_iou_thresh: float = 0.88
    stability_score_thresh: float = 0.92
    box_nms_thresh: float = 0.7
    min_region_area: int = 100
    tau_m: float = 0.7  # fusion: overlap ratio below which a SAM grid segment is kept
    sam_score_range: list[float] = field(default_factory=lambda: [0.88, 1.0])
    conf_range: list[float] = field(default_factory=lambda: [0.5, 1.0])
    execution_provider: str = "auto"  # auto | cpu | cuda
    # SAM automatic mask generation (paper Sec. III-B.1); defaults follow segment-anything's generator.
    sam_input_size: int = 1024  # encoder side length, used only when the ONNX input has no fixed size
    points_per_batch: int = 16  # grid prompts per decoder call (1 when the export fixes the batch to 1)
    stability_score_offset: float = 1.0
    mask_threshold: float = 0.0  # logit threshold that binarises decoder masks
    # open-vocabulary detector (YOLO-World style export)
    detector_input_size: int = 640  # letterbox side, used only when the ONNX input has no fixed size
    detector_score_thresh: float = 0.25
    detector_nms_thresh: float = 0.5
    detector_max_detections: int = 100
    detector_box_format: str = "xyxy"  # xyxy | cxcywh, for exports with separate boxes/scores/labels outputs
    # classical (weight-free) fallback: graph segmentation on colour, depth and normals
    classical_k: float = 100.0  # Felzenszwalb scale (CIELAB ΔE units): larger -> larger regions
    classical_min_size: int = 60  # pixels at the working resolution
    classical_max_side: int = 320  # images are segmented at most this large, labels upsampled
    classical_depth_weight: float = 300.0  # ΔE per unit of relative depth discontinuity
    classical_normal_weight: float = 100.0  # ΔE per unit of (1 - cos) between neighbouring normals
    # simulated SAM from ground-truth instances (synthetic scenes only)
    simulated_noise: str = "default"  # as synthetic.noise (segmentation/simulated.py NOISE_LEVELS)
    simulated_seed: int = 0


@dataclass
class MappingConfig:
    ablation: str = "full"  # naive | local | local+global | full
    keyframe_every: int = 1
    keyframe_translation: float = 0.0  # metres; 0 = unused
    keyframe_rotation_deg: float = 0.0  # 0 = unused
    # Pose-jump check (mapping/pose_jump.py): the most a camera may move between two consecutive frames of
    # the folder, times data.stride and the selected frames since the last accepted one; 0 = no limit. About
    # twice the largest steps of the samples here (7-Scenes every 20th frame: 0.26 m, 13.6 deg).
    max_pose_step: float = 0.5  # metres
    max_pose_step_deg: float = 30.0
    on_pose_jump: str = "warn"  # warn (map it anyway) | skip (leave the frame out) | error (stop, map saved)
    pixels_per_gaussian: int = 4  # subsampling of back-projected pixels per segment
    # Neighbours per probe in the association (the paper gives no k). Each probe votes once, for its nearest
    # labelled Gaussian: with k=5 the few boundary matches of a mostly new segment (a door in a wall) drew
    # votes from every neighbouring object, r(m) >= tau_valid, and the object stayed unlabelled (see local.py)
    knn_k: int = 1
    knn_radius: float = 0.05
    # case (iii) before case (i): a segment that hardly overlaps the labelled map (p < tau_p) is novel
    # whatever its few border matches give r; false = the paper's order (see mapping/local.py)
    novel_before_ambiguous: bool = True
    knn_radius_spacing: float = 0.0  # >0: per-probe KNN radius max(knn_radius, this x probe grid spacing)
    # true: Eq. 5 updates come only from probes off their segment's boundary. A table segment's probes around
    # a cup's base have the cup's Gaussians as nearest match and lower them at every view, which over a long
    # run lets refinement give the cup the table's label; but the same boundary updates also lower wrongly
    # labelled rims that refinement then fixes. Measured trade-off in README ("Ablation"); off by default.
    eq5_skip_edges: bool = False
    tau_valid: float = 0.25
    tau_p: float = 0.15
    tau_high: float = 0.7
    tau_low: float = 0.3
    r_search: float = 0.1
    tau_long: float = 0.5
    refine_every: int = 6
    longterm_every: int = 6
    longterm_views: int = 4
    opt_iters: int = 10
    opt_memory_frames: int = 2
    # metres per Adam step (the paper gives none; SplaTAM's value). Adam moves every visible centre by about
    # lr per step whatever its gradient; at 1e-3 a 240-frame synthetic stream left 7-9% of the centres more
    # than 5 cm off the surfaces, and the distance-based association then split objects into new labels
    lr_means: float = 0.0001
    lr_scales: float = 0.001
    lr_quats: float = 0.001  # the paper gives none (only scales, opacity, colour); 3DGS's value
    lr_opacities: float = 0.05
    lr_colors: float = 0.0001
    lambda_c: float = 1.0
    lambda_d: float = 0.1
    ssim_lambda: float = 0.2
    prune_opacity: float = 0.005
    prune_scale: float = 0.5
    checkpoint_every: int = 0  # keyframes; 0 = only at the end
    init_opacity: float = 0.9  # opacity of newly added Gaussians
    init_alpha_thresh: float = 0.5  # a pixel rendered with less alpha is unexplained -> new Gaussian
    init_depth_margin: float = 0.1  # metres; observed depth this far in front of the render -> new Gaussian
    refine_cluster_radius: float = 0.3  # metres; search radius of the cluster-level refinement
    refine_graph_k: int = 8  # same-label neighbours linked per Gaussian when building clusters
    memory_max: int = 64  # long-term memory buffer capacity (frames)
    memory_point_step: int = 4  # pixel grid step of the memory point clouds (overlap criterion)
    longterm_pixel_step: int = 2  # pixel grid step of the long-term pixel-to-Gaussian association
    longterm_knn_k: int = 5  # Gaussians associated with each back-projected memory pixel (within knn_radius)
    longterm_skip_edges: bool = True  # long-term: leave out pixels on segment / rendered-label boundaries
    # Beyond the paper (which takes a pixel's nearest Gaussians, whatever their label): a memory pixel is
    # associated only with Gaussians of the label rendered there, the ones that can have produced it (near a
    # boundary the nearest include the neighbouring object's). Synthetic seeds 0-2: mIoU 70.25 vs 69.75.
    longterm_same_class: bool = True
    fill_unlabeled: bool = True  # unlabeled Gaussians under a labeled segment take its label
    refine_unlabeled: bool = False  # individual refinement also labels unlabeled Gaussians (confidence 0)
    # Beyond the paper (mapping/merge.py): an ambiguous segment that contains two labels' whole visible
    # extent (>= merge_contain each) with SAM score >= merge_min_score merges them (one object, two labels).
    merge_duplicates: bool = True
    merge_contain: float = 0.8
    merge_min_score: float = 0.95
    # --- i26: multi-view co-segmentation evidence (mapping/evidence.py), beyond the paper; all three false =
    # the paper's long-term step and Algorithm 1 (with the extensions above). Merge and veto are off by
    # default: over 10 synthetic seeds they did not help (docs/consistency.md)
    evidence_split: bool = True  # bool: long-term lowers the confidence of Gaussians that most views show as
    #   a separate part of their label; refinement splits such low-confidence parts off as new labels
    evidence_merge: bool = False  # bool: refinement merges labels that most views show in one segment
    evidence_min_views: int = 3  # int >= 1: views a Gaussian / a label pair needs before it is decided
    evidence_split_ratio: float = 0.5  # float in (0, 1]: share of split views that marks a Gaussian
    evidence_merge_ratio: float = 0.7  # float in (0, 1]: share of one-segment views that merges two labels
    evidence_min_group: int = 3  # int >= 1: Gaussians a separate part needs (per view, and to be split off)
    evidence_veto: bool = False  # bool: undo Alg. 1 relabellings between labels that most views show apart
    evidence_apart_ratio: float = 0.3  # float in [0, 1]: labels in one segment in fewer views are apart


@dataclass
class CaptionerConfig:
    kind: str = "heuristic"  # heuristic | openai | groundtruth
    base_url: str = "http://127.0.0.1:8000/v1"
    model: str = ""
    api_key_env: str = "OPENAI_API_KEY"
    timeout_s: float = 30.0
    max_retries: int = 2
    backoff_s: float = 1.0  # first retry delay; doubles per retry
    max_tokens: int = 300
    concurrency: int = 4  # parallel per-node caption requests


@dataclass
class RelationsConfig:
    kind: str = "geometric"  # geometric | llm
    base_url: str = "http://127.0.0.1:8000/v1"
    model: str = ""
    api_key_env: str = "OPENAI_API_KEY"
    timeout_s: float = 30.0
    max_retries: int = 2
    backoff_s: float = 1.0
    max_tokens: int = 2000
    # geometric predictor (metres / ratios); also the LLM's per-pair fallback
    contact_tol: float = 0.05  # vertical gap still counted as contact ("on")
    cell_size: float = 0.05  # horizontal grid for per-column stacking tests
    overlap_ratio: float = 0.3  # shared footprint cells (of the smaller node) for on/above/under/below
    inside_ratio: float = 0.8  # fraction of points inside the other's box for "in"
    under_gap: float = 0.5  # lower, smaller node closer than this: "under", else "below"
    attach_elevation: float = 0.1  # min height above a wall's bottom for "attached to"


@dataclass
class NodeConfidenceConfig:
    kind: str = "mean"  # mean | clip
    clip_image: str | None = None
    clip_text: str | None = None
    clip_vocab: str | None = None  # OpenAI bpe_simple_vocab_16e6.txt(.gz), or HF vocab.json (+ clip_merges)
    clip_merges: str | None = None  # HF merges.txt, only with a vocab.json
    # the image encoder's input size when its export leaves it dynamic (e.g. 336 for ViT-L/14-336); a static
    # export's own size is used, and must agree if this is set; None: 224 for a dynamic one
    clip_image_size: int | None = None
    execution_provider: str = "auto"  # auto | cpu | cuda


@dataclass
class GraphConfig:
    enabled: bool = True
    init_keyframes: int = 12
    update_every: int = 12
    tau_update: float = 0.3
    theta_e: float = 0.1
    tau_e: float = 0.2
    min_gaussians: int = 20
    up_axis: list[float] = field(default_factory=lambda: [0.0, -1.0, 0.0])
    # A node's points for edges and relations: its Gaussian means thinned to one per voxel of edge_voxel
    # metres (0 = theta_e / 2, spatially uniform), then at most max_points_per_node (seeded random).
    edge_voxel: float = 0.0
    max_points_per_node: int = 4096
    # Extension of Eqs. 20-21 (false = the paper's rule only): a pair is also a candidate when the bottom
    # (or top) band of one node lies mostly within theta_e of the other (furniture on the floor, lamp on a
    # ceiling), which R_ij misses because it normalises by the whole node.
    support_edges: bool = True
    support_band: float = 0.05  # metres along up
    support_ratio: float = 0.5
    background: bool = False  # run graph updates on a worker thread (never blocks mapping)
    max_masked_views: int = 3
    crop_max_side: int = 256  # stored crops are downscaled to this many pixels on the long side
    context_pad: float = 0.25  # context crop: bbox grown by this fraction of its size on each side
    min_obs_pixels: int = 50  # smaller projections are not stored as observations
    query_embedding: str = "none"  # none | clip | openai (the captioner's endpoint, /embeddings)
    embedding_model: str = ""
    query_min_similarity: float = 0.25
    captioner: CaptionerConfig = field(default_factory=CaptionerConfig)
    relations: RelationsConfig = field(default_factory=RelationsConfig)
    confidence: NodeConfidenceConfig = field(default_factory=NodeConfidenceConfig)


@dataclass
class TrackingConfig:
    poses: str = "gt"  # gt | odometry
    max_translation: float = 0.3  # metres per frame beyond which a step is implausible
    max_rotation_deg: float = 30.0
    keyframe_every: int = 5
    # RGB-D odometry (ogscene3d.tracking); see that module's docstring for the meaning of each field.
    method: str = "auto"  # auto (point_to_plane, hybrid if degenerate) | hybrid | color | point_to_plane
    min_conditioning: float = 0.01  # auto: keyframe conditioning below which hybrid replaces point_to_plane
    iterations: list[int] = field(default_factory=lambda: [20, 10, 5])  # per pyramid level, coarse to fine
    max_width: int = 640  # track on images downsampled by an integer factor to at most this width; 0 = full
    depth_min: float = 0.1  # metres
    depth_max: float = 5.0  # metres
    depth_outlier_trunc: float = 0.07  # metres
    depth_huber_delta: float = 0.05  # metres
    intensity_huber_delta: float = 0.1  # intensity in [0, 1]
    min_fitness: float = 0.25  # fraction of pixels with a valid correspondence below which a step fails
    max_inlier_rmse: float = 0.02  # Open3D residual above which a step fails (good steps: 1e-5..4e-3)
    keyframe_fitness: float = 0.7  # overlap with the keyframe below which the frame becomes a keyframe
    keyframe_translation: float = 0.1  # metres from the keyframe beyond which the frame becomes a keyframe
    keyframe_rotation_deg: float = 10.0
    max_lost_frames: int = 0  # consecutive failures after which tracking restarts at the last pose; 0 = never
    max_residual_ratio: float = 5.0  # re-acquisition fails above this x the recent residuals; 0 = off
    feature_init: bool = True  # ORB + RANSAC initial guess when the motion prior does not converge
    orb_features: int = 500
    ransac_threshold: float = 0.05  # metres
    min_feature_inliers: int = 20


@dataclass
class Config:
    device: str | None = None
    seed: int = 0
    data: DataConfig = field(default_factory=DataConfig)
    synthetic: SyntheticConfig = field(default_factory=SyntheticConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    graph: GraphConfig = field(default_factory=GraphConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)


# --------------------------------------------------------------------------------------------------- ranges
@dataclass(frozen=True)
class Range:
    """The allowed values of one numeric setting: ``lo``/``hi`` (None: unbounded), open or closed. Floats must
    also be finite (NaN and inf fail every float setting); ``optional`` settings also take None."""

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


def _int(lo: int, hi: int | None = None, note: str = "", optional: bool = False) -> Range:
    return Range(lo, hi, integer=True, optional=optional, note=note)


def _float(
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    hi_open: bool = False,
    note: str = "",
    optional: bool = False,
) -> Range:
    return Range(lo, hi, lo_open, hi_open, optional=optional, note=note)


_UNIT = _float(0.0, 1.0)  # probabilities, ratios, thresholds on scores
_NONNEG = _float(0.0)
_POS = _float(0.0, lo_open=True)
_LLM = {  # graph.captioner and graph.relations: the OpenAI-compatible client's settings
    "timeout_s": _POS,
    "max_retries": _int(0),
    "backoff_s": _NONNEG,
    "max_tokens": _int(0, note="0 = no max_tokens in the request"),
}

# Every int / float setting of Config, by dotted key. Each range follows what the setting's consumer does
# with it: where 0 means "off" or "no limit" it stays allowed. tests/test_config_ranges.py checks that every
# numeric field has an entry.
RANGES: dict[str, Range] = {
    "seed": _int(0),
    "data.stride": _int(1),
    "data.start": _int(0),
    "data.max_frames": _int(1, optional=True, note="null = all frames"),
    "data.depth_scale": _float(0.0, lo_open=True, optional=True, note="null = the dataset's own"),
    "data.min_depth": _float(0.0, note="0 = the dataset's own"),
    "data.max_depth": _float(0.0, note="0 = no limit"),
    "synthetic.seed": _int(0),
    "synthetic.frames": _int(1),
    "synthetic.width": _int(8),
    "synthetic.height": _int(8),
    "synthetic.depth_noise": _NONNEG,
    "synthetic.pose_noise": _NONNEG,
    "segmentation.points_per_side": _int(1),
    "segmentation.pred_iou_thresh": _UNIT,
    "segmentation.stability_score_thresh": _UNIT,
    "segmentation.box_nms_thresh": _UNIT,
    "segmentation.min_region_area": _int(0, note="0 = no clean-up"),
    "segmentation.tau_m": _UNIT,
    "segmentation.sam_input_size": _int(1),
    "segmentation.points_per_batch": _int(1),
    "segmentation.stability_score_offset": _NONNEG,
    "segmentation.mask_threshold": _float(),
    "segmentation.detector_input_size": _int(1),
    "segmentation.detector_score_thresh": _UNIT,
    "segmentation.detector_nms_thresh": _UNIT,
    "segmentation.detector_max_detections": _int(1),
    "segmentation.classical_k": _POS,
    "segmentation.classical_min_size": _int(0),
    "segmentation.classical_max_side": _int(8),
    "segmentation.classical_depth_weight": _NONNEG,
    "segmentation.classical_normal_weight": _NONNEG,
    "segmentation.simulated_seed": _int(0),
    "mapping.keyframe_every": _int(0, note="0 = by camera motion only"),
    "mapping.keyframe_translation": _float(0.0, note="0 = unused"),
    "mapping.keyframe_rotation_deg": _float(0.0, note="0 = unused"),
    "mapping.max_pose_step": _float(0.0, note="0 = no limit"),
    "mapping.max_pose_step_deg": _float(0.0, note="0 = no limit"),
    "mapping.pixels_per_gaussian": _int(1),
    "mapping.knn_k": _int(1),
    "mapping.knn_radius": _POS,
    "mapping.knn_radius_spacing": _float(0.0, note="0 = off"),
    "mapping.tau_valid": _UNIT,
    "mapping.tau_p": _UNIT,
    "mapping.tau_high": _UNIT,
    "mapping.tau_low": _UNIT,
    "mapping.r_search": _POS,
    "mapping.tau_long": _UNIT,
    "mapping.refine_every": _int(0, note="0 = off"),
    "mapping.longterm_every": _int(0, note="0 = off"),
    "mapping.longterm_views": _int(1),
    "mapping.opt_iters": _int(0, note="0 = no optimisation"),
    "mapping.opt_memory_frames": _int(0),
    "mapping.lr_means": _NONNEG,
    "mapping.lr_scales": _NONNEG,
    "mapping.lr_quats": _NONNEG,
    "mapping.lr_opacities": _NONNEG,
    "mapping.lr_colors": _NONNEG,
    "mapping.lambda_c": _NONNEG,
    "mapping.lambda_d": _NONNEG,
    "mapping.ssim_lambda": _UNIT,
    "mapping.prune_opacity": _float(0.0, 1.0, hi_open=True, note="1 would prune every Gaussian"),
    "mapping.prune_scale": _float(0.0, note="0 = off"),
    "mapping.checkpoint_every": _int(0, note="0 = only at the end"),
    "mapping.init_opacity": _float(0.0, 1.0, lo_open=True, hi_open=True),
    "mapping.init_alpha_thresh": _UNIT,
    "mapping.init_depth_margin": _NONNEG,
    "mapping.refine_cluster_radius": _POS,
    "mapping.refine_graph_k": _int(1),
    "mapping.memory_max": _int(1),
    "mapping.memory_point_step": _int(1),
    "mapping.longterm_pixel_step": _int(1),
    "mapping.longterm_knn_k": _int(1),
    "mapping.merge_contain": _UNIT,
    "mapping.merge_min_score": _UNIT,
    # i26: mapping/evidence.py
    "mapping.evidence_min_views": _int(1),
    "mapping.evidence_split_ratio": _float(0.0, 1.0, lo_open=True),
    "mapping.evidence_merge_ratio": _float(0.0, 1.0, lo_open=True),
    "mapping.evidence_min_group": _int(1),
    "mapping.evidence_apart_ratio": _UNIT,
    "graph.init_keyframes": _int(1),
    "graph.update_every": _int(1),
    "graph.tau_update": _UNIT,
    "graph.theta_e": _POS,
    "graph.tau_e": _float(0.0, 1.0, hi_open=True),
    "graph.min_gaussians": _int(1),
    "graph.edge_voxel": _float(0.0, note="0 = theta_e / 2"),
    "graph.max_points_per_node": _int(1),
    "graph.support_band": _POS,
    "graph.support_ratio": _float(0.0, 1.0, lo_open=True),
    "graph.max_masked_views": _int(1),
    "graph.crop_max_side": _int(1),
    "graph.context_pad": _NONNEG,
    "graph.min_obs_pixels": _int(0),
    "graph.query_min_similarity": _float(-1.0, 1.0),  # a cosine similarity
    **{f"graph.captioner.{k}": r for k, r in _LLM.items()},
    "graph.captioner.concurrency": _int(1),
    **{f"graph.relations.{k}": r for k, r in _LLM.items()},
    "graph.relations.contact_tol": _POS,
    "graph.relations.cell_size": _POS,
    "graph.relations.overlap_ratio": _float(0.0, 1.0, lo_open=True),
    "graph.relations.inside_ratio": _float(0.0, 1.0, lo_open=True),
    "graph.relations.under_gap": _POS,
    "graph.relations.attach_elevation": _NONNEG,
    "graph.confidence.clip_image_size": _int(1, optional=True, note="null = the export's own, or 224"),
    "tracking.max_translation": _POS,
    "tracking.max_rotation_deg": _POS,
    "tracking.keyframe_every": _int(1, note="1 = frame-to-frame"),
    "tracking.min_conditioning": _float(0.0, 1.0, hi_open=True),
    "tracking.max_width": _int(0, note="0 = full resolution"),
    "tracking.depth_min": _NONNEG,
    "tracking.depth_max": _POS,
    "tracking.depth_outlier_trunc": _POS,
    "tracking.depth_huber_delta": _POS,
    "tracking.intensity_huber_delta": _POS,
    "tracking.min_fitness": _UNIT,
    "tracking.max_inlier_rmse": _POS,
    "tracking.keyframe_fitness": _UNIT,
    "tracking.keyframe_translation": _POS,
    "tracking.keyframe_rotation_deg": _POS,
    "tracking.max_lost_frames": _int(0, note="0 = never restart"),
    "tracking.max_residual_ratio": _float(0.0, note="0 = off"),
    "tracking.orb_features": _int(10),
    "tracking.ransac_threshold": _POS,
    "tracking.min_feature_inliers": _int(3),
}


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
    vals = _numbers(v, 3)
    if vals is None or not math.hypot(*vals) > 1e-9:
        return "must be a finite non-zero 3-vector"
    return None


def _check_iterations(v: Any) -> str | None:
    vals = _numbers(v, integer=True)
    if not vals or not all(n >= 1 for n in vals):
        return "must be a non-empty list of integers >= 1 (one per pyramid level)"
    return None


# the numeric list settings: a check returns what is wrong (None: fine)
LIST_CHECKS: dict[str, Callable[[Any], str | None]] = {
    "data.intrinsics": _check_intrinsics,
    "segmentation.sam_score_range": _check_score_range,
    "segmentation.conf_range": _check_conf_range,
    "graph.up_axis": _check_up_axis,
    "tracking.iterations": _check_iterations,
}


def _get(cfg: Any, key: str) -> Any:
    for part in key.split("."):
        cfg = getattr(cfg, part)
    return cfg


def _cross_checks(cfg: Config) -> str | None:
    m, d, t = cfg.mapping, cfg.data, cfg.tracking
    if not m.tau_low <= m.tau_high:
        return f"mapping.tau_low must be <= mapping.tau_high, got {m.tau_low!r} > {m.tau_high!r}"
    if m.keyframe_every == 0 and m.keyframe_translation == 0 and m.keyframe_rotation_deg == 0:
        return (
            "mapping.keyframe_every is 0 and so are mapping.keyframe_translation and "
            "mapping.keyframe_rotation_deg: no frame would become a keyframe; set one of them > 0"
        )
    if d.max_depth > 0 and not d.min_depth < d.max_depth:
        return (
            f"data.min_depth must be < data.max_depth when data.max_depth > 0 (0 = no limit), got "
            f"{d.min_depth!r} >= {d.max_depth!r}"
        )
    if not t.depth_min < t.depth_max:
        return f"tracking.depth_min must be < tracking.depth_max, got {t.depth_min!r} >= {t.depth_max!r}"
    return None


def check_config(cfg: Config) -> None:
    """Raise :class:`ConfigError` naming the key, the value and the allowed range of the first numeric
    setting of ``cfg`` out of its range (:data:`RANGES`, :data:`LIST_CHECKS`, then the cross-field rules).

    ``load_config`` calls it, and so does ``Mapper`` (a ``Config()`` built and changed in Python)."""
    for key, rng in RANGES.items():
        value = _get(cfg, key)
        if not rng.contains(value):
            raise ConfigError(f"{key} must be {rng.describe()}, got {value!r}")
    for key, check in LIST_CHECKS.items():
        value = _get(cfg, key)
        problem = check(value)
        if problem is not None:
            raise ConfigError(f"{key} {problem}, got {value!r}")
    problem = _cross_checks(cfg)
    if problem is not None:
        raise ConfigError(problem)


def _is_dataclass_type(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


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


def _build(cls: type, values: dict, prefix: str = "") -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
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
    """``"mapping.tau_p=0.2"`` -> ``{"mapping": {"tau_p": 0.2}}`` (the value is parsed as YAML)."""
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
    return _build(Config, values)


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """Load a YAML config (None: all defaults) and apply ``key=value`` overrides."""
    values: dict = {}
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"config file {str(p)!r} does not exist")
        try:
            loaded = yaml.safe_load(p.read_text())
        except yaml.YAMLError as e:
            raise ConfigError(f"config file {str(p)!r} is not valid YAML: {e}") from e
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"config file {str(p)!r} must hold a mapping at the top level")
        values = loaded
    for ov in overrides or []:
        values = _merge(values, parse_override(ov))
    cfg = config_from_dict(values)
    check_config(cfg)
    return cfg


def add_override_argument(parser: Any, example: str = "mapping.opt_iters=5") -> None:
    """The ``--set KEY=VALUE`` option every command that reads a config offers (parsed by ``load_config``)."""
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=f"config override, repeatable (e.g. --set {example})",
    )


def config_to_dict(cfg: Any) -> dict:
    return dataclasses.asdict(cfg)


def save_config(cfg: Config, path: str | Path) -> None:
    """Write ``cfg`` as YAML (``load_config`` reads it back), atomically."""
    atomic_write_text(path, yaml.safe_dump(config_to_dict(cfg), sort_keys=False))
