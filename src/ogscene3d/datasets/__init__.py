"""RGB-D datasets: lazy readers for Replica (NICE-SLAM's and Semantic-NeRF's layouts), ScanNet, TUM RGB-D,
7-Scenes, label-fusion and synthetic scenes.

``open_dataset(path)`` detects the layout and returns an :class:`RGBDDataset` (``len``, ``ds[i]``,
iteration yielding :class:`~ogscene3d.frame.Frame`). Synthetic scenes (``make_synthetic_scene``)
carry their simulated SAM segments in ``segments/``, which is used automatically when
``segments_dir`` is None; for other layouts segments are read only from ``segments_dir``.
"""

from __future__ import annotations

from .base import FrameRecord, RGBDDataset, decode_depth, read_depth_raw, read_rgb
from .loader import READERS, detect_kind, open_dataset
from .replica import ReplicaDataset
from .scannet import ScanNetDataset
from .semantic_nerf import SemanticNeRFDataset
from .sevenscenes import LabelFusionDataset, SevenScenesDataset
from .synthetic import SyntheticDataset, configured_scene, load_instances, make_synthetic_scene
from .tum import TUMDataset

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
