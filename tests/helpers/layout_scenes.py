"""RGB-D frames written in the dataset layouts users bring (ScanNet, Replica NICE-SLAM, Semantic-NeRF's
Replica, TUM, 7-Scenes), each as that format writes its files: its depth units, its pose files, its
intrinsics and their pixel-centre convention. The frames come from a synthetic scene (its world turned to the
format's own, e.g. z-up) or are tiny fabricated ones."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

#: the synthetic scenes' world (-y up) turned so that its up is z: (x, y, z) -> (x, z, -y)
Y_DOWN_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])

LAYOUTS = ("scannet", "replica", "semantic_nerf", "tum", "sevenscenes")


@dataclass
class Frames:
    """Frames to write: colour (uint8 RGB), depth (float metres), camera-to-world poses (OpenCV axes), K with
    pixel centres at +0.5 (ogscene3d's), and per frame the segments files (png, json) to copy, if any."""

    rgb: list[np.ndarray]
    depth: list[np.ndarray]
    poses: list[np.ndarray]
    K: np.ndarray
    segments: list[tuple[Path, Path | None]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.rgb)


def synthetic_frames(scene: Path, world: np.ndarray = Y_DOWN_TO_Z_UP) -> Frames:
    """The frames of a synthetic scene folder, their poses moved into ``world`` @ the scene's world."""
    from ogscene3d.datasets import open_dataset

    ds = open_dataset(scene)
    frames = list(ds)
    segs = [(scene / "segments" / f"{f.name}.png", scene / "segments" / f"{f.name}.json") for f in frames]
    poses = [world @ f.pose for f in frames]
    return Frames([f.rgb for f in frames], [f.depth for f in frames], poses, ds.K.copy(), segs)


def tiny_frames(n: int = 3, w: int = 32, h: int = 24) -> Frames:
    """``n`` frames of a wall 2 m ahead (random colours), the camera stepping 0.1 m along x."""
    rng = np.random.default_rng(0)
    poses = []
    for i in range(n):
        p = np.eye(4)
        p[0, 3] = 0.1 * i
        poses.append(p)
    K = np.array([[20.0, 0, w / 2], [0, 20.0, h / 2], [0, 0, 1]])
    return Frames(
        [rng.integers(0, 255, (h, w, 3), dtype=np.uint8) for _ in range(n)],
        [np.full((h, w), 2.0, np.float32) for _ in range(n)],
        poses,
        K,
    )


def _write(path: Path, img: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    assert cv2.imwrite(str(path), img)
    return path


def _raw(depth: np.ndarray, per_metre: float) -> np.ndarray:
    return np.round(depth * per_metre).astype(np.uint16)


def _opencv_K(K: np.ndarray) -> np.ndarray:
    """K with pixel centres at integers, as calibration files (ScanNet, TUM, 7-Scenes) write it."""
    out = np.asarray(K, dtype=np.float64).copy()
    out[:2, 2] -= 0.5
    return out


def _pose_lines(poses: list[np.ndarray]) -> str:
    """One row-major 4x4 per line (NICE-SLAM's traj.txt, Semantic-NeRF's traj_w_c.txt)."""
    return "".join(" ".join(f"{v:.9e}" for v in p.ravel()) + "\n" for p in poses)


def _segments(frames: Frames, out: Path, stems: list[str]) -> None:
    for (png, meta), stem in zip(frames.segments, stems):
        out.mkdir(parents=True, exist_ok=True)
        shutil.copy(png, out / f"{stem}.png")
        if meta is not None and meta.is_file():
            shutil.copy(meta, out / f"{stem}.json")


def write_layout(layout: str, root: Path, frames: Frames) -> Path:
    """Write ``frames`` in ``layout`` (one of :data:`LAYOUTS`) under ``root``; segments (when the frames
    have them) go to ``root/segments`` named by each frame's rgb stem. -> the folder to open."""
    root.mkdir(parents=True, exist_ok=True)
    n = len(frames)
    if layout == "scannet":  # SensReader's export: jpg colour, depth in mm, pose/N.txt, intrinsic/
        stems = [str(i) for i in range(n)]
        for i in range(n):
            _write(root / "color" / f"{i}.jpg", frames.rgb[i])
            _write(root / "depth" / f"{i}.png", _raw(frames.depth[i], 1000.0))
            (root / "pose").mkdir(exist_ok=True)
            np.savetxt(root / "pose" / f"{i}.txt", frames.poses[i])
        K4 = np.eye(4)
        K4[:3, :3] = _opencv_K(frames.K)
        (root / "intrinsic").mkdir(exist_ok=True)
        np.savetxt(root / "intrinsic" / "intrinsic_depth.txt", K4)
    elif layout == "replica":  # NICE-SLAM's: results/, traj.txt, cam_params.json (K read as it is)
        stems = [f"frame{i:06d}" for i in range(n)]
        for i in range(n):
            _write(root / "results" / f"frame{i:06d}.jpg", frames.rgb[i])
            _write(root / "results" / f"depth{i:06d}.png", _raw(frames.depth[i], 6553.5))
        (root / "traj.txt").write_text(_pose_lines(frames.poses))
        h, w = frames.depth[0].shape
        K = frames.K
        cam = {"w": w, "h": h, "fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "scale": 6553.5}
        (root / "cam_params.json").write_text(json.dumps({"camera": {k: float(v) for k, v in cam.items()}}))
    elif layout == "semantic_nerf":  # rgb/rgb_i.png, depth/depth_i.png (mm), traj_w_c.txt; K from the size
        stems = [f"rgb_{i}" for i in range(n)]
        for i in range(n):
            _write(root / "rgb" / f"rgb_{i}.png", frames.rgb[i])
            _write(root / "depth" / f"depth_{i}.png", _raw(frames.depth[i], 1000.0))
        (root / "traj_w_c.txt").write_text(_pose_lines(frames.poses))
    elif layout == "tum":  # rgb.txt, depth.txt, groundtruth.txt (quaternions); depth / 5000; no K file
        stamps = [100.0 + 0.1 * i for i in range(n)]
        stems = [f"{t:.6f}" for t in stamps]
        rgb_lines, depth_lines = ["# color images"], ["# depth maps"]
        gt = ["# timestamp tx ty tz qx qy qz qw"]
        for i, t in enumerate(stamps):
            _write(root / "rgb" / f"{t:.6f}.png", frames.rgb[i])
            _write(root / "depth" / f"{t + 0.004:.6f}.png", _raw(frames.depth[i], 5000.0))
            rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
            depth_lines.append(f"{t + 0.004:.6f} depth/{t + 0.004:.6f}.png")
            q = Rotation.from_matrix(frames.poses[i][:3, :3]).as_quat()  # x, y, z, w
            gt.append(f"{t + 0.002:.6f} " + " ".join(f"{v:.9f}" for v in (*frames.poses[i][:3, 3], *q)))
        (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
        (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
        (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    elif layout == "sevenscenes":  # frame-N.color.png, .depth.png (mm), .pose.txt, camera-intrinsics.txt
        stems = [f"frame-{i:06d}.color" for i in range(n)]
        for i in range(n):
            _write(root / f"frame-{i:06d}.color.png", frames.rgb[i])
            _write(root / f"frame-{i:06d}.depth.png", _raw(frames.depth[i], 1000.0))
            np.savetxt(root / f"frame-{i:06d}.pose.txt", frames.poses[i])
        np.savetxt(root / "camera-intrinsics.txt", _opencv_K(frames.K))
    else:
        raise ValueError(f"unknown layout {layout!r}")
    if frames.segments:
        _segments(frames, root / "segments", stems)
    return root


def tum_intrinsics(frames: Frames) -> list[float]:
    """``data.intrinsics`` for a TUM-layout folder of ``frames`` (TUM has no K file: read as OpenCV's)."""
    K = _opencv_K(frames.K)
    return [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])]


def frame_files(layout: str, root: Path, i: int) -> dict[str, Path]:
    """The colour, depth and pose files of frame ``i`` of a folder :func:`write_layout` wrote (TUM's and
    Replica's poses are lines of one file: not listed)."""
    if layout == "scannet":
        return {"colour": root / "color" / f"{i}.jpg", "depth": root / "depth" / f"{i}.png",
                "pose": root / "pose" / f"{i}.txt"}  # fmt: skip
    if layout == "replica":
        res = root / "results"
        return {"colour": res / f"frame{i:06d}.jpg", "depth": res / f"depth{i:06d}.png"}
    if layout == "semantic_nerf":
        return {"colour": root / "rgb" / f"rgb_{i}.png", "depth": root / "depth" / f"depth_{i}.png"}
    if layout == "tum":
        t = 100.0 + 0.1 * i
        return {"colour": root / "rgb" / f"{t:.6f}.png", "depth": root / "depth" / f"{t + 0.004:.6f}.png"}
    if layout == "sevenscenes":
        return {"colour": root / f"frame-{i:06d}.color.png", "depth": root / f"frame-{i:06d}.depth.png",
                "pose": root / f"frame-{i:06d}.pose.txt"}  # fmt: skip
    raise ValueError(f"unknown layout {layout!r}")


def garble_pixels(path: Path) -> Path:
    """Garble a PNG's compressed pixels, leaving its header and end marker sound: the file passes the checks
    made when a dataset opens, and fails only when the frame is decoded (a bad frame found mid-run)."""
    data = bytearray(path.read_bytes())
    start = data.index(b"IDAT") + 4
    data[start : start + 8] = b"\xff" * 8
    path.write_bytes(bytes(data))
    return path
