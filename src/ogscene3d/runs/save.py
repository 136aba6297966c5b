"""The order in which a save writes a run folder, and the error that names what a failed save wrote."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..atomic import atomic_write_text
from ..config import Config
from ..errors import OGSceneError
from .graph_json import write_graph_json
from .layout import CONFIG, GAUSSIANS, GRAPH, MAP, TIMINGS, TRAJECTORY, RunFolder
from .record import remove_run_id, write_config, write_timings


class SaveError(OGSceneError, OSError):
    """A write of :func:`save_run` failed: ``failed`` (a file name in the run directory), ``written``
    (the names written before it), ``cause`` (the OSError, e.g. ENOSPC)."""

    def __init__(self, failed: str, written: list[str], cause: OSError) -> None:
        self.failed, self.written, self.cause = failed, list(written), cause
        self.reason = cause.strerror or str(cause)
        done = ", ".join(written) if written else "nothing"
        super().__init__(f"could not write {failed}: {self.reason} (written before it: {done})")


def save_run(
    out_dir: str | Path,
    *,
    config: Config,
    checkpoint: Callable[[Path], None],
    gaussians: Callable[[Path], None],
    timings: Callable[[], dict[str, Any]],
    trajectory: Callable[[], str | None],
    graph: Callable[[], dict[str, Any]],
    keeps_run_id: bool,
) -> Path:
    """Write a run folder: ``config.yaml`` and ``map.npz`` (``checkpoint`` writes it, with its memory views)
    first, which is what a resume needs, then the exports: ``gaussians.ply`` (``gaussians`` writes it),
    ``timings.json``, ``traj.txt`` (when ``trajectory`` gives a text) and ``graph.json``. A save cut short
    (a full disk) thus leaves a map that ``run --resume`` writes the exports from. Unless ``keeps_run_id``
    (the save of a run that records its id in its checkpoint), an earlier run's ``run_id`` is removed.

    Raises:
        SaveError: a write failed; it names the file and those written before it.
    """
    folder = RunFolder(out_dir)
    folder.path.mkdir(parents=True, exist_ok=True)
    if not keeps_run_id:
        # saved outside a run that names itself (a script's save, the live viewer's save box): an earlier
        # run's id left here would vouch for this config.yaml beside that run's map.npz should this save
        # stop before its map.npz, and --resume would go on with the old map and these settings
        remove_run_id(folder.path)

    def write_trajectory() -> None:
        text = trajectory()
        if text:
            atomic_write_text(folder.trajectory, text)

    steps: list[tuple[str, Callable[[], None]]] = [
        (CONFIG, lambda: write_config(folder.config, config)),
        (MAP, lambda: checkpoint(folder.map)),
        (GAUSSIANS, lambda: gaussians(folder.gaussians)),
        (TIMINGS, lambda: write_timings(folder.timings, timings())),
        (TRAJECTORY, write_trajectory),
        (GRAPH, lambda: write_graph_json(folder.graph, graph())),
    ]
    written: list[str] = []
    for name, write in steps:
        try:
            write()
        except OSError as e:
            raise SaveError(name, written, e) from e
        written.append(name)
    return folder.path


__all__ = ["SaveError", "save_run"]
