"""``open_dataset``: layout detection and the one entry point to every reader."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..config import DataConfig
from ..errors import DataError
from .base import RGBDDataset
from .record3d import Record3DDataset
from .replica import ReplicaDataset
from .rosbag import RosBagDataset
from .scannet import ScanNetDataset
from .semantic_nerf import SemanticNeRFDataset
from .sevenscenes import LabelFusionDataset, SevenScenesDataset
from .synthetic import SyntheticDataset
from .tum import TUMDataset

# Detection order matters: a synthetic scene is also a Replica scene, label-fusion also 7-Scenes.
READERS: dict[str, type[RGBDDataset]] = {
    "synthetic": SyntheticDataset,
    "replica": ReplicaDataset,
    "semantic_nerf": SemanticNeRFDataset,
    "scannet": ScanNetDataset,
    "tum": TUMDataset,
    "labelfusion": LabelFusionDataset,
    "sevenscenes": SevenScenesDataset,
    # recordings in one file (or a ROS 2 bag folder): their readers import their libraries only when opening
    "rosbag": RosBagDataset,
    "record3d": Record3DDataset,
}

_LAYOUTS = (
    "synthetic (results/ + traj.txt + gt/instances.json), replica (results/frame*.jpg + traj.txt), "
    "semantic_nerf (rgb/rgb_N.png + depth/depth_N.png + traj_w_c.txt or SNI-SLAM's traj.txt, or a scene's "
    "Sequence_N/ of them), "
    "scannet (color/ + depth/ + pose/), tum (rgb.txt + depth.txt), labelfusion/sevenscenes "
    "(frame-*.color.*), "
    "rosbag (a ROS 1 .bag, a ROS 2 bag folder with metadata.yaml, or an .mcap file), record3d (an .r3d file)"
)


def detect_kind(path: str | Path) -> tuple[str, Path]:
    """(kind, scene folder) for ``path``; a folder holding exactly one recognisable scene is entered."""
    root = Path(path)
    if not root.exists():
        raise DataError(f"{root}: dataset path does not exist")
    if not root.is_dir():
        for kind in ("rosbag", "record3d"):
            if READERS[kind].detect(root):
                return kind, root
        if root.suffix.lower() == ".db3":
            raise DataError(
                f"{root}: a .db3 file alone is a librealsense recording (map it with ogscene3d-live --source "
                "realsense:FILE) or part of a ROS 2 bag (give the bag's folder, which holds metadata.yaml)"
            )
        raise DataError(f"{root}: dataset path is a file, but not a .bag, .mcap or .r3d recording")
    for kind, reader in READERS.items():
        if reader.detect(root):
            return kind, root
    found = _single_scene(root, list(READERS))
    if found is not None:
        return found
    if not any(root.iterdir()):
        raise DataError(f"{root}: folder is empty")
    raise DataError(f"{root}: no known dataset layout; expected one of {_LAYOUTS}")


def _single_scene(root: Path, kinds: list[str]) -> tuple[str, Path] | None:
    """(kind, sub-folder) when exactly one sub-folder of ``root`` is a scene of one of ``kinds`` (the
    first that fits, in detection order), e.g. a NICE-SLAM ``Replica/`` folder holding ``room0/``; None
    when none is. Several scenes are an error: which one to open is the user's choice."""
    children = [d for d in sorted(root.iterdir()) if d.is_dir()]
    found = [(k, d) for d in children for k in kinds if READERS[k].detect(d)]
    scenes = {d for _, d in found}
    if len(scenes) > 1:
        names = ", ".join(sorted(d.name for d in scenes))
        raise DataError(f"{root}: holds several scenes ({names}); open one of them")
    return found[0] if found else None


def open_dataset(
    path: str | Path | None = None,
    kind: str = "auto",
    segments_dir: str | Path | None = None,
    stride: int | None = None,
    max_frames: int | None = None,
    config: DataConfig | None = None,
) -> RGBDDataset:
    """Open an RGB-D sequence lazily: frames are read when indexed or iterated.

    Arguments left at None fall back to ``config``, then to the defaults (stride 1, all frames).

    Args:
        path: the dataset folder (or a ROS bag / Record3D file); None: ``config.path``.
        kind: the layout: auto (detected) | replica | semantic_nerf | scannet | tum | sevenscenes |
            labelfusion | synthetic | rosbag | record3d.
        segments_dir: a folder of precomputed segments (``<rgb stem>.png/.json``); None:
            ``config.segments_dir``.
        stride: use every N-th frame; None: ``config.stride``.
        max_frames: read at most this many frames; None: ``config.max_frames``.
        config: the ``data`` config section (a :class:`~ogscene3d.config.DataConfig`), which also gives
            ``start``, ``depth_scale``, ``depth_format``, ``intrinsics``, ``min_depth`` / ``max_depth``
            and ``on_bad_frame``; None: its defaults.

    Returns:
        The dataset: a sequence of :class:`~ogscene3d.frame.Frame` (``len``, indexing, iteration) with
        the sequence's intrinsics ``K``.

    Raises:
        DataError: no path, a missing folder, or a layout it does not recognise.
    """
    cfg = dataclasses.replace(config) if config is not None else DataConfig()
    if path is None:
        path = cfg.path
    if path is None:
        raise DataError("no dataset path given (argument path or data.path)")
    if kind == "auto" and cfg.kind != "auto":
        kind = cfg.kind
    if segments_dir is None and cfg.segments_dir:
        segments_dir = cfg.segments_dir
    if stride is not None:
        cfg.stride = int(stride)
    if max_frames is not None:
        cfg.max_frames = int(max_frames)
    if kind == "auto":
        kind, root = detect_kind(path)
    else:
        if kind not in READERS:
            raise DataError(f"unknown dataset kind {kind!r}; expected auto or one of {sorted(READERS)}")
        root = Path(path)
        if not root.is_dir() and not (root.is_file() and READERS[kind].detect(root)):
            raise DataError(f"{root}: dataset path does not exist or is not a folder")
        if root.is_dir() and not READERS[kind].detect(root):
            # as with kind auto, a folder holding a single scene is entered (data.kind set in a config)
            found = _single_scene(root, [kind])
            if found is None:
                raise DataError(f"{root}: does not look like a {kind} dataset; expected one of {_LAYOUTS}")
            root = found[1]
    seg = Path(segments_dir) if segments_dir is not None else None
    return READERS[kind](root, cfg, seg)
