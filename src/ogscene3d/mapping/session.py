"""One mapping session, however it is started: the config, the data (a dataset, the synthetic scene generated
for the run, or a live camera), its frames, a :class:`~ogscene3d.mapping.mapper.Mapper` and the
:class:`~ogscene3d.mapping.engine.MappingEngine` opened on the run folder.

``ogscene3d run``, each scene of ``run-batch``, ``ogscene3d live`` and the ablation build their sessions
here, so each run folder records the same things: the run's id and settings, and the data it mapped
(``config.yaml``'s ``data.path``, where ``eval`` finds the ground truth and ``run --resume`` the frames).
The commands parse their options and print; the frame loop is the engine's.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import Config
from ..datasets import configured_scene, open_dataset
from ..errors import DataError
from ..runs import RunFolder, run_directory
from ..up_axis import choose_up_axis
from .engine import MappingEngine, RunSummary
from .mapper import Mapper
from .source import record_data

log = logging.getLogger(__name__)

#: What to do when the synthetic scene's folder holds another scene.
SCENE_REMEDY = "give a new --out, or remove that folder to generate the scene there again"


@dataclass
class Session:
    """A mapping session ready to run: ``engine`` (with its ``mapper``) opened on the run folder, and the
    frames it maps from ``start`` on (``total`` of them, when known)."""

    cfg: Config
    engine: MappingEngine
    data: str | Path  # the dataset folder, or the camera's name
    dataset: Any | None  # the opened dataset (None for a live camera)
    frames: Iterable
    start: int
    total: int | None

    @property
    def mapper(self) -> Mapper:
        return self.engine.mapper

    def run(self, *, progress: bool = False, desc: str = "mapping") -> RunSummary:
        """Map the frames in this thread; Ctrl-C or SIGTERM stop after the frame in progress (the map so far
        is saved: ``summary.status == "stopped"``)."""
        with self.engine.stop.signals():
            return self.engine.run(self.frames, total=self.total, progress=progress, desc=desc)


def open_frames(
    cfg: Config, data: str | Path, segments: str | Path | None = None, max_frames: int | None = None
):
    """The dataset of a run (its path, and ``segments`` when given, recorded in ``cfg``: the run's
    ``config.yaml`` then tells ``eval`` the ground truth and ``--resume`` the frames); ``graph.up_axis``
    auto is chosen for it, where its format or poses tell (:func:`~ogscene3d.up_axis.choose_up_axis`)."""
    record_data(cfg, data, segments)
    ds = open_dataset(max_frames=max_frames, config=cfg.data)
    if len(ds) == 0:
        raise DataError(f"{data}: the dataset has no frames")
    choose_up_axis(cfg.graph, ds)
    return ds


def synthetic_scene(cfg: Config, folder: str | Path, progress: bool = False) -> Path:
    """The synthetic scene of ``cfg.synthetic``, generated in ``folder`` (or the one already there)."""
    s = cfg.synthetic
    log.info(
        "no --data: generating the synthetic scene (seed %d, %d frames, %dx%d) in %s",
        s.seed,
        s.frames,
        s.width,
        s.height,
        folder,
    )
    return configured_scene(Path(folder), s, progress=progress, remedy=SCENE_REMEDY)


def open_session(
    cfg: Config,
    out: str | Path | None,
    data: str | Path | None = None,
    *,
    segments: str | Path | None = None,
    max_frames: int | None = None,
    resume: bool = False,
    stream: Any = None,
    progress: bool = False,
) -> Session:
    """Build the session of ``cfg`` into the run folder ``out`` (None: nothing is written). The caller holds
    the folder's lock (:func:`mapping_session` does).

    Args:
        cfg: the run's settings; the data it maps is recorded in it (``data.path``, ``data.segments_dir``).
        out: the run folder.
        data: the dataset folder; None: ``cfg.synthetic``'s scene, generated in ``OUT/scene``.
        segments: a folder of precomputed segments.
        max_frames: map at most this many frames (this invocation only: a resume without it goes on to
            the end).
        resume: go on from ``OUT/map.npz`` (checked against these frames and settings).
        stream: a live camera (``ogscene3d.streams``) to map instead of a dataset; nothing to resume by.
        progress: show the synthetic scene's generation.

    Returns:
        The session, its engine opened (``config.yaml`` and ``run_id`` written in ``out``).
    """
    dataset = None
    if stream is None:
        if data is None:
            if out is None:
                raise ValueError("open_session: the synthetic scene needs a run folder (out) to be made in")
            data = synthetic_scene(cfg, RunFolder(out).scene, progress)
        dataset = open_frames(cfg, data, segments, max_frames)
    engine = MappingEngine(Mapper(cfg, cfg.device), out, data if stream is None else stream.name)
    start = engine.open(cfg, dataset, resume=resume, bounded=max_frames is not None)
    if dataset is None:
        return Session(cfg, engine, stream.name, None, stream, start, None)
    assert data is not None
    return Session(cfg, engine, data, dataset, dataset.frames(start), start, max(0, len(dataset) - start))


@contextlib.contextmanager
def mapping_session(
    cfg: Config, out: str | Path, data: str | Path | None = None, *, command: str, **options: Any
) -> Iterator[Session]:
    """:func:`open_session` within the run folder's lock, held for the block (``command`` names the holder:
    ``run``, ``run-batch``, ``ablation``)."""
    with run_directory(out, command):
        yield open_session(cfg, out, data, **options)


__all__ = ["SCENE_REMEDY", "Session", "mapping_session", "open_session", "synthetic_scene"]
