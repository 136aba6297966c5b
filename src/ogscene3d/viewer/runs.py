"""Reading a saved run directory for browsing (``ogscene3d-live RUN_DIR``).

Only file formats are used here, read by their owner :mod:`ogscene3d.runs` (docs/formats.md):
``gaussians.ply``, ``graph.json``, ``timings.json``, ``config.yaml`` and, when present, the memory keyframe
poses in ``map.npz``. Nothing from the mapper is imported, so a run can be browsed wherever the files are.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..runs import RunFolder, read_timings, recorded_up
from ..runs.gaussians_ply import read_gaussians_ply
from ..runs.graph_json import read_graph_json
from ..runs.map_npz import read_map_npz
from .snapshot import MapSnapshot, timings_ms_per_keyframe

log = logging.getLogger(__name__)



@dataclass
class RunInfo:
    """What else a run directory says: the world up vector (from config.yaml) and its path."""

    path: Path
    up: np.ndarray | None


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
        z = read_map_npz(path, ("mem_pose", "mem_keyframe"))
    except DataError as e:
        # a run cut short mid-write leaves a truncated zip or member
        log.warning("%s; no keyframe poses shown", e)
        return empty
    if "mem_pose" not in z or "mem_keyframe" not in z:
        return empty
    poses = np.asarray(z["mem_pose"], dtype=np.float64)
    keyframes = np.asarray(z["mem_keyframe"])
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


def load_run(run_dir: str | Path) -> tuple[MapSnapshot, RunInfo]:
    """Read a run directory into one snapshot (status "browse") plus its :class:`RunInfo`."""
    root = Path(run_dir)
    if not root.is_dir():
        raise DataError(f"{root}: run directory does not exist")
    folder = RunFolder(root)
    if not folder.gaussians.is_file():
        raise DataError(f"{root}: not a run directory (no gaussians.ply)")
    arrays = read_gaussians_ply(folder.gaussians).arrays()
    graph = read_graph_json(folder.graph, centers=True) if folder.graph.is_file() else None
    timings = read_timings(folder.timings)
    trajectory = _read_trajectory(folder.map)
    counts: dict[str, float] = {"gaussians": len(arrays["means"])}
    counts.update(_run_counts(timings, folder.timings))
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
    return snap, RunInfo(path=root, up=recorded_up(root, trajectory))


__all__ = ["RunInfo", "load_run"]
