"""Run configuration: nested dataclasses loaded from YAML (``yaml.safe_load``) with ``key=value`` overrides.

Every section has the paper's defaults (Sec. IV-A.4); ``configs/*.yaml`` only state what differs per dataset.
Unknown keys are errors, so a typo in a YAML file never silently falls back to a default.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .errors import ConfigError


@dataclass
class DataConfig:
    kind: str = "auto"  # auto | replica | scannet | tum | sevenscenes | synthetic
    path: str | None = None
    segments_dir: str | None = None
    stride: int = 1
    start: int = 0
    max_frames: int | None = None
    depth_scale: float | None = None  # raw depth units per metre; None = the dataset's own
    intrinsics: list[float] | None = None  # [fx, fy, cx, cy] overriding the dataset's
    min_depth: float = 0.0
    max_depth: float = 0.0  # 0 = no limit
    on_bad_frame: str = "error"  # error | skip


@dataclass
class SyntheticConfig:
    seed: int = 0
    frames: int = 60
    width: int = 160
    height: int = 120
    noise: str = "default"  # none | low | default | high
    depth_noise: float = 0.0  # std in metres
    pose_noise: float = 0.0  # std of translation in metres


@dataclass
class SegmentationConfig:
    backend: str = "precomputed"  # precomputed | sam | sam+detector | classical | simulated
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


@dataclass
class MappingConfig:
    ablation: str = "full"  # naive | local | local+global | full
    keyframe_every: int = 1
    keyframe_translation: float = 0.0  # metres; 0 = unused
    keyframe_rotation_deg: float = 0.0  # 0 = unused
    pixels_per_gaussian: int = 4  # subsampling of back-projected pixels per segment
    knn_k: int = 5
    knn_radius: float = 0.05
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
    lr_means: float = 0.001
    lr_scales: float = 0.001
    lr_quats: float = 0.001
    lr_opacities: float = 0.05
    lr_colors: float = 0.0001
    lambda_c: float = 1.0
    lambda_d: float = 0.1
    ssim_lambda: float = 0.2
    prune_opacity: float = 0.005
    prune_scale: float = 0.5
    checkpoint_every: int = 0  # keyframes; 0 = only at the end


@dataclass
class CaptionerConfig:
    kind: str = "heuristic"  # heuristic | openai | groundtruth
    base_url: str = "http://127.0.0.1:8000/v1"
    model: str = ""
    api_key_env: str = "OPENAI_API_KEY"
    timeout_s: float = 30.0
    max_retries: int = 2


@dataclass
class RelationsConfig:
    kind: str = "geometric"  # geometric | llm
    base_url: str = "http://127.0.0.1:8000/v1"
    model: str = ""
    api_key_env: str = "OPENAI_API_KEY"
    timeout_s: float = 30.0
    max_retries: int = 2


@dataclass
class NodeConfidenceConfig:
    kind: str = "mean"  # mean | clip
    clip_image: str | None = None
    clip_text: str | None = None
    clip_vocab: str | None = None


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
    captioner: CaptionerConfig = field(default_factory=CaptionerConfig)
    relations: RelationsConfig = field(default_factory=RelationsConfig)
    confidence: NodeConfidenceConfig = field(default_factory=NodeConfidenceConfig)


@dataclass
class TrackingConfig:
    poses: str = "gt"  # gt | odometry
    max_translation: float = 0.3  # metres per frame beyond which a step is implausible
    max_rotation_deg: float = 30.0
    keyframe_every: int = 5


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
    return config_from_dict(values)


def config_to_dict(cfg: Any) -> dict:
    return dataclasses.asdict(cfg)


def save_config(cfg: Config, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(config_to_dict(cfg), sort_keys=False))
