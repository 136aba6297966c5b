"""A small run folder and scene written for the viewer and export tests."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from ogscene3d.gaussians import GaussianMap
from ogscene3d.viewer.snapshot import (
    MapSnapshot,
)

# Object colours of the test scene: saturated, so that a screenshot can be checked for them.
GREEN = (0.1, 0.85, 0.1)


BLUE = (0.1, 0.15, 0.95)


def make_scene(n_per_object: int = 400, seed: int = 0, objects: int = 3) -> MapSnapshot:
    """A small scene: ``objects`` flat-ish blobs (alternately green and blue) on the x axis, one label
    each, a graph node per object, "next to" edges between neighbours and a short camera trajectory."""
    rng = np.random.default_rng(seed)
    means, colors, labels, nodes = [], [], [], []
    for k in range(objects):
        c = np.array([1.2 * k, 0.0, 0.0])
        m = c + rng.normal(size=(n_per_object, 3)) * np.array([0.25, 0.25, 0.05])
        means.append(m)
        colors.append(np.tile(GREEN if k % 2 == 0 else BLUE, (n_per_object, 1)))
        labels.append(np.full(n_per_object, k))
        nodes.append(
            {
                "id": k,
                "label": k,
                "tag": ["sofa", "table", "lamp", "shelf"][k % 4],
                "caption": f"a test object number {k}",
                "confidence": 0.5 + 0.1 * k,
                "center": c.tolist(),
                "bbox_min": (c - 0.5).tolist(),
                "bbox_max": (c + 0.5).tolist(),
                "num_gaussians": n_per_object,
            }
        )
    means = np.concatenate(means)
    n = len(means)
    edges = [{"source": k, "target": k + 1, "relation": "next to", "score": 0.5} for k in range(objects - 1)]
    traj = np.tile(np.eye(4), (5, 1, 1))
    traj[:, 0, 3] = np.linspace(-1.0, 1.0, 5)
    traj[:, 2, 3] = -3.0
    return MapSnapshot(
        means=means,
        quats=np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
        scales=np.full((n, 3), 0.04),
        opacities=np.full(n, 0.95),
        colors=np.concatenate(colors),
        labels=np.concatenate(labels),
        confidences=rng.random(n),
        trajectory=traj,
        pose=traj[-1],
        K=np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]]),
        image=np.full((120, 160, 3), 128, np.uint8),
        graph={"version": 1, "nodes": nodes, "edges": edges},
        counts={"frames": 5, "keyframes": 5},
        timings={"init": 1.5, "optimize": 20.0},
        map_rev=objects,
        status="test",
    )


def _write_run(path: Path, snap: MapSnapshot) -> Path:
    gm = GaussianMap("cpu")
    gm.append(
        torch.from_numpy(snap.means),
        torch.from_numpy(snap.colors),
        torch.from_numpy(np.log(snap.scales)),
        labels=torch.from_numpy(snap.labels),
        confidences=torch.from_numpy(snap.confidences),
        opacity_logits=torch.logit(torch.from_numpy(snap.opacities)),
    )
    path.mkdir(parents=True, exist_ok=True)
    gm.export_ply(path / "gaussians.ply")
    (path / "graph.json").write_text(json.dumps(snap.graph))
    (path / "config.yaml").write_text("graph:\n  up_axis: [0.0, -1.0, 0.0]\n")
    return path
