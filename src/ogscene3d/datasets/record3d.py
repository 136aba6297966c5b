"""Record3D captures (``.r3d``, exported by the Record3D iPhone/iPad app; LZFSE needs
``pip install "ogscene3d[record3d]"``).

An ``.r3d`` file is a zip holding ``metadata`` (JSON: colour size ``w``/``h``, depth size ``dw``/``dh``, the
colour camera's ``K`` stored column-major, ``fps``, and per frame a camera-to-world pose ``[qx, qy, qz, qw,
tx, ty, tz]`` in ARKit's axes) and per frame ``rgbd/N.jpg`` (colour), ``rgbd/N.depth`` (LZFSE-compressed
float32 metres at the LiDAR's resolution, e.g. 256x192) and ``rgbd/N.conf`` (LZFSE-compressed uint8 ARKit
confidence, 0 low / 1 medium / 2 high).

Frames have the depth resolution: colour is resampled to it and K scaled to it. Depth whose confidence is
below ``data.r3d_min_confidence`` (default 1: low is left out) is invalid. ARKit's camera looks down -z with
+y up and its world has +y up; both are turned half a turn about x, so that poses are OpenCV
camera-to-world (z forward, y down) in a world whose up is -y, which ``graph.up_axis: auto`` takes.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import logging
import math
import zipfile
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np

from ..config import DataConfig
from ..errors import DataError
from ..optional import require
from .base import FrameRecord, quat_to_matrix
from .decoded import DecodedDataset

log = logging.getLogger(__name__)

#: ARKit (x right, y up, z backward) <-> OpenCV (x right, y down, z forward): half a turn about x
FLIP = np.diag([1.0, -1.0, -1.0, 1.0])


def arkit_to_opencv(pose_xyzw_t: np.ndarray) -> np.ndarray:
    """OpenCV camera-to-world (world: ARKit's turned half a turn about x) from a Record3D pose row
    ``[qx, qy, qz, qw, tx, ty, tz]``."""
    v = np.asarray(pose_xyzw_t, dtype=np.float64)
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(v[:4])
    T[:3, 3] = v[4:7]
    return FLIP @ T @ FLIP


def lzfse_module() -> ModuleType:
    """The LZFSE bindings: ``lzfse`` (the ``record3d`` extra; it has wheels) or ``pyliblzfse``'s ``liblzfse``
    (what ConceptGraphs' instructions install), both with ``compress``/``decompress``."""
    if importlib.util.find_spec("lzfse") is None and importlib.util.find_spec("liblzfse") is not None:
        return importlib.import_module("liblzfse")
    return require("lzfse", "record3d", "reading Record3D .r3d captures (LZFSE-compressed depth)")


def _member_number(name: str, suffix: str) -> int | None:
    stem = name[len("rgbd/") : -len(suffix)]
    return int(stem) if name.startswith("rgbd/") and name.endswith(suffix) and stem.isdigit() else None


class Record3DDataset(DecodedDataset):
    kind = "record3d"
    depth_scale_default = 1.0  # depth is float metres
    up_axis = (0.0, -1.0, 0.0)
    up_axis_source = "Record3D (ARKit's gravity-aligned world, y up, turned to OpenCV axes: -y up)"
    # ARKit intrinsics count pixel centres from 0, as OpenCV does
    pixel_centers_default = "integer"

    @staticmethod
    def detect(root: Path) -> bool:
        return Path(root).is_file() and Path(root).suffix.lower() == ".r3d"

    def __init__(self, root: Path, config: DataConfig, segments_dir: Path | None = None) -> None:
        root = Path(root)
        self._lzfse = lzfse_module()
        if not 0 <= int(config.r3d_min_confidence) <= 2:
            raise DataError(f"data.r3d_min_confidence must be 0, 1 or 2, got {config.r3d_min_confidence}")
        self.min_confidence = int(config.r3d_min_confidence)
        try:
            self.zip = zipfile.ZipFile(root)
        except (OSError, zipfile.BadZipFile) as e:
            raise DataError(f"{root}: not a readable Record3D capture (an .r3d is a zip file): {e}") from e
        try:
            records, K = self._scan(root, config)
        except BaseException:
            self.zip.close()
            raise
        super().__init__(root, records, K, config, segments_dir, resize_rgb_to_depth=True)

    def _scan(self, root: Path, config: DataConfig) -> tuple[list[FrameRecord], np.ndarray | None]:
        names = set(self.zip.namelist())
        if "metadata" not in names:
            raise DataError(f"{root}: holds no 'metadata' entry (is it a Record3D .r3d export?)")
        try:
            meta = json.loads(self.zip.read("metadata"))
            self.rgb_size = (int(meta["h"]), int(meta["w"]))
            K_rgb = np.asarray(meta["K"], dtype=np.float64).reshape(3, 3).T  # stored column-major
            poses = np.asarray(meta.get("poses", []), dtype=np.float64).reshape(-1, 7)
            fps = float(meta.get("fps", 30.0)) or 30.0
            stamps = meta.get("frameTimestamps")
        except (KeyError, TypeError, ValueError, zipfile.BadZipFile) as e:
            raise DataError(f"{root}: metadata is not Record3D's JSON (w, h, K, poses): {e}") from e
        self.depth_size = (int(meta["dh"]), int(meta["dw"])) if "dh" in meta and "dw" in meta else None
        colour = {n: k for k in names if (n := _member_number(k, ".jpg")) is not None}
        depth = {n: k for k in names if (n := _member_number(k, ".depth")) is not None}
        if not colour:
            raise DataError(f"{root}: holds no rgbd/N.jpg colour images")
        records, missing = [], []
        sizes = {i.filename: i.file_size for i in self.zip.infolist()}
        for n in sorted(set(colour) | set(depth)):
            # every frame the capture holds some of: a missing or empty member is named, not passed over
            have = (("colour", colour.get(n)), ("depth", depth.get(n)))
            lacks = [what if m is None else f"empty {what}" for what, m in have if not sizes.get(m)]
            if n >= len(poses):
                lacks.append("pose")
            if lacks:
                missing.append(f"frame {n} ({' and '.join(lacks)})")
                continue
            t = float(stamps[n]) if isinstance(stamps, list) and n < len(stamps) else n / fps
            records.append(
                FrameRecord(
                    name=f"frame{n:06d}",
                    rgb_path=root / f"frame{n:06d}",
                    depth_path=root / f"frame{n:06d}",
                    pose=arkit_to_opencv(poses[n]),
                    pose_source=f"{root}: metadata pose {n}",
                    timestamp=t,
                    extras={"rgb": Path(colour[n]), "depth": Path(depth[n])},
                )
            )
        if missing:
            shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
            msg = f"{root}: {len(missing)} of {len(set(colour) | set(depth))} frames lack data: {shown}"
            if config.on_bad_frame != "skip" or not records:
                raise DataError(f"{msg}; set data.on_bad_frame: skip to leave them out")
            log.warning("%s; leaving them out (data.on_bad_frame: skip)", msg)
        if self.depth_size is None:
            self.depth_size = self._depth_size_from(records[0])
        if config.intrinsics is not None:
            return records, None
        # the colour camera's K, scaled to the depth image: a resize maps pixel edges onto pixel edges
        (h, w), (dh, dw) = self.rgb_size, self.depth_size
        K = K_rgb.copy()
        off = 0.5 if self.read_pixel_centers(config) == "integer" else 0.0
        K[0] *= dw / w
        K[1] *= dh / h
        K[:2, 2] += off * (np.array([dw / w, dh / h]) - 1.0)
        return records, K

    def _depth_size_from(self, rec: FrameRecord) -> tuple[int, int]:
        """(dh, dw) of an older capture whose metadata lacks them: from the first depth image's value count
        and the colour image's aspect ratio."""
        n = self._decompress(str(rec.extras["depth"])).size // 4
        h, w = self.rgb_size
        dh = int(round(math.sqrt(n * h / w)))
        if dh <= 0 or n % dh:
            raise DataError(f"{self.root}: cannot tell the depth image size (metadata has no dw/dh)")
        return dh, n // dh

    def _decompress(self, member: str) -> np.ndarray:
        try:
            data = self.zip.read(member)
        except KeyError:
            raise DataError(f"{self.root}: {member} is missing") from None
        except (OSError, zipfile.BadZipFile) as e:
            raise DataError(f"{self.root}: cannot read {member} ({e})") from e
        try:
            return np.frombuffer(self._lzfse.decompress(data), np.uint8)
        except Exception as e:  # liblzfse raises its own error type
            raise DataError(f"{self.root}: {member} is not LZFSE-compressed data ({e})") from e

    def _image_size(self) -> tuple[int, int]:
        return self.depth_size

    def _read_arrays(self, rec: FrameRecord) -> tuple[np.ndarray, np.ndarray]:
        dh, dw = self.depth_size
        raw = self._decompress(str(rec.extras["depth"]))
        if raw.size != dh * dw * 4:
            raise DataError(
                f"{self.root}: {rec.extras['depth']} holds {raw.size} bytes, a {dw}x{dh} float32 depth image "
                f"{dh * dw * 4}"
            )
        depth = raw.view(np.float32).reshape(dh, dw).copy()
        conf_member = f"rgbd/{Path(str(rec.extras['depth'])).stem}.conf"
        if self.min_confidence > 0 and conf_member in self.zip.NameToInfo:
            conf = self._decompress(conf_member)
            if conf.size != dh * dw:
                raise DataError(f"{self.root}: {conf_member} holds {conf.size} values, expected {dw}x{dh}")
            depth[conf.reshape(dh, dw) < self.min_confidence] = 0.0
        member = str(rec.extras["rgb"])
        try:
            data = np.frombuffer(self.zip.read(member), np.uint8)
        except (KeyError, OSError, zipfile.BadZipFile) as e:
            raise DataError(f"{self.root}: cannot read {member} ({e})") from e
        if data[:2].tobytes() == b"\xff\xd8" and b"\xff\xd9" not in data[-64:].tobytes():
            raise DataError(f"{self.root}: {member} is truncated (no JPEG end-of-image marker)")
        img = cv2.imdecode(data, cv2.IMREAD_COLOR)
        if img is None:
            raise DataError(f"{self.root}: {member} cannot be decoded (corrupt image)")
        if img.shape[:2] != self.rgb_size:
            raise DataError(
                f"{self.root}: {member} is {img.shape[1]}x{img.shape[0]}, the metadata says "
                f"{self.rgb_size[1]}x{self.rgb_size[0]}"
            )
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB), depth
