"""ScanNet as exported by the official SensReader (``python reader.py --export_*``).

``SCENE/color/N.jpg`` (1296x968), ``SCENE/depth/N.png`` (uint16 millimetres, 640x480),
``SCENE/pose/N.txt`` (4x4 camera-to-world, OpenCV axes; invalid frames hold ``-inf``), and the
intrinsics in ``SCENE/intrinsic/intrinsic_depth.txt`` (4x4; or ``intrinsic_color.txt``, rescaled)
or ``SCENE/intrinsics.txt``. Colour is resampled to the depth resolution, so frames use the depth
camera's intrinsics (the two are registered in ScanNet's export).

The same layout with zero-padded names (``color/000000.png``, ``depth/000000.png``, ``intrinsics.txt``:
a bring-your-own-camera export) is read too; files are matched by frame number.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..config import DataConfig
from ..errors import DataError
from .base import FrameRecord, RGBDDataset, read_depth_raw, read_matrix, read_rgb

_RGB_SUFFIXES = (".jpg", ".jpeg", ".png")


def _numeric_stems(folder: Path, suffixes: tuple[str, ...]) -> dict[int, Path]:
    """{frame number: file} for the files ``<digits><suffix>`` in ``folder``, whatever the zero-padding
    (``0.png`` and ``000000.png`` are both frame 0); two files with one number are an error."""
    out: dict[int, Path] = {}
    if not folder.is_dir():
        return out
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() in suffixes and p.stem.isdigit():
            n = int(p.stem)
            if n in out:
                raise DataError(f"{folder}: {out[n].name} and {p.name} are both frame {n}; remove one")
            out[n] = p
    return out


class ScanNetDataset(RGBDDataset):
    kind = "scannet"
    depth_scale_default = 1000.0

    @staticmethod
    def detect(root: Path) -> bool:
        return (root / "color").is_dir() and (root / "depth").is_dir()

    def __init__(self, root: Path, config: DataConfig, segments_dir: Path | None = None) -> None:
        root = Path(root)
        color = _numeric_stems(root / "color", _RGB_SUFFIXES)
        if not color:
            raise DataError(f"{root / 'color'}: no numbered colour images (N.jpg or 000000.png)")
        # Depth and pose files are matched to colour by number: SensReader writes 0.png, other
        # exporters (bring-your-own-camera) 000000.png. A frame without one gets the name it would
        # most likely have (the colour file's stem), which the base class reports as missing.
        depth = _numeric_stems(root / "depth", (".png",))
        pose_dir = root / "pose"
        poses = _numeric_stems(pose_dir, (".txt",))
        has_poses = bool(poses)  # without pose files (no pose/ or an empty one) the frames need tracking
        records = [
            FrameRecord(
                name=color[n].stem,
                rgb_path=color[n],
                depth_path=depth.get(n, root / "depth" / f"{color[n].stem}.png"),
                pose_path=poses.get(n, pose_dir / f"{color[n].stem}.txt") if has_poses else None,
                timestamp=float(n),
            )
            for n in sorted(color)
        ]
        K = None
        if config.intrinsics is None:
            K = self._intrinsics(root, records)
        super().__init__(root, records, K, config, segments_dir, resize_rgb_to_depth=True)

    @staticmethod
    def _intrinsics(root: Path, records: list[FrameRecord]) -> np.ndarray:
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
            K[0] *= w_d / w_c
            K[1] *= h_d / h_c
            return K
        raise DataError(
            f"{root}: no intrinsics (intrinsic/intrinsic_depth.txt, intrinsic/intrinsic_color.txt or "
            "intrinsics.txt); give data.intrinsics = [fx, fy, cx, cy]"
        )
