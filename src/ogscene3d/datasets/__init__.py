"""RGB-D datasets: lazy readers for Replica (NICE-SLAM's and Semantic-NeRF's layouts), ScanNet, TUM RGB-D,
7-Scenes, label-fusion and synthetic scenes.

``open_dataset(path)`` detects the layout and returns an :class:`RGBDDataset` (``len``, ``ds[i]``,
iteration yielding :class:`~ogscene3d.frame.Frame`). Synthetic scenes (``make_synthetic_scene``)
carry their simulated SAM segments in ``segments/``, which is used automatically when
``segments_dir`` is None; for other layouts segments are read only from ``segments_dir``."""

from __future__ import annotations

from .._lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        ".base": ["FrameRecord", "RGBDDataset", "decode_depth", "read_depth_raw", "read_rgb"],
        ".loader": ["READERS", "detect_kind", "open_dataset"],
        ".replica": ["ReplicaDataset"],
        ".scannet": ["ScanNetDataset"],
        ".semantic_nerf": ["SemanticNeRFDataset"],
        ".sevenscenes": ["LabelFusionDataset", "SevenScenesDataset"],
        ".synthetic": ["SyntheticDataset", "configured_scene", "load_instances", "make_synthetic_scene"],
        ".tum": ["TUMDataset"],
    },
)

__all__ = [
    "READERS",
    "FrameRecord",
    "LabelFusionDataset",
    "RGBDDataset",
    "ReplicaDataset",
    "ScanNetDataset",
    "SemanticNeRFDataset",
    "SevenScenesDataset",
    "SyntheticDataset",
    "TUMDataset",
    "decode_depth",
    "detect_kind",
    "load_instances",
    "make_synthetic_scene",
    "configured_scene",
    "open_dataset",
    "read_depth_raw",
    "read_rgb",
]
