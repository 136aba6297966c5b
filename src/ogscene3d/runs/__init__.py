"""The run folder: one owner of its layout, its lock and stop signal, and the one reader and writer of each
of its files (docs/formats.md "The run directory", docs/runs.md).

Everything that writes or reads a run folder (the mapper's save and load, the engine, ``run-batch``,
``eval``, the viewer, ``export``) goes through this package; nothing here imports the mapping, the viewer
or the evaluation, and nothing heavy (torch, warp, open3d) is imported.
"""

from __future__ import annotations

from .gaussians_ply import GaussianPly, read_gaussians_ply, write_gaussians_ply
from .graph_json import read_graph_json, write_graph_json
from .layout import (
    CONFIG,
    EXPORT,
    EXPORTS,
    GAUSSIANS,
    GRAPH,
    LOCK,
    MAP,
    METRICS,
    RUN_FILES,
    RUN_ID,
    SCENE,
    TIMINGS,
    TRAJECTORY,
    RunFolder,
)
from .lock import RunDirBusyError, RunDirLock, run_directory
from .map_npz import CorruptMapError, read_map_npz, write_map_npz
from .stop import StopRequest

__all__ = [
    "CONFIG",
    "CorruptMapError",
    "EXPORT",
    "EXPORTS",
    "GAUSSIANS",
    "GaussianPly",
    "GRAPH",
    "LOCK",
    "MAP",
    "METRICS",
    "RUN_FILES",
    "RUN_ID",
    "RunDirBusyError",
    "RunDirLock",
    "RunFolder",
    "SCENE",
    "StopRequest",
    "TIMINGS",
    "TRAJECTORY",
    "read_gaussians_ply",
    "read_graph_json",
    "read_map_npz",
    "run_directory",
    "write_gaussians_ply",
    "write_graph_json",
    "write_map_npz",
]
