"""Run folders and ground truth written for the evaluation tests, and the CLI call they share."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from dataset_files import _png, _rgb
from plyfile import PlyData, PlyElement

from ogscene3d import cli

GAUSSIAN_DTYPE = (
    [(n, "<f4") for n in ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity")]
    + [(f"scale_{i}", "<f4") for i in range(3)]
    + [(f"rot_{i}", "<f4") for i in range(4)]
    + [("label", "<i4"), ("confidence", "<f4")]
)

# the label-fusion wall of the 2D evaluation tests
W, H = 32, 24
K = np.array([[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]])  # ogscene3d's (pixel centres at +0.5)
# as the datasets' files write it (pixel centres counted from 0)
K_FILE = K - np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])
Z = 0.6  # metres: label-fusion's bit-shifted uint16 depth reaches 0.82 m at most
SHIFTS = (0.0, 0.025, 0.06)  # camera x per frame (no pixel centre on the wall's class boundary)


def _pose(tx: float) -> np.ndarray:
    p = np.eye(4)
    p[0, 3] = tx
    return p


def _left_right(tx: float, left: int, right: int, w: int = W, h: int = H) -> np.ndarray:
    """Class image of a wall at Z whose world x < 0 half is ``left`` and the other half ``right``."""
    u = (np.arange(w) + 0.5) * (W / w)  # pixel centres in the WxH camera
    world_x = (u - K[0, 2]) / K[0, 0] * Z + tx
    row = np.where(world_x < 0, left, right)
    return np.repeat(row[None], h, axis=0)


def _write_ply(path, arr, extra=()):
    PlyData([PlyElement.describe(arr, "vertex"), *extra], byte_order="<").write(str(path))


def _main(argv, monkeypatch):
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["ogscene3d.commands.eval"])
    return cli.main(argv)


def _run_from_ground_truth(gt, run, scale=0.02):
    """A 'perfect' run: a Gaussian per GT point, labelled 100 + its instance id, tagged by class."""
    n = gt.points.shape[0]
    g = np.zeros(n, dtype=GAUSSIAN_DTYPE)
    g["x"], g["y"], g["z"] = gt.points.T
    g["opacity"] = 4.0
    g["rot_0"] = 1.0
    for i in range(3):
        g[f"scale_{i}"] = np.log(scale)
    g["label"] = gt.instances + 100
    g["confidence"] = 0.9
    run.mkdir()
    _write_ply(run / "gaussians.ply", g)
    nodes = [{"id": i + 100, "tag": gt.class_names[c]} for i, c in gt.instance_classes.items()]
    edges = [{"source": s + 100, "target": o + 100, "relation": r} for s, r, o in gt.relations]
    (run / "graph.json").write_text(json.dumps({"version": 1, "nodes": nodes, "edges": edges}))


def make_labelfusion(root: Path, shifts: Sequence[float] = SHIFTS) -> Path:
    """Frames (camera x ``shifts``) of a wall whose left half is class 8 and right half class 22 (segm
    value = id * 6)."""
    root.mkdir(parents=True)
    np.savetxt(root / "camera-intrinsics.color.txt", K_FILE)
    for i, tx in enumerate(shifts):
        _png(root / f"frame-{i:06d}.color.png", _rgb(H, W, i))
        _png(root / f"frame-{i:06d}.depth.png", np.full((H, W), int(Z * 1e4) << 3, np.uint16))
        np.savetxt(root / f"frame-{i:06d}.pose.txt", _pose(tx))
        _png(root / f"frame-{i:06d}.segm.png", (_left_right(tx, 8, 22) * 6).astype(np.uint8))
    return root


def write_wall_run(run: Path, labels: tuple[int, int] = (3, 7), graph: dict | None = None) -> Path:
    """A run whose Gaussians tile the wall: scene label ``labels[0]`` where x < 0, ``labels[1]`` elsewhere."""
    xs, ys = np.meshgrid(np.arange(-0.4, 0.46, 0.01), np.arange(-0.3, 0.31, 0.01))
    n = xs.size
    g = np.zeros(n, dtype=GAUSSIAN_DTYPE)
    g["x"], g["y"], g["z"] = xs.ravel(), ys.ravel(), Z
    g["opacity"] = 4.0
    g["rot_0"] = 1.0
    for i in range(3):
        g[f"scale_{i}"] = np.log(0.006)
    g["label"] = np.where(xs.ravel() < 0, labels[0], labels[1])
    g["confidence"] = 0.9
    run.mkdir(parents=True)
    _write_ply(run / "gaussians.ply", g)
    if graph is not None:
        (run / "graph.json").write_text(json.dumps(graph))
    return run
