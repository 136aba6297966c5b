"""Exports of a saved run for other tools (``ogscene3d export``): coloured point clouds, one per scene-graph
node, and the graph as GraphML with the nodes' boxes.

The run's ``gaussians.ply`` is a 3DGS file (SH degree 0: colour as ``f_dc_*``), which point-cloud tools
(Open3D, CloudCompare, MeshLab) show grey because they look for ``red``/``green``/``blue``. The clouds
written here have one vertex per Gaussian mean with standard ``uchar`` ``red``/``green``/``blue`` (the
Gaussian colour or its semantic label's colour) and the ``label`` (int) and ``confidence`` (float)
properties. Only file formats are read (gaussians.ply, graph.json, through :mod:`ogscene3d.runs`), so any run
directory can be exported.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .colors import label_colors
from .errors import DataError
from .graph.scenegraph import SceneGraph
from .runs import RunFolder
from .runs.gaussians_ply import read_gaussians_ply

log = logging.getLogger(__name__)

COLOR_SOURCES = ("rgb", "semantic")

_CLOUD_DTYPE = [
    ("x", "<f4"),
    ("y", "<f4"),
    ("z", "<f4"),
    ("red", "u1"),
    ("green", "u1"),
    ("blue", "u1"),
    ("label", "<i4"),
    ("confidence", "<f4"),
]


@dataclass
class ExportResult:
    """What :func:`export_run` wrote: the cloud, the per-node clouds (by node id) and the GraphML file."""

    cloud: Path | None = None
    nodes: dict[int, Path] = field(default_factory=dict)
    graphml: Path | None = None

    def paths(self) -> list[Path]:
        out = [self.cloud] if self.cloud else []
        out += [self.nodes[i] for i in sorted(self.nodes)]
        return out + ([self.graphml] if self.graphml else [])


def point_colors(arrays: dict[str, np.ndarray], colors: str) -> np.ndarray:
    """[N,3] uint8 vertex colours: the Gaussians' own colour (``"rgb"``) or their label's colour as the
    viewer draws it (``"semantic"``; unlabelled Gaussians grey)."""
    if colors == "rgb":
        rgb = arrays["colors"]
    elif colors == "semantic":
        rgb = label_colors(arrays["labels"])
    else:
        raise ValueError(f"colors must be one of {COLOR_SOURCES}, got {colors!r}")
    return np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)


def write_point_cloud(
    path: str | Path, points: np.ndarray, rgb: np.ndarray, labels: np.ndarray, confidences: np.ndarray
) -> Path:
    """Write a binary PLY point cloud (atomically): float x/y/z, uchar red/green/blue, int label, float
    confidence. ``points`` [N,3], ``rgb`` [N,3] uint8, ``labels`` [N], ``confidences`` [N]."""
    from plyfile import PlyData, PlyElement

    n = len(points)
    for name, arr, shape in (
        ("rgb", rgb, (n, 3)),
        ("labels", labels, (n,)),
        ("confidences", confidences, (n,)),
    ):
        if np.shape(arr) != shape:
            raise ValueError(f"write_point_cloud: {name} must have shape {shape}, got {np.shape(arr)}")
    vert = np.empty(n, dtype=_CLOUD_DTYPE)
    for k, axis in enumerate("xyz"):
        vert[axis] = points[:, k]
    for k, channel in enumerate(("red", "green", "blue")):
        vert[channel] = rgb[:, k]
    vert["label"] = labels
    vert["confidence"] = confidences
    path = Path(path)
    with atomic_path(path) as tmp:
        PlyData([PlyElement.describe(vert, "vertex")], text=False).write(str(tmp))
    return path


def _slug(text: str, limit: int = 40) -> str:
    """A file-name-safe form of a node tag ("coffee table" -> "coffee_table")."""
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")[:limit].strip("_")


def node_file_name(node_id: int, tag: str) -> str:
    """``node_<id>_<tag>.ply`` (``node_<id>.ply`` for an untagged node); ids are zero-padded so that a
    directory listing follows the node order."""
    slug = _slug(tag)
    return f"node_{node_id:04d}_{slug}.ply" if slug else f"node_{node_id:04d}.ply"


def export_run(
    run_dir: str | Path,
    out_dir: str | Path | None = None,
    *,
    colors: str = "rgb",
    cloud: bool = True,
    nodes: bool = True,
    graphml: bool = True,
    min_opacity: float = 0.0,
) -> ExportResult:
    """Export a run directory into ``out_dir`` (default ``<run_dir>/export``).

    ``cloud``: ``points_<colors>.ply``, every Gaussian as a coloured point; ``nodes``: ``nodes/`` with
    one such cloud per scene-graph node (its Gaussians are those carrying the node's label); ``graphml``:
    ``graph.graphml`` (node boxes included, needs networkx). Gaussians with an opacity below
    ``min_opacity`` are left out of the clouds. DataError when the run lacks a file an export needs.
    """
    if colors not in COLOR_SOURCES:
        raise ValueError(f"colors must be one of {COLOR_SOURCES}, got {colors!r}")
    if not 0.0 <= min_opacity <= 1.0:
        raise ValueError(f"min_opacity must be in [0, 1], got {min_opacity}")
    root = Path(run_dir)
    if not root.is_dir():
        raise DataError(f"{root}: run directory does not exist")
    out = Path(out_dir) if out_dir is not None else root / "export"
    result = ExportResult()
    graph = None
    if nodes or graphml:
        graph = SceneGraph.load(root)  # DataError naming the run when graph.json is missing
    if cloud or nodes:
        arrays = read_gaussians_ply(RunFolder(root).gaussians).arrays()
        keep = arrays["opacities"] >= min_opacity
        arrays = {k: v[keep] for k, v in arrays.items()}
        rgb = point_colors(arrays, colors)
        if cloud:
            result.cloud = write_point_cloud(
                out / f"points_{colors}.ply", arrays["means"], rgb, arrays["labels"], arrays["confidences"]
            )
        if nodes:
            assert graph is not None
            for nid in sorted(graph.nodes):
                node = graph.nodes[nid]
                sel = arrays["labels"] == node.label
                if not sel.any():
                    log.warning(
                        "export: node #%d (label %d) has no Gaussians in gaussians.ply", nid, node.label
                    )
                    continue
                result.nodes[nid] = write_point_cloud(
                    out / "nodes" / node_file_name(nid, node.tag),
                    arrays["means"][sel],
                    rgb[sel],
                    arrays["labels"][sel],
                    arrays["confidences"][sel],
                )
    if graphml:
        assert graph is not None
        result.graphml = out / "graph.graphml"
        graph.save_graphml(result.graphml)
    return result


__all__ = [
    "COLOR_SOURCES",
    "ExportResult",
    "export_run",
    "node_file_name",
    "point_colors",
    "write_point_cloud",
]
