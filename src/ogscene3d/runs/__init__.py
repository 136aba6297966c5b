"""The run folder: one owner of its layout, its lock and stop signal, and the one reader and writer of each
of its files (docs/formats.md "The run directory", docs/runs.md).

Everything that writes or reads a run folder (the mapper's save and load, the engine, ``run-batch``,
``eval``, the viewer, ``export``) goes through this package; nothing here imports the mapping, the viewer
or the evaluation, nor torch, warp or open3d. Modules:

- ``layout``: the file names (:class:`RunFolder`);
- ``lock``, ``stop``: one writer per folder (:func:`run_directory`), a stop after the frame in progress;
- ``record``: ``run_id``, ``config.yaml``, ``timings.json``, ``metrics.json``; ``save``: the order of a save;
- ``gaussians_ply``, ``graph_json``, ``map_npz``: the three data files.

Names load on first use (PEP 562), so that ``ogscene3d --help`` reads the layout without numpy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        ".layout": [
            "CONFIG",
            "EXPORT",
            "EXPORTS",
            "GAUSSIANS",
            "GRAPH",
            "LOCK",
            "MAP",
            "METRICS",
            "RUN_FILES",
            "RUN_ID",
            "SCENE",
            "TIMINGS",
            "TRAJECTORY",
            "RunFolder",
        ],
        ".lock": ["RunDirBusyError", "RunDirLock", "run_directory"],
        ".stop": ["StopRequest"],
        ".record": [
            "config_digest",
            "json_safe",
            "read_config",
            "read_run_id",
            "read_timings",
            "recorded_data_path",
            "recorded_up",
            "resumed_run_id",
            "start_run_dir",
            "write_metrics",
            "write_timings",
        ],
        ".save": ["SaveError", "save_run"],
        ".gaussians_ply": ["GaussianPly", "read_gaussians_ply", "write_gaussians_ply"],
        ".graph_json": ["graph_up", "read_graph_json", "write_graph_json"],
        ".map_npz": ["CorruptMapError", "read_map_npz", "write_map_npz"],
    },
)

if TYPE_CHECKING:  # the same names, for type checkers and editors
    from .gaussians_ply import GaussianPly, read_gaussians_ply, write_gaussians_ply
    from .graph_json import graph_up, read_graph_json, write_graph_json
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
    from .record import (
        config_digest,
        json_safe,
        read_config,
        read_run_id,
        read_timings,
        recorded_data_path,
        recorded_up,
        resumed_run_id,
        start_run_dir,
        write_metrics,
        write_timings,
    )
    from .save import SaveError, save_run
    from .stop import StopRequest

__all__ = [
    "CONFIG",
    "CorruptMapError",
    "EXPORT",
    "EXPORTS",
    "GAUSSIANS",
    "GRAPH",
    "GaussianPly",
    "LOCK",
    "MAP",
    "METRICS",
    "RUN_FILES",
    "RUN_ID",
    "RunDirBusyError",
    "RunDirLock",
    "RunFolder",
    "SCENE",
    "SaveError",
    "StopRequest",
    "TIMINGS",
    "TRAJECTORY",
    "config_digest",
    "graph_up",
    "json_safe",
    "read_config",
    "read_gaussians_ply",
    "read_graph_json",
    "read_map_npz",
    "read_run_id",
    "read_timings",
    "recorded_data_path",
    "recorded_up",
    "resumed_run_id",
    "run_directory",
    "save_run",
    "start_run_dir",
    "write_gaussians_ply",
    "write_graph_json",
    "write_map_npz",
    "write_metrics",
    "write_timings",
]
