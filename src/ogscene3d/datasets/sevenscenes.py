"""7-Scenes style sequences and the label-fusion variant.

7-Scenes: ``frame-%06d.color.png|jpg``, ``frame-%06d.depth.png`` (uint16 millimetres, 65535 =
invalid), ``frame-%06d.pose.txt`` (4x4 camera-to-world, OpenCV axes), optional
``camera-intrinsics.txt`` (3x3; default fx = fy = 585, cx = 320, cy = 240). The files may sit in
the folder itself or in ``seq-XX/`` sub-folders (all sequences are concatenated in name order).

Label-fusion / APC (``camera-intrinsics.color.txt`` or ``frame-*.segm.png`` present): the same
names, depth in the bit-shifted format metres = (value >> 3) / 1e4 with < 0.3 m invalid, and
``frame-%06d.segm.png`` uint8 class labels (class id = value / 6) returned as ``Frame.gt_classes``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..config import DataConfig
from .base import FrameRecord, K_from_values, RGBDDataset, read_label_png, read_matrix

SEVENSCENES_DEFAULT_K = (585.0, 585.0, 320.0, 240.0)


def _color_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.glob("frame-*.color.*") if p.suffix.lower() in (".png", ".jpg", ".jpeg"))


def _sequence_dirs(root: Path) -> list[Path]:
    if _color_files(root):
        return [root]
    return sorted(d for d in root.glob("seq*") if d.is_dir() and _color_files(d))


class SevenScenesDataset(RGBDDataset):
    kind = "sevenscenes"
    depth_scale_default = 1000.0
    invalid_raw = 65535
    intrinsics_files = ("camera-intrinsics.txt",)

    @staticmethod
    def detect(root: Path) -> bool:
        return bool(_sequence_dirs(root))

    def __init__(self, root: Path, config: DataConfig, segments_dir: Path | None = None) -> None:
        root = Path(root)
        records = []
        for seq in _sequence_dirs(root):
            has_poses = any(seq.glob("frame-*.pose.txt"))  # a sequence without any pose file needs tracking
            for rgb in _color_files(seq):
                base = rgb.name.split(".")[0]  # frame-000000
                records.append(
                    FrameRecord(
                        name=rgb.stem,
                        rgb_path=rgb,
                        depth_path=seq / f"{base}.depth.png",
                        pose_path=seq / f"{base}.pose.txt" if has_poses else None,
                        timestamp=float(len(records)),
                        extras={"segm": seq / f"{base}.segm.png"},
                    )
                )
        K = None
        for name in self.intrinsics_files:
            for d in (root, *(_sequence_dirs(root)[:1])):
                if (d / name).is_file() and K is None:
                    K = read_matrix(d / name, (3, 3), "intrinsics")
        if K is None:
            K = K_from_values(*SEVENSCENES_DEFAULT_K)
        super().__init__(root, records, K, config, segments_dir)


class LabelFusionDataset(SevenScenesDataset):
    kind = "labelfusion"
    depth_scale_default = 1.0e4
    depth_format_default = "shift3"
    min_depth_default = 0.3
    invalid_raw = None
    intrinsics_files = ("camera-intrinsics.color.txt", "camera-intrinsics.txt")
    label_divisor = 6

    @staticmethod
    def detect(root: Path) -> bool:
        dirs = _sequence_dirs(root)
        return bool(dirs) and (
            (root / "camera-intrinsics.color.txt").is_file()
            or any(any(d.glob("frame-*.segm.png")) for d in dirs)
        )

    def _load_gt(
        self, rec: FrameRecord, shape: tuple[int, int]
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        path = rec.extras.get("segm")
        if path is None or not path.is_file():
            return None, None
        return None, read_label_png(path, shape, "label", lambda x: x // self.label_divisor)
