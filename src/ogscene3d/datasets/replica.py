"""Replica in the NICE-SLAM / SplaTAM layout.

``SCENE/results/frame%06d.jpg`` (or .png), ``SCENE/results/depth%06d.png`` (uint16, metres =
value / 6553.5), ``SCENE/traj.txt`` (one row-major 4x4 camera-to-world matrix per line, OpenCV
axes, line k = frame k), and ``cam_params.json`` (``{"camera": {"w", "h", "fx", "fy", "cx", "cy",
"scale"}}``) in the scene folder or its parent. The json's ``scale`` is the depth scale.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..config import DataConfig
from ..errors import DataError
from .base import FrameRecord, K_from_values, RGBDDataset, frame_number

_RGB_SUFFIXES = (".jpg", ".jpeg", ".png")


def find_cam_params(root: Path) -> Path | None:
    for d in (root, root.parent):
        p = d / "cam_params.json"
        if p.is_file():
            return p
    return None


def read_cam_params(path: Path) -> tuple[np.ndarray, float | None, tuple[int, int] | None]:
    """(K, depth scale or None, (w, h) or None) from a NICE-SLAM ``cam_params.json``."""
    try:
        cam = json.loads(path.read_text())["camera"]
        K = K_from_values(float(cam["fx"]), float(cam["fy"]), float(cam["cx"]), float(cam["cy"]))
        scale = float(cam["scale"]) if "scale" in cam else None
        size = (int(cam["w"]), int(cam["h"])) if "w" in cam and "h" in cam else None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise DataError(
            f'{path}: malformed camera parameters ({e}); expected {{"camera": {{"fx", "fy", "cx", "cy"}}}}'
        ) from e
    return K, scale, size


def read_traj_lines(path: Path) -> tuple[np.ndarray, dict[int, str]]:
    """[N, 4, 4] camera-to-world poses from a NICE-SLAM ``traj.txt`` (16 numbers per line, blank lines
    left out) and {pose index: error} for the lines that hold no pose (their poses are NaN), so that a
    reader can fail or skip just those frames. Each error names the file and line."""
    if not path.is_file():
        raise DataError(f"{path}: trajectory file is missing")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise DataError(f"{path}: cannot read the trajectory file ({e})") from e
    poses, errors = [], {}
    for k, line in enumerate(text.splitlines()):
        if not line.strip():
            continue
        try:
            vals = np.array(line.split(), dtype=np.float64)
        except ValueError as e:
            errors[len(poses)] = f"{path}:{k + 1}: non-numeric pose ({e})"
            vals = np.full(16, np.nan)
        if vals.size != 16:
            errors[len(poses)] = (
                f"{path}:{k + 1}: expected 16 numbers (a row-major 4x4 pose), found {vals.size}"
            )
            vals = np.full(16, np.nan)
        poses.append(vals.reshape(4, 4))
    if not poses:
        raise DataError(f"{path}: trajectory file holds no poses")
    return np.stack(poses), errors


def read_traj(path: Path) -> np.ndarray:
    """[N, 4, 4] camera-to-world poses from a NICE-SLAM ``traj.txt``; the first bad line is a
    :class:`DataError` naming the file and line."""
    poses, errors = read_traj_lines(path)
    if errors:
        raise DataError(bad_lines_message(errors))
    return poses


def beyond_trajectory(path: Path, poses: int, n: int) -> str | None:
    """Why frame number ``n`` has no pose in a trajectory file of ``poses`` lines (line i is frame i); None
    when it has one."""
    return None if n < poses else f"no pose: {path.name} has poses for frames 0 to {poses - 1} only"


def bad_lines_message(errors: dict[int, str]) -> str:
    """The first bad line's error, and how many more there are."""
    first = errors[min(errors)]
    return first if len(errors) == 1 else f"{first} (and {len(errors) - 1} more bad lines)"


def list_replica_frames(results: Path) -> list[tuple[int, Path, Path]]:
    """(frame number, rgb path, depth path) sorted by number, for the ``results/frame*`` images and the
    ``results/depth*.png`` images. A depth image without its colour image gets the colour file's expected
    name (the other frames' suffix), which the base class then reports as missing rather than the frame
    disappearing without a word."""
    rgbs = {frame_number(p.stem): p for p in results.glob("frame*") if p.suffix.lower() in _RGB_SUFFIXES}
    suffix = next(iter(rgbs.values())).suffix if rgbs else ".jpg"
    out = [(n, p, results / f"depth{p.stem[len('frame') :]}.png") for n, p in rgbs.items()]
    for d in results.glob("depth*.png"):
        if d.stem[len("depth") :].isdigit() and frame_number(d.stem) not in rgbs:
            out.append((frame_number(d.stem), results / f"frame{d.stem[len('depth') :]}{suffix}", d))
    out.sort(key=lambda t: t[0])
    return out


class ReplicaDataset(RGBDDataset):
    kind = "replica"
    depth_scale_default = 6553.5
    up_axis = (0.0, 0.0, 1.0)
    up_axis_source = "the Replica layout (its meshes' world is z-up)"
    # Replica's renders agree with cam_params.json read with ogscene3d's pixel centres (+0.5): between
    # frames of NICE-SLAM's room0, depth reprojects best as read, worse with cx or cy shifted by half a
    # pixel either way (docs/results.md, "Dataset checks"; benchmarks/pixel_centers.py)
    pixel_centers_default = "half"
    layout_markers = ("results/", "traj.txt")

    def __init__(self, root: Path, config: DataConfig, segments_dir: Path | None = None) -> None:
        root = Path(root)
        results = root / "results"
        if not results.is_dir():
            raise DataError(f"{root}: no results/ folder (Replica NICE-SLAM layout)")
        frames = list_replica_frames(results)
        if not frames:
            raise DataError(f"{results}: no frame*.jpg / frame*.png images")
        traj_path = root / "traj.txt"
        poses, bad_lines = read_traj_lines(traj_path)
        if bad_lines and config.on_bad_frame != "skip":
            # found now rather than when mapping reaches the frame; under skip only those frames are left out
            raise DataError(
                f"{bad_lines_message(bad_lines)}; set data.on_bad_frame: skip to leave those frames out"
            )
        K, size = None, None
        cam = find_cam_params(root)
        if cam is not None:
            K, scale, size = read_cam_params(cam)
            if scale is not None:
                self.depth_scale_default = scale
        records = [
            FrameRecord(
                name=rgb.stem,
                rgb_path=rgb,
                depth_path=depth,
                pose=poses[n] if n < len(poses) else None,
                pose_source=f"{traj_path}:{n + 1}",
                pose_error=bad_lines.get(n),
                timestamp=float(n),
                lacks=beyond_trajectory(traj_path, len(poses), n),
            )
            for n, rgb, depth in frames
        ]
        if K is None and config.intrinsics is None:
            raise DataError(
                f"{root}: cam_params.json not found here or in the parent folder; "
                "give data.intrinsics = [fx, fy, cx, cy]"
            )
        super().__init__(root, records, K, config, segments_dir)
        if size is not None and config.intrinsics is None:
            assert cam is not None
            self.check_image_size(size, cam)
