"""``map.npz`` as a mapper checkpoint: the mapper's state written (:func:`write_checkpoint`) and restored
(:func:`restore_mapper`), reading its format version, and the one place that upgrades the checkpoints of
older versions to today's.

A checkpoint is the Gaussians (``GaussianMap.state_dict``, with the format ``version``) plus the arrays of
``Mapper.state()``, which gathers the ``state()`` of its parts (keyframe selector, pose-jump check,
timings, tracker, scene graph, memory views). From version 2 every mapper array below is always written;
a version-1 file may lack those added over its life, and :func:`upgrade` gives each its old meaning.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import DataError, OGSceneError
from ..gaussians import FIELDS
from ..runs.map_npz import NPZ_VERSION, corrupt_npz_message, read_map_npz
from .longterm import MemoryEntry
from .memory_files import load_view, manifest, read_manifest, remove_unreferenced, store_view

if TYPE_CHECKING:
    from .mapper import Mapper

log = logging.getLogger(__name__)

#: The arrays every version-2 checkpoint holds (the tracker's ``trk_*``, ``graph_state`` and the view lists
#: ``mem_*`` / ``recent_*`` are there only when the run has a tracker, a graph, or views).
REQUIRED = (
    "mapper_frames_seen",
    "mapper_next_index",
    "mapper_keyframe_count",
    "mapper_memory_cursor",
    "mapper_finalized",
    "mapper_rng",
    "mapper_source",
    "mapper_timings",
    "mapper_trajectory",
    "mapper_recent",
    "kf_since_last",
    "kf_last_pose",
    "posecheck_last_pose",
    "posecheck_last_index",
)


class CheckpointArrays(dict):
    """A checkpoint's arrays by name, readable where an opened npz is (``.files``, ``[name]``)."""

    @property
    def files(self) -> list[str]:
        return list(self)


def read_checkpoint(path: str | Path, seed: int | None = None) -> CheckpointArrays:
    """The mapper arrays of ``map.npz`` in today's format (the Gaussians are read by
    ``GaussianMap.load_npz``). ``seed``: the run's ``config.seed``, the random stream of a checkpoint
    that saved none.

    Raises:
        DataError: unreadable or damaged, written by a newer version, or not a mapper checkpoint.
    """
    p = Path(path)
    arrays = read_map_npz(p, lambda k: k not in FIELDS and k != "next_label")
    try:
        version = int(arrays.pop("version", 1))
    except (TypeError, ValueError) as e:
        raise DataError(corrupt_npz_message(p, e)) from e
    if version > NPZ_VERSION:
        raise DataError(
            f"{p}: written by a newer ogscene3d (checkpoint format {version}; this one reads up to "
            f"{NPZ_VERSION}): update ogscene3d to resume it"
        )
    if version < NPZ_VERSION:
        arrays = upgrade(arrays, version, p, seed)
    missing = [k for k in REQUIRED if k not in arrays]
    if missing:
        raise DataError(f"{p}: not a mapper checkpoint (missing {', '.join(repr(k) for k in missing)})")
    return CheckpointArrays(arrays)


