"""ScanNet as exported by the official SensReader (``python reader.py --export_*``).

``SCENE/color/N.jpg`` (1296x968), ``SCENE/depth/N.png`` (uint16 millimetres, 640x480),
``SCENE/pose/N.txt`` (4x4 camera-to-world, OpenCV axes; invalid frames hold ``-inf``), and the
intrinsics in ``SCENE/intrinsic/intrinsic_depth.txt`` (4x4; or ``intrinsic_color.txt``, rescaled)
or ``SCENE/intrinsics.txt``. Colour is resampled to the depth resolution, so frames use the depth
camera's intrinsics (the two are registered in ScanNet's export).

The same layout with zero-padded names (``color/000000.png``, ``depth/000000.png``, ``intrinsics.txt``:
a bring-your-own-camera export) is read too; files are matched by frame number.

Per-frame labels: when ``SCENE/label-filt/N.png`` exist (ScanNet's ``*_2d-label-filt.zip`` unpacked into the
scene folder: uint16 raw ScanNet category ids at the colour camera's size) and
``scannetv2-labels.combined.tsv`` lies in the scene folder or one of its two parents, frames carry
``gt_classes`` in NYU40 ids (the tsv's ``id`` -> ``nyu40id`` columns), the id space of the 3D ground truth
``*_vh_clean_2.labels.ply``; 0 (unannotated, or a raw id the tsv lacks) is void. Label images are resampled
to the depth size by nearest neighbour, as colour is.
"""

from __future__ import annotations

import csv
import logging
from pathlib import Path

import numpy as np

from ..config import DataConfig
from ..errors import DataError
from .base import (
    FrameRecord,
    RGBDDataset,
    numbered_files,
    read_depth_raw,
    read_label_png,
    read_matrix,
    read_rgb,
)

log = logging.getLogger(__name__)

_RGB_SUFFIXES = (".jpg", ".jpeg", ".png")

LABEL_DIR = "label-filt"
LABEL_MAP_NAME = "scannetv2-labels.combined.tsv"

#: NYU40 class names by id (1..40), the id space of ScanNet's ``*_vh_clean_2.labels.ply`` and of the frames'
#: ``gt_classes``; spelled as ScanNet's benchmark scripts spell them (0 = unannotated is not a class).
NYU40_CLASSES: dict[int, str] = dict(
    enumerate(
        [
            "wall", "floor", "cabinet", "bed", "chair", "sofa", "table", "door", "window", "bookshelf",
            "picture", "counter", "blinds", "desk", "shelves", "curtain", "dresser", "pillow", "mirror",
            "floor mat", "clothes", "ceiling", "books", "refrigerator", "television", "paper", "towel",
            "shower curtain", "box", "whiteboard", "person", "night stand", "toilet", "sink", "lamp",
            "bathtub", "bag", "otherstructure", "otherfurniture", "otherprop",
        ],
        start=1,
    )
)  # fmt: skip


#: The NYU40 ids of ScanNet's 20-class benchmark (its ``VALID_CLASS_IDS``), the classes HOV-SG and most
#: open-vocabulary methods report on ScanNet; ``--classes scannet20`` scores these, the other ids are void.
SCANNET20_IDS: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 14, 16, 24, 28, 33, 34, 36, 39)
SCANNET20_CLASSES: dict[int, str] = {i: NYU40_CLASSES[i] for i in SCANNET20_IDS}

#: Class tables ``--classes`` takes by name: ScanNet's ids are NYU40 ids in both.
BUILTIN_CLASS_TABLES: dict[str, dict[int, str]] = {"nyu40": NYU40_CLASSES, "scannet20": SCANNET20_CLASSES}


def find_label_map(root: Path) -> Path | None:
    """``scannetv2-labels.combined.tsv`` in ``root`` or one of its two parents (ScanNet keeps it at the top
    of the download, beside ``scans/``), or None."""
    for d in (root, root.parent, root.parent.parent):
        if (d / LABEL_MAP_NAME).is_file():
            return d / LABEL_MAP_NAME
    return None


def read_label_map(path: str | Path, src: str = "id", dst: str = "nyu40id") -> np.ndarray:
    """Lookup table raw ScanNet category id -> ``dst`` id (0 where the tsv has no row or no value) from
    ``scannetv2-labels.combined.tsv``."""
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f, delimiter="\t"))
    except OSError as e:
        raise DataError(f"{path}: cannot read the label map ({e})") from e
    if not rows or src not in rows[0] or dst not in rows[0]:
        have = list(rows[0]) if rows else []
        raise DataError(
            f"{path}: a ScanNet label map needs tab-separated columns {src!r} and {dst!r}; has {have}"
        )
    pairs: dict[int, int] = {}
    for line, row in enumerate(rows, start=2):
        if not (row[dst] or "").strip():
            continue  # a category without an NYU40 class: its pixels stay void
        try:
            pairs[int(row[src])] = int(row[dst])
        except (TypeError, ValueError):
            raise DataError(
                f"{path}: line {line}: {src}={row[src]!r}, {dst}={row[dst]!r} are not integers"
            ) from None
    if any(k < 0 or k > 65535 for k in pairs):
        raise DataError(f"{path}: raw category ids must lie in 0..65535 (16-bit label images)")
    lut = np.zeros(max(pairs, default=0) + 1, dtype=np.int32)
    for k, v in pairs.items():
        lut[k] = v
    return lut


