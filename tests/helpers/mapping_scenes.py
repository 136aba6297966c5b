"""Tiny scenes for the mapping tests: a two-object wall seen by a moving camera, as frames and as a
Replica-layout folder, and the common arguments of their runs."""

import json

import cv2
import numpy as np

from ogscene3d.config import load_config
from ogscene3d.frame import Frame
from ogscene3d.segmentation.precomputed import write_segments

W, H, F = 32, 24, 24.0


K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]], dtype=np.float32)


def _frame(i: int, ids: tuple[int, int] = (1, 2), with_segments: bool = True) -> Frame:
    """A fronto-parallel wall 2 m ahead: a red object left of x = 0 and a blue one right of it, seen from
    a camera shifted 20 cm per frame along x."""
    tx = 0.2 * i
    pose = np.eye(4)
    pose[0, 3] = tx
    u = (np.arange(W) + 0.5 - W / 2) / F * 2.0 + tx  # world x of each column on the wall
    left = np.broadcast_to(u[None, :] < 0, (H, W))
    rgb = np.where(left[..., None], np.array([200, 30, 30], np.uint8), np.array([30, 30, 200], np.uint8))
    seg = np.where(left, ids[0], ids[1]).astype(np.int32)
    return Frame(
        i,
        np.ascontiguousarray(rgb),
        np.full((H, W), 2.0, np.float32),
        K,
        pose,
        name=f"f{i}",
        segments=seg if with_segments else None,
        segment_scores={ids[0]: 0.97, ids[1]: 0.91},
    )


def _config(*overrides: str):
    return load_config(
        None,
        ["graph.enabled=false", "mapping.optimize.iters=2", "mapping.association.knn_radius=0.1", *overrides],
    )


def _replica_scene(root, frames: int = 3):
    """A tiny Replica-layout scene: a two-coloured wall 2 m ahead, camera moving 0.2 m per frame."""
    res = root / "results"
    res.mkdir(parents=True)
    f = 24.0
    cam = {"camera": {"w": W, "h": H, "fx": f, "fy": f, "cx": W / 2, "cy": H / 2, "scale": 6553.5}}
    (root / "cam_params.json").write_text(json.dumps(cam))
    lines = []
    for i in range(frames):
        pose = np.eye(4)
        pose[0, 3] = 0.2 * i
        lines.append(" ".join(f"{v:.6f}" for v in pose.reshape(-1)))
        u = (np.arange(W) + 0.5 - W / 2) / f * 2.0 + pose[0, 3]
        left = np.broadcast_to(u[None, :] < 0, (H, W))
        rgb = np.where(left[..., None], np.uint8([30, 30, 200]), np.uint8([200, 30, 30])).astype(np.uint8)
        cv2.imwrite(str(res / f"frame{i:06d}.jpg"), rgb)
        cv2.imwrite(str(res / f"depth{i:06d}.png"), np.full((H, W), round(2.0 * 6553.5), np.uint16))
        write_segments(
            root / "segs", f"frame{i:06d}", np.where(left, 1 + i, 10 + i), {1 + i: 0.95, 10 + i: 0.9}
        )
    (root / "traj.txt").write_text("\n".join(lines) + "\n")
    return root


def _common(scene, out):
    return ["--out", str(out), "--device", "cpu", "--no-progress", "--data", str(scene),
            "--segments", str(scene / "segs"), "--set", "mapping.optimize.iters=1",
            "--set", "graph.enabled=false",
            "--set", "mapping.association.knn_radius=0.1"]  # fmt: skip
