"""Reading a saved run directory for browsing (``ogscene3d-live RUN_DIR``).

Only file formats are used here (DESIGN.md "Files"): ``gaussians.ply`` through plyfile, ``graph.json``,
``timings.json``, ``config.yaml`` and, when present, the memory keyframe poses in ``map.npz``. Nothing
from the mapper is imported, so a run can be browsed wherever the files are.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError
from .snapshot import MapSnapshot, timings_ms_per_keyframe

log = logging.getLogger(__name__)

SH_C0 = 0.28209479177387814
_REQUIRED = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
_REQUIRED += [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]


@dataclass
class RunInfo:
    """What else a run directory says: the world up vector (from config.yaml) and its path."""

    path: Path
    up: np.ndarray | None


def read_gaussians_ply(path: str | Path) -> dict[str, np.ndarray]:
    """Read a 3DGS PLY (SH degree 0, optional ``label``/``confidence``) into snapshot arrays.

    Returns means [N,3], quats [N,4] wxyz, scales [N,3] (exp of the stored log scales), opacities [N]
    (sigmoid of the stored logits), colors [N,3] in [0,1] (from f_dc), labels [N] int32 (-1 when the
    file has none), confidences [N] float32 (0 when none). Raises DataError on a missing or corrupt file.
    """
    from plyfile import PlyData

    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: Gaussian PLY does not exist")
    try:
        ply = PlyData.read(str(p))
        v = ply["vertex"].data
    except Exception as e:  # plyfile raises several unrelated exception types on corrupt input
        raise DataError(f"{p}: cannot read PLY ({type(e).__name__}: {e})") from e
    names = v.dtype.names or ()
    missing = [k for k in _REQUIRED if k not in names]
    if missing:
        raise DataError(f"{p}: PLY vertex lacks the 3DGS properties {missing}")
    n = len(v)

    def cols(*keys: str) -> np.ndarray:
        return np.stack([np.asarray(v[k], dtype=np.float32) for k in keys], axis=1).reshape(n, len(keys))

    with np.errstate(over="ignore"):
        scales = np.exp(cols("scale_0", "scale_1", "scale_2").astype(np.float64)).astype(np.float32)
        opac = (1.0 / (1.0 + np.exp(-np.asarray(v["opacity"], dtype=np.float64)))).astype(np.float32)
    return {
        "means": cols("x", "y", "z"),
        "quats": cols("rot_0", "rot_1", "rot_2", "rot_3"),
        "scales": scales,
        "opacities": opac,
        "colors": np.clip(cols("f_dc_0", "f_dc_1", "f_dc_2") * SH_C0 + 0.5, 0.0, 1.0),
        "labels": np.asarray(v["label"], dtype=np.int32) if "label" in names else np.full(n, -1, np.int32),
        "confidences": np.asarray(v["confidence"], dtype=np.float32)
        if "confidence" in names
        else np.zeros(n, np.float32),
    }


def read_graph_json(path: str | Path) -> dict:
    """Read graph.json and check its structure (nodes need id and center; edges source/target)."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DataError(f"{p}: cannot read graph JSON ({e})") from e
    if not isinstance(doc, dict) or not isinstance(doc.get("nodes", []), list):
        raise DataError(f"{p}: expected an object with a 'nodes' list")
    nodes = doc.get("nodes", [])
    for i, node in enumerate(nodes):
        if not isinstance(node, dict) or "id" not in node or "center" not in node:
            raise DataError(f"{p}: node {i} lacks 'id' or 'center'")
        c = np.asarray(node["center"], dtype=np.float64) if isinstance(node["center"], list) else None
        if c is None or c.shape != (3,):
            raise DataError(f"{p}: node {node.get('id')} has a bad center {node['center']!r}")
    ids = {n["id"] for n in nodes}
    edges = doc.get("edges", [])
    if not isinstance(edges, list):
        raise DataError(f"{p}: 'edges' must be a list")
    for i, e in enumerate(edges):
        if not isinstance(e, dict) or e.get("source") not in ids or e.get("target") not in ids:
            raise DataError(f"{p}: edge {i} does not join two known nodes")
    return {"version": doc.get("version", 1), "nodes": nodes, "edges": edges}


def _read_up(path: Path) -> np.ndarray | None:
    if not path.is_file():
        return None
    import yaml

    try:
        doc = yaml.safe_load(path.read_text())
        up = np.asarray(doc["graph"]["up_axis"], dtype=np.float64)
    except Exception:  # noqa: BLE001 - the up vector only orients the camera; a default is fine
        log.warning("%s: no readable graph.up_axis; using the viewer's default up direction", path)
        return None
    if up.shape != (3,) or not np.isfinite(up).all() or np.linalg.norm(up) == 0:
        return None
    return up / np.linalg.norm(up)


def load_run(run_dir: str | Path) -> tuple[MapSnapshot, RunInfo]:
    """Read a run directory into one snapshot (status "browse") plus its :class:`RunInfo`."""
    root = Path(run_dir)
    if not root.is_dir():
        raise DataError(f"{root}: run directory does not exist")
    ply = root / "gaussians.ply"
    if not ply.is_file():
        raise DataError(f"{root}: not a run directory (no gaussians.ply)")
    arrays = read_gaussians_ply(ply)
    graph = read_graph_json(root / "graph.json") if (root / "graph.json").is_file() else None
    timings: dict = {}
    tpath = root / "timings.json"
    if tpath.is_file():
        try:
            timings = json.loads(tpath.read_text())
        except (OSError, json.JSONDecodeError) as e:
            log.warning("%s: unreadable (%s); no timings shown", tpath, e)
    trajectory = np.zeros((0, 4, 4))
    npz = root / "map.npz"
    if npz.is_file():
        try:
            with np.load(npz, allow_pickle=False) as z:
                if "mem_pose" in z.files and "mem_keyframe" in z.files:
                    order = np.argsort(z["mem_keyframe"])
                    trajectory = np.asarray(z["mem_pose"], dtype=np.float64)[order]
        except (OSError, ValueError, EOFError) as e:
            log.warning("%s: unreadable (%s); no keyframe poses shown", npz, e)
    counts: dict[str, float] = {"gaussians": len(arrays["means"])}
    for key in ("frames", "keyframes", "labels"):
        if key in timings.get("counts", {}):
            counts[key] = timings["counts"][key]
    snap = MapSnapshot(
        **arrays,
        trajectory=trajectory,
        pose=trajectory[-1] if len(trajectory) else None,
        graph=graph,
        counts=counts,
        timings=timings_ms_per_keyframe(timings),
        map_rev=0,
        status=f"browsing {root.name}",
    )
    return snap, RunInfo(path=root, up=_read_up(root / "config.yaml"))


__all__ = ["RunInfo", "load_run", "read_gaussians_ply", "read_graph_json"]