class ScanNetDataset(RGBDDataset):
    kind = "scannet"
    depth_scale_default = 1000.0
    up_axis = (0.0, 0.0, 1.0)
    up_axis_source = "the ScanNet layout (its scans' world is z-up)"

    layout_markers = ("color/", "depth/")

    def __init__(self, root: Path, config: DataConfig, segments_dir: Path | None = None) -> None:
        root = Path(root)
        color = numbered_files(root / "color", _RGB_SUFFIXES)
        if not color:
            raise DataError(f"{root / 'color'}: no numbered colour images (N.jpg or 000000.png)")
        # Colour, depth and pose files are matched by number: SensReader writes 0.png, other exporters
        # (bring-your-own-camera) 000000.png. A frame is every number one of them has; a frame without one of
        # its files gets the name that file would most likely have (the stem of a file it has, the colour
        # images' suffix), which the base class reports as missing rather than the frame vanishing unnamed.
        depth = numbered_files(root / "depth", (".png",))
        pose_dir = root / "pose"
        poses = numbered_files(pose_dir, (".txt",))
        has_poses = bool(poses)  # without pose files (no pose/ or an empty one) the frames need tracking
        labels = self._label_files(root)
        suffix = next(iter(color.values())).suffix
        records = []
        for n in sorted(set(color) | set(depth) | set(poses)):
            stem = next(files[n].stem for files in (color, depth, poses) if n in files)
            records.append(
                FrameRecord(
                    name=stem,
                    rgb_path=color.get(n, root / "color" / f"{stem}{suffix}"),
                    depth_path=depth.get(n, root / "depth" / f"{stem}.png"),
                    pose_path=poses.get(n, pose_dir / f"{stem}.txt") if has_poses else None,
                    timestamp=float(n),
                    extras={"label": labels[n]} if n in labels else {},
                )
            )
        K = None
        if config.intrinsics is None:
            K = self._intrinsics(root, records, self.read_pixel_centers(config))
        super().__init__(root, records, K, config, segments_dir, resize_rgb_to_depth=True)

    def _label_files(self, root: Path) -> dict[int, Path]:
        """The frames' label-filt images, with ``self._label_lut`` set to translate them; none (with a
        warning) when there is no label map to translate them with."""
        self._label_lut: np.ndarray | None = None
        labels = numbered_files(root / LABEL_DIR, (".png",))
        if not labels:
            return {}
        tsv = find_label_map(root)
        if tsv is None:
            log.warning(
                "%s: %s/ holds raw ScanNet category ids, but no %s was found in the scene folder or its two "
                "parents to map them to NYU40: frames carry no ground-truth class maps",
                root,
                LABEL_DIR,
                LABEL_MAP_NAME,
            )
            return {}
        self._label_lut = read_label_map(tsv)
        return labels

    @property
    def class_names(self) -> dict[int, str] | None:
        return dict(NYU40_CLASSES) if self.has_class_maps else None

    @property
    def has_class_maps(self) -> bool:
        return self._label_lut is not None and any("label" in rec.extras for rec in self.records)

    def _load_gt(
        self, rec: FrameRecord, shape: tuple[int, int]
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        path = rec.extras.get("label")
        if path is None or self._label_lut is None:
            return None, None
        raw = read_label_png(path, shape, "ScanNet label", resize=True)
        lut = self._label_lut
        # a raw id beyond the tsv's rows has no class: void (0), as unannotated pixels are
        return None, np.where(raw < lut.size, lut[np.minimum(raw, lut.size - 1)], 0).astype(np.int32)

    @staticmethod
    def _intrinsics(root: Path, records: list[FrameRecord], pixel_centers: str) -> np.ndarray:
        intr = root / "intrinsic"
        if (intr / "intrinsic_depth.txt").is_file():
            return read_matrix(intr / "intrinsic_depth.txt", (3, 3), "intrinsics")
        if (root / "intrinsics.txt").is_file():
            return read_matrix(root / "intrinsics.txt", (3, 3), "intrinsics")
        if (intr / "intrinsic_color.txt").is_file():
            # Colour intrinsics, rescaled to the depth image the frames are resampled to.
            K = read_matrix(intr / "intrinsic_color.txt", (3, 3), "intrinsics").copy()
            # sizes from a complete frame, so that missing files are reported all at once by the base class
            first = next((r for r in records if r.depth_path.is_file()), records[0])
            h_c, w_c = read_rgb(first.rgb_path).shape[:2]
            h_d, w_d = read_depth_raw(first.depth_path).shape
            # a resize maps pixel edges onto pixel edges: the centre offset is scaled with the image
            off = 0.5 if pixel_centers == "integer" else 0.0
            K[0] *= w_d / w_c
            K[1] *= h_d / h_c
            K[:2, 2] += off * (np.array([w_d / w_c, h_d / h_c]) - 1.0)
            return K
        raise DataError(
            f"{root}: no intrinsics (intrinsic/intrinsic_depth.txt, intrinsic/intrinsic_color.txt or "
            "intrinsics.txt); give data.intrinsics = [fx, fy, cx, cy]"
        )
