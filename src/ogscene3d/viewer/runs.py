"""Reading a saved run directory for browsing (``ogscene3d-live RUN_DIR``).

Only file formats are used here (README "File formats"): ``gaussians.ply`` through plyfile, ``graph.json``,
``timings.json``, ``config.yaml`` and, when present, the memory keyframe poses in ``map.npz``. Nothing
from the mapper is imported, so a run can be browsed wherever the files are.
"""

from __future__ import annotations

import json
import logging
import zipfile
import zlib
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


def _check_node(p: Path, i: int, node: object) -> None:
    """DataError naming the file, the node and the field unless ``node`` has an integer id and a finite
    3-vector center (the viewer places every node at its center)."""
    if not isinstance(node, dict) or "id" not in node or "center" not in node:
        raise DataError(f"{p}: node {i} lacks 'id' or 'center'")
    nid = node["id"]
    if not isinstance(nid, int) or isinstance(nid, bool):
        raise DataError(f"{p}: node {i} field 'id' must be an integer, got {nid!r:.60}")
    center = node["center"]
    numbers = isinstance(center, list) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in center
    )
    if not numbers or len(center) != 3:
        raise DataError(f"{p}: node {nid} has a bad center {center!r:.80} (field 'center': 3 numbers)")
    if not np.isfinite(np.asarray(center, dtype=np.float64)).all():
        raise DataError(f"{p}: node {nid} has a non-finite center {center!r:.80} (field 'center')")


def read_graph_json(path: str | Path) -> dict:
    """Read graph.json and check its structure (nodes need an integer id and a finite 3-vector center;
    edges a source and target among the node ids). DataError naming the file and the field."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DataError(f"{p}: cannot read graph JSON ({e})") from e
    if not isinstance(doc, dict) or not isinstance(doc.get("nodes", []), list):
        raise DataError(f"{p}: expected an object with a 'nodes' list")
    nodes = doc.get("nodes", [])
    for i, node in enumerate(nodes):
        _check_node(p, i, node)
    ids = {n["id"] for n in nodes}
    edges = doc.get("edges", [])
    if not isinstance(edges, list):
        raise DataError(f"{p}: 'edges' must be a list")
    for i, e in enumerate(edges):
        if not isinstance(e, dict) or not _known(e.get("source"), ids) or not _known(e.get("target"), ids):
            raise DataError(f"{p}: edge {i} does not join two known nodes (fields 'source', 'target')")
    return {"version": doc.get("version", 1), "nodes": nodes, "edges": edges}


def _known(node_id: object, ids: set[int]) -> bool:
    # an unhashable id (a list) cannot be looked up in the set: it is simply not a known node
    return isinstance(node_id, int) and not isinstance(node_id, bool) and node_id in ids


def _read_timings(path: Path) -> dict:
    """timings.json as a dict; {} with a warning when it is unreadable or not an object (it only feeds
    the timings panel, so a bad file must not stop browsing)."""
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        log.warning("%s: unreadable (%s); no timings shown", path, e)
        return {}
    if not isinstance(doc, dict):
        log.warning("%s: expected a JSON object, got %s; no timings shown", path, type(doc).__name__)
        return {}
    return doc


def _run_counts(timings: dict, path: Path) -> dict[str, float]:
    """frames / keyframes / labels from timings.json's ``counts`` (numbers only; others warned about)."""
    counts = timings.get("counts", {})
    if not isinstance(counts, dict):
        log.warning("%s: field 'counts' is not an object; no counts shown", path)
        return {}
    out: dict[str, float] = {}
    for key in ("frames", "keyframes", "labels"):
        v = counts.get(key)
        if isinstance(v, int | float) and not isinstance(v, bool):
            out[key] = v
        elif v is not None:
            log.warning("%s: field 'counts.%s' is not a number (%r); not shown", path, key, v)
    return out


def _read_trajectory(path: Path) -> np.ndarray:
    """The memory keyframes' camera-to-world poses [T,4,4] from map.npz, in keyframe order; [0,4,4] with
    a warning when the file is unreadable (it is optional: it only draws the camera path)."""
    empty = np.zeros((0, 4, 4))
    if not path.is_file():
        return empty
    try:
        with np.load(path, allow_pickle=False) as z:
            if "mem_pose" not in z.files or "mem_keyframe" not in z.files:
                return empty
            poses = np.asarray(z["mem_pose"], dtype=np.float64)
            keyframes = np.asarray(z["mem_keyframe"])
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as e:
        # a run cut short mid-write leaves a truncated zip (BadZipFile) or member (zlib.error, EOFError)
        log.warning("%s: unreadable (%s: %s); no keyframe poses shown", path, type(e).__name__, e)
        return empty
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or keyframes.shape != (len(poses),):
        log.warning(
            "%s: fields 'mem_pose' %s / 'mem_keyframe' %s are not [T,4,4] / [T]; no keyframe poses shown",
            path,
            poses.shape,
            keyframes.shape,
        )
        return empty
    ok = np.isfinite(poses).all(axis=(1, 2))
    if not ok.all():
        log.warning("%s: %d keyframe pose(s) with non-finite entries left out", path, int((~ok).sum()))
    order = np.argsort(keyframes[ok], kind="stable")
    return poses[ok][order]


def _read_up(path: Path, trajectory: np.ndarray) -> np.ndarray | None:
    """The run's up direction: its config's graph.up_axis, or where that stayed auto (chosen from tracked
    cameras during the run) the keyframe cameras' up direction."""
    if not path.is_file():
        return None
    import yaml

    from ..up_axis import CameraUp, is_auto

    try:
        doc = yaml.safe_load(path.read_text())
        value = doc["graph"]["up_axis"]
        if is_auto(value):
            cams = CameraUp()
            for pose in trajectory:
                cams.add(pose)
            return cams.estimate()
        up = np.asarray(value, dtype=np.float64)
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
    timings = _read_timings(root / "timings.json")
    trajectory = _read_trajectory(root / "map.npz")
    counts: dict[str, float] = {"gaussians": len(arrays["means"])}
    counts.update(_run_counts(timings, root / "timings.json"))
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
    return snap, RunInfo(path=root, up=_read_up(root / "config.yaml", trajectory))


__all__ = ["RunInfo", "load_run", "read_gaussians_ply", "read_graph_json"]