def upgrade(arrays: dict[str, Any], version: int, path: Path, seed: int | None = None) -> dict[str, Any]:
    """A version-``version`` checkpoint's arrays in today's format: every legacy case is here.

    Version 1 grew over time; a file may lack (and then means):
    - ``mapper_next_index``: the dataset position, then counted by ``mapper_frames_seen``;
    - ``mapper_finalized``: not finalized; ``mapper_source``: no record of the frames (resumed unchecked);
    - ``mapper_timings``: times from zero; ``mapper_rng``: the random stream from ``seed``;
    - ``mapper_trajectory``: no tracked poses (written only under odometry); ``mapper_memory_cursor``: 0;
    - ``mapper_recent``: the first keyframes after the resume pair with memory views only;
    - ``posecheck_*``: no reference pose (the check starts at the next frame);
    - ``mem_file``: the memory views inline (``mem_rgb``, ``mem_depth``, ...), handed on as
      :class:`MemoryEntry` objects under ``mem_inline`` for the loader to restore.
    """
    out = dict(arrays)
    if version < 2:
        if "mapper_frames_seen" not in out:
            raise DataError(f"{path}: not a mapper checkpoint (missing 'mapper_frames_seen')")
        out.setdefault("mapper_next_index", out["mapper_frames_seen"])
        out.setdefault("mapper_finalized", np.array(False))
        out.setdefault("mapper_source", np.array("{}"))
        out.setdefault("mapper_timings", np.array("{}"))
        rng = np.random.default_rng(seed)
        out.setdefault("mapper_rng", np.array(json.dumps(rng.bit_generator.state)))
        out.setdefault("mapper_trajectory", np.zeros((0, 4, 4)))
        out.setdefault("mapper_memory_cursor", np.array(0))
        out.setdefault("mapper_recent", np.zeros(0, dtype=np.int64))
        out.setdefault("posecheck_last_pose", np.zeros((0, 4, 4)))
        out.setdefault("posecheck_last_index", np.array(-1))
        if "mem_file" not in out and "mem_keyframe" in out:
            out["mem_inline"] = _inline_views(out)
    return out


def _inline_views(arrays: dict[str, Any]) -> list[MemoryEntry]:
    """The memory views of a checkpoint from before they had their own files (removed from ``arrays``)."""
    scores = json.loads(str(arrays.pop("mem_scores")))
    mem = {k: arrays.pop(f"mem_{k}") for k in ("rgb", "depth", "K", "pose", "segments")}
    keyframes = arrays.pop("mem_keyframe")
    return [
        MemoryEntry(
            int(kf),
            mem["rgb"][i].copy(),
            mem["depth"][i].copy(),
            mem["K"][i].copy(),
            mem["pose"][i].copy(),
            mem["segments"][i].copy(),
            {int(k): float(v) for k, v in scores[i].items()},
        )
        for i, kf in enumerate(keyframes)
    ]


def mapper_state(mapper: Mapper) -> dict[str, np.ndarray]:
    """The mapper's state besides the Gaussians, as the arrays of a checkpoint: its counters and random
    stream, and the ``state()`` of its parts."""
    nan = np.full((4, 4), np.nan)
    state = {
        "mapper_frames_seen": np.array(mapper.frames_seen),
        "mapper_next_index": np.array(mapper.next_index),
        "mapper_keyframe_count": np.array(mapper.keyframe_count),
        "mapper_memory_cursor": np.array(mapper.memory._cursor),
        "mapper_finalized": np.array(mapper.finalized),
        # a resumed run draws the same random numbers as one that was never interrupted
        "mapper_rng": np.array(json.dumps(mapper.rng.bit_generator.state)),
        "mapper_source": np.array(json.dumps(mapper.source)),
        # the module times of a run go on across resumes (ms per keyframe divides by all keyframes)
        "mapper_timings": np.array(json.dumps(mapper.timings.state())),
        "mapper_trajectory": np.stack([nan if p is None else p for p in mapper.trajectory])
        if mapper.trajectory
        else np.zeros((0, 4, 4)),
        "mapper_recent": np.array([e.keyframe for e in mapper.recent], dtype=np.int64),
    }
    state.update(mapper.keyframes.state())
    state.update(mapper.pose_check.state())
    if mapper._tracker is not None:
        state.update(mapper._tracker.state())  # the odometry goes on in the same trajectory
    state.update(mapper.graph_feed.state())
    return state


def write_checkpoint(mapper: Mapper, path: str | Path) -> None:
    """Write ``map.npz``: the Gaussians plus the mapper state needed to resume (atomically), and the
    memory views it does not have on disk yet, each in its own file (``memory_files``)."""
    path = Path(path)
    extra = mapper_state(mapper)
    mem = mapper.memory.entries
    # the keyframes the next one is optimised with (opt_memory_frames) that are not in the memory
    recent = [e for e in mapper.recent if not any(e is m for m in mem)]
    # the order makes a kill at any point safe: the views the new map.npz names are on disk before it,
    # and the evicted views go only once it has replaced the map.npz that named them
    files = [store_view(path, e) for e in mem]
    recent_files = [store_view(path, e) for e in recent]
    extra.update(manifest(mem, files))
    extra.update(manifest(recent, recent_files, prefix="recent"))
    mapper.map.save_npz(path, extra=extra)
    for f in remove_unreferenced(path, files + recent_files):
        log.debug("removed %s, a view no longer in the memory", f)


