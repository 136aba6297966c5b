"""Live mapping behind the viewer: the mapper runs on its own thread and publishes snapshots.

The mapping thread never waits on the viewer: between two frames it asks
:meth:`LiveViewer.wants_snapshot` (a rate limit, and whether a browser watches) and only then copies a
decimated snapshot off the device. Pause and save come from the GUI through :class:`LiveSession`,
which serialises them with mapping by one lock held during each ``process``/``finalize``/save. The
run itself (the frame loop, stop, save-on-error, final save) is that of
:class:`~ogscene3d.mapping.engine.MappingEngine`, as for ``ogscene3d run``; the session is its hooks.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ..mapping.engine import MappingEngine, RunSummary
from .snapshot import snapshot_from_mapper

log = logging.getLogger(__name__)


class LiveSession:
    """Runs ``mapper`` over ``frames`` on a background thread and feeds ``viewer``.

    ``mapper``: a :class:`~ogscene3d.mapping.mapper.Mapper` (or anything with ``process(frame) ->
    bool``, ``finalize()``, ``save(dir)``, ``map``, ``timings``, ``frames_seen``, ``keyframe_count``).
    ``frames``: an iterable of :class:`~ogscene3d.frame.Frame`. ``budget``: most Gaussians per
    snapshot. ``max_overhead``: the largest fraction of the mapping thread's time spent building
    snapshots (each one costs O(budget)); after a snapshot that took t seconds the next one waits at
    least t / max_overhead. ``out_dir``: where the run is saved at the end of the stream, or when it is
    stopped (None: only on request); it is also the default of the GUI's save box. ``engine``: the run's
    engine, opened by the caller on its run directory (default: a new one on ``mapper`` and ``out_dir``).
    ``total``: the number of frames, when known (counts the frames a dataset skipped at the end).
    """

    def __init__(
        self,
        mapper: Any,
        frames: Iterable,
        viewer: Any,
        *,
        budget: int = 1_000_000,
        max_overhead: float = 0.1,
        out_dir: str | Path | None = None,
        finalize: bool = True,
        engine: MappingEngine | None = None,
        total: int | None = None,
    ) -> None:
        if budget < 1:
            raise ValueError(f"budget must be >= 1, got {budget}")
        if not 0 < max_overhead <= 1:
            raise ValueError(f"max_overhead must be in (0, 1], got {max_overhead}")
        self.max_overhead = float(max_overhead)
        self._next_snapshot = 0.0  # monotonic time before which no snapshot is built
        self.snapshot_seconds = 0.0  # total time spent building snapshots (mapping-thread overhead)
        self.snapshots = 0
        self.mapper = mapper
        self.frames = frames
        self.viewer = viewer
        self.budget = int(budget)
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self.finalize_at_end = finalize
        self._lock = threading.Lock()  # held while the mapper changes (process/finalize) or is saved
        self._run = threading.Event()
        self._run.set()
        self._stop = threading.Event()
        self._done = threading.Event()
        self._poses: list[np.ndarray] = []
        self._last_frame = None
        self._map_rev = 0
        self.status = "starting"
        self.error: BaseException | None = None
        self.saved_to: Path | None = None
        self.summary: RunSummary | None = None
        self.seconds = 0.0
        self.total = total
        self.engine = engine if engine is not None else MappingEngine(mapper, self.out_dir)
        self.engine.hooks = self
        self.engine.guard = lambda: self._lock
        self._thread = threading.Thread(target=self._main, name="ogscene3d-mapping", daemon=True)

    # ------------------------------------------------------------------ MappingControl
    @property
    def paused(self) -> bool:
        return not self._run.is_set()

    def set_paused(self, paused: bool) -> None:
        if paused:
            self._run.clear()
        else:
            self._run.set()
        log.info("mapping %s", "paused" if paused else "resumed")

    @property
    def default_out_dir(self) -> Path:
        return (
            self.out_dir
            if self.out_dir is not None
            else Path("outputs") / time.strftime("live-%Y%m%d-%H%M%S")
        )

    def save(self, out_dir: str | Path) -> Path:
        """Save the current map, graph and timings to ``out_dir`` (waits for the frame in progress)."""
        with self._lock:
            path = Path(self.mapper.save(out_dir) or out_dir)
        log.info("saved the run to %s", path)
        return path

    # ------------------------------------------------------------------ thread
    def start(self) -> LiveSession:
        self._thread.start()
        return self

    def stop(self, timeout: float = 30.0) -> None:
        """Ask the mapping thread to stop after the current frame and wait for it."""
        self._stop.set()
        self._run.set()
        self._thread.join(timeout)

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the end of the stream; True when mapping has finished."""
        return self._done.wait(timeout)

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def _publish(self, force: bool = False) -> None:
        if not force and (time.monotonic() < self._next_snapshot or not self.viewer.wants_snapshot()):
            return
        t0 = time.perf_counter()
        traj = np.stack(self._poses) if self._poses else np.zeros((0, 4, 4))
        snap = snapshot_from_mapper(
            self.mapper,
            self.budget,
            trajectory=traj,
            frame=self._last_frame,
            map_rev=self._map_rev,
            status=self.status,
        )
        self.viewer.publish(snap)
        cost = time.perf_counter() - t0
        self.snapshot_seconds += cost
        self.snapshots += 1
        self._next_snapshot = time.monotonic() + cost / self.max_overhead

    # ------------------------------------------------------------------ engine hooks (mapping thread)
    def before_frame(self) -> None:
        while not self._run.is_set() and not self._stop.is_set():
            self._run.wait(0.2)
            self._publish()  # keep late joiners served while paused
        if self._stop.is_set():
            self.engine.stop.request()

    def after_frame(self, frame: Any, is_keyframe: bool) -> None:
        if frame.pose is not None:
            self._poses.append(np.asarray(frame.pose, dtype=np.float64))
        self._last_frame = frame
        if is_keyframe:
            self._map_rev += 1
        self._publish()
        if self._stop.is_set():
            self.engine.stop.request()

    def status_changed(self, text: str) -> None:
        self.status = text

    def _main(self) -> None:
        t0 = time.perf_counter()
        try:
            summary = self.engine.run(self.frames, total=self.total, finalize=self.finalize_at_end)
            self.summary = summary
            self._map_rev += 1
            self.seconds = time.perf_counter() - t0
            if summary.saved:
                self.saved_to = self.engine.out
                log.info("saved the run to %s", self.saved_to)
            status = "stopped" if summary.status == "stopped" else "finished"
            self.status = f"{status}, saved to {self.saved_to}" if summary.saved else status
        except Exception as e:  # noqa: BLE001 - shown in the GUI; the viewer keeps serving the map so far
            self.error = e
            self.status = f"error: {type(e).__name__}: {e}"
            log.exception("mapping failed")
        finally:
            self.seconds = time.perf_counter() - t0
            try:
                self._publish(force=True)
            except Exception:  # noqa: BLE001
                log.exception("could not publish the final snapshot")
            self._done.set()


__all__ = ["LiveSession"]
