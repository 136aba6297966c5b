"""``map.npz`` as a mapper checkpoint: reading its format version, and the one place that upgrades the
checkpoints of older versions to today's.

A checkpoint is the Gaussians (``GaussianMap.state_dict``, with the format ``version``) plus the arrays of
``Mapper.state()``, which gathers the ``state()`` of its parts (keyframe selector, pose-jump check,
timings, tracker, scene graph, memory views). From version 2 every mapper array below is always written;
a version-1 file may lack those added over its life, and :func:`upgrade` gives each its old meaning.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError
from ..gaussians import FIELDS
from ..runs.map_npz import NPZ_VERSION, corrupt_npz_message, read_map_npz
from .longterm import MemoryEntry

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
