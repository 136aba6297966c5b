"""7-Scenes style sequences and the label-fusion variant.

7-Scenes: ``frame-%06d.color.png|jpg``, ``frame-%06d.depth.png`` (uint16 millimetres, 65535 =
invalid), ``frame-%06d.pose.txt`` (4x4 camera-to-world, OpenCV axes), optional
``camera-intrinsics.txt`` (3x3; without it the Kinect default fx = fy = 585, cx = 320, cy = 240, with a
warning). The files may sit in the folder itself or in ``seq-XX/`` sub-folders (all sequences are
concatenated in name order); the intrinsics file in the folder or in the first sequence.

Known limitation: 7-Scenes' depth is NOT registered to its colour. Depth, poses and the 585 intrinsics are
the Kinect's depth camera's; the colour comes from its other camera (focal length about 525-535 px, a few
cm beside it), whose calibration the dataset does not publish. Read pixel by pixel, colour (and so the
segments) lands off the depth, most toward the image borders; scaling colour about the centre and shifting
it brings depth and colour edges closer but not together (measured on the redkitchen sample:
docs/results.md, "Dataset checks"). No correction is applied (relocalisation works register depth with
an approximate calibration or use depth rendered from the 3D models instead); the reader warns when it
reads the 585 depth camera.

Label-fusion / APC (``camera-intrinsics.color.txt``, preferred over ``camera-intrinsics.txt``, or
``frame-*.segm.png`` present): the same names, depth in the bit-shifted format metres = (value >> 3) /
1e4 with < 0.3 m invalid, and ``frame-%06d.segm.png`` uint8 class labels (class id = value / 6) returned
as ``Frame.gt_classes``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..config import DataConfig
from .base import FrameRecord, K_from_values, RGBDDataset, read_label_png, read_matrix

log = logging.getLogger(__name__)

SEVENSCENES_DEFAULT_K = (585.0, 585.0, 320.0, 240.0)
SEVENSCENES_DEPTH_FOCAL = 585.0  # 7-Scenes' (and 3DMatch's copies of it) depth camera, not the colour one


def _color_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.glob("frame-*.color.*") if p.suffix.lower() in (".png", ".jpg", ".jpeg"))


def _frame_color_files(folder: Path) -> list[Path]:
    """The colour file of every frame in ``folder``, by frame name: a depth image or pose file without its
    colour image gets the colour file's expected name (the other frames' suffix), which the base class then
    reports as missing rather than the frame disappearing without a word."""
    colors = {p.name.split(".")[0]: p for p in _color_files(folder)}
    suffix = next(iter(colors.values())).suffix if colors else ".png"
    for d in (*folder.glob("frame-*.depth.png"), *folder.glob("frame-*.pose.txt")):
        base = d.name.split(".")[0]
        colors.setdefault(base, folder / f"{base}.color{suffix}")
    return [colors[b] for b in sorted(colors)]


def _sequence_dirs(root: Path) -> list[Path]:
    if _color_files(root):
        return [root]
    return sorted(d for d in root.glob("seq*") if d.is_dir() and _color_files(d))


def find_intrinsics(root: Path, names: tuple[str, ...]) -> Path | None:
    """The first of ``names`` (in order of preference) in ``root`` or its first sequence folder."""
    folders = (root, *_sequence_dirs(root)[:1])
    for name in names:
        for d in folders:
            if (d / name).is_file():
                return d / name
    return None


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
            for rgb in _frame_color_files(seq):
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
        if config.intrinsics is None:  # data.intrinsics wins over the files (the base class applies it)
            K = self._intrinsics(root)
        super().__init__(root, records, K, config, segments_dir)
        focals = self.K[[0, 1], [0, 1]]
        if self.kind == "sevenscenes" and np.allclose(focals, SEVENSCENES_DEPTH_FOCAL, atol=1.0):
            log.warning(
                "%s: fx = fy = 585 is the 7-Scenes Kinect's depth camera; 7-Scenes colour images are not "
                "registered to their depth (another camera, f ~ 530 px, a few cm aside), so colours and "
                "segments land up to ~30 px off toward the image borders (not corrected)",
                root,
            )

    @classmethod
    def _intrinsics(cls, root: Path) -> np.ndarray:
        """K from the first of ``intrinsics_files`` in the scene folder or its first sequence; else the
        7-Scenes Kinect default, with a warning (right only for a Kinect v1 at 640x480)."""
        path = find_intrinsics(root, cls.intrinsics_files)
        if path is not None:
            return read_matrix(path, (3, 3), "intrinsics")
        log.warning(
            "%s: no %s; using the 7-Scenes Kinect default intrinsics fx, fy, cx, cy = %s, right only for "
            "that camera: give data.intrinsics = [fx, fy, cx, cy] for any other",
            root,
            " or ".join(cls.intrinsics_files),
            SEVENSCENES_DEFAULT_K,
        )
        return K_from_values(*SEVENSCENES_DEFAULT_K)


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
        # the colour intrinsics file is looked for where the reader looks for it, not in the scene folder only
        return bool(dirs) and (
            find_intrinsics(root, ("camera-intrinsics.color.txt",)) is not None
            or any(any(d.glob("frame-*.segm.png")) for d in dirs)
        )

    @property
    def has_class_maps(self) -> bool:
        return any(rec.extras["segm"].is_file() for rec in self.records)

    def _load_gt(
        self, rec: FrameRecord, shape: tuple[int, int]
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        path = rec.extras.get("segm")
        if path is None or not path.is_file():
            return None, None
        return None, read_label_png(path, shape, "label", lambda x: x // self.label_divisor)
