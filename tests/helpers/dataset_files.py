"""Dataset folders and frame files written for the tests (PNG, RGB, poses, a tiny Replica scene), and the
reprojection check."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from ogscene3d.frame import Frame


def reprojection_error(fa: Frame, fb: Frame, step: int = 4) -> tuple[float, float, int]:
    """Back-project frame a's depth, move it with the poses into frame b, compare with b's depth.

    Returns (median |depth difference| in m, fraction within 5 cm, number of compared pixels).
    """
    pts = fa.camera.backproject(fa.depth)[::step, ::step].reshape(-1, 3)
    pts = pts[fa.depth[::step, ::step].reshape(-1) > 0].astype(np.float64)
    world = pts @ fa.pose[:3, :3].T + fa.pose[:3, 3]
    w2c = np.linalg.inv(fb.pose)
    pc = world @ w2c[:3, :3].T + w2c[:3, 3]
    z = pc[:, 2]
    front = z > 0.1
    pc, z = pc[front], z[front]
    # pixel (x, y) has its centre at (x + 0.5, y + 0.5) in K's frame
    u = np.floor(fb.K[0, 0] * pc[:, 0] / z + fb.K[0, 2]).astype(int)
    v = np.floor(fb.K[1, 1] * pc[:, 1] / z + fb.K[1, 2]).astype(int)
    inside = (u >= 0) & (v >= 0) & (u < fb.width) & (v < fb.height)
    db = fb.depth[v[inside], u[inside]]
    ok = db > 0
    diff = np.abs(db[ok] - z[inside][ok])
    return float(np.median(diff)), float((diff < 0.05).mean()), int(ok.sum())


def _png(path: Path, img: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), img)
    return path


def _rgb(h: int, w: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, (h, w, 3), dtype=np.uint8)


def _pose(tx: float = 0.0) -> np.ndarray:
    p = np.eye(4)
    p[0, 3] = tx
    return p


def make_replica(root: Path, n: int = 3, w: int = 32, h: int = 24, cam_in_parent: bool = False) -> Path:
    """A tiny Replica-layout scene: fronto-parallel wall at 2 m, camera stepping 0.1 m in x."""
    scene = root / "scene"
    for i in range(n):
        _png(scene / "results" / f"frame{i:06d}.jpg", _rgb(h, w, i))
        _png(scene / "results" / f"depth{i:06d}.png", np.full((h, w), round(2.0 * 6553.5), np.uint16))
    (scene / "traj.txt").write_text(
        "".join(" ".join(map(str, _pose(0.1 * i).ravel())) + "\n" for i in range(n))
    )
    cam = {"camera": {"w": w, "h": h, "fx": 20.0, "fy": 20.0, "cx": w / 2, "cy": h / 2, "scale": 6553.5}}
    (root if cam_in_parent else scene).joinpath("cam_params.json").write_text(json.dumps(cam))
    return scene