def restore_mapper(mapper: Mapper, state: CheckpointArrays, path: Path) -> None:
    """Restore :func:`mapper_state` (read from the checkpoint ``path`` by :func:`read_checkpoint`) into
    ``mapper``, and the memory views its lists name (from their files beside ``path``)."""
    p = path
    try:
        mapper.frames_seen = int(state["mapper_frames_seen"])
        mapper.next_index = int(state["mapper_next_index"])
        mapper.keyframe_count = int(state["mapper_keyframe_count"])
        mapper.finalized = bool(state["mapper_finalized"])
        mapper.rng.bit_generator.state = json.loads(str(state["mapper_rng"]))
        mapper.source = json.loads(str(state["mapper_source"]))
        mapper.timings.load_state(json.loads(str(state["mapper_timings"])))
        mapper.trajectory = [None if np.isnan(t).any() else t for t in state["mapper_trajectory"]]
        mapper.keyframes.load_state(state)
        mapper.pose_check.load_state(state)
        cursor = int(state["mapper_memory_cursor"])
        views = read_manifest(state, p)
        recent_views = read_manifest(state, p, "recent")
        recent = [int(k) for k in state["mapper_recent"]]
    except DataError:
        raise
    except KeyError as e:
        raise DataError(f"{p}: not a mapper checkpoint (missing {e})") from e
    except (ValueError, TypeError) as e:  # a damaged array
        raise DataError(corrupt_npz_message(p, e)) from e
    _restore_views(mapper, state, p, views, recent_views, recent, cursor)
    mapper.graph_feed.load_state(state.get("graph_state"), p)
    _restore_tracker(mapper, {k: v for k, v in state.items() if k.startswith("trk_")}, p)
    mapper.timings.counts["keyframes"] = mapper.keyframe_count
    mapper.timings.counts["frames"] = mapper.frames_seen


def _restore_views(
    mapper: Mapper, state, p: Path, views, recent_views, recent: list[int], cursor: int
) -> None:
    """The memory buffer and the recent keyframes of a checkpoint."""
    memory = mapper.memory
    memory.entries = []
    for entry in state.get("mem_inline", []):  # an older checkpoint's inline views (upgrade)
        memory.restore(entry, mapper.device)
    # a smaller memory_max keeps the newest views: the older ones are not even read
    for record in views[max(0, len(views) - memory.max_size) :]:
        memory.restore(load_view(p, record), mapper.device)  # one file read per view
    memory._cursor = cursor % max(1, len(memory.entries))
    # the recent keyframes in the memory are its entries (one object, as while mapping); the others, and
    # any that a smaller memory_max left out of it, are read from their own files
    in_memory = {e.keyframe: e for e in memory.entries}
    records = {r.keyframe: r for r in views + recent_views}
    mapper.recent.clear()
    for kf in recent[max(0, len(recent) - (mapper.recent.maxlen or 0)) :]:  # a smaller opt_memory_frames
        entry = in_memory.get(kf)
        if entry is None and kf in records:
            entry = load_view(p, records[kf])
        if entry is not None:
            mapper.recent.append(entry)


def _restore_tracker(mapper: Mapper, tracker_state: dict[str, np.ndarray], p: Path) -> None:
    mapper._tracker = None
    if mapper.config.tracking.poses != "odometry":
        return
    if tracker_state:
        try:
            mapper._get_tracker().load_state(tracker_state)
        except (ValueError, OGSceneError) as e:
            raise DataError(f"{p}: cannot restore the tracker: {e}") from e
    elif mapper.frames_seen:
        log.warning(
            "%s holds no tracker state (written with dataset poses, or by an older version): "
            "odometry restarts at the next frame's own pose, or the identity where it has none",
            p,
        )
