"""The names of a run folder's files, written once (docs/formats.md "The run directory").

A run folder holds what a resume needs (``config.yaml``, ``run_id``, ``map.npz`` with its memory views in
``map_memory/``), the exports (``gaussians.ply``, ``timings.json``, ``traj.txt``, ``graph.json``), and,
beside them, what other commands add: the synthetic scene a run generated (``scene/``, where ``eval`` finds
its ground truth), ``metrics.json`` and the IoU charts of ``eval``, and ``export/``.
"""

from __future__ import annotations

from pathlib import Path

CONFIG = "config.yaml"
RUN_ID = "run_id"
MAP = "map.npz"
GAUSSIANS = "gaussians.ply"
TIMINGS = "timings.json"
TRAJECTORY = "traj.txt"
GRAPH = "graph.json"
SCENE = "scene"
METRICS = "metrics.json"
EXPORT = "export"
LOCK = ".ogscene3d.lock"

#: The files a run writes (each atomically: a killed write leaves a temporary beside it).
RUN_FILES = (MAP, GAUSSIANS, GRAPH, TIMINGS, CONFIG, TRAJECTORY, RUN_ID)
#: What a finished run's exports are; a resume of a finished map writes again any that are missing or older
#: than its map.npz (a save stopped between the two by a full disk or a kill).
EXPORTS = (GAUSSIANS, GRAPH, TIMINGS)


class RunFolder:
    """The paths of one run folder's files (``RunFolder(out).map`` is ``out/map.npz``)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    @property
    def config(self) -> Path:
        return self.path / CONFIG

    @property
    def run_id(self) -> Path:
        return self.path / RUN_ID

    @property
    def map(self) -> Path:
        """The checkpoint; its memory views are in ``map_memory/`` beside it (``mapping.memory_files``)."""
        return self.path / MAP

    @property
    def gaussians(self) -> Path:
        return self.path / GAUSSIANS

    @property
    def timings(self) -> Path:
        return self.path / TIMINGS

    @property
    def trajectory(self) -> Path:
        return self.path / TRAJECTORY

    @property
    def graph(self) -> Path:
        return self.path / GRAPH

    @property
    def scene(self) -> Path:
        """Where a run without ``--data`` generates its synthetic scene."""
        return self.path / SCENE

    @property
    def metrics(self) -> Path:
        return self.path / METRICS

    @property
    def export(self) -> Path:
        return self.path / EXPORT

    @property
    def lock(self) -> Path:
        return self.path / LOCK

