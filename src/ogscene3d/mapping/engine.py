"""One mapping run, whoever starts it: ``ogscene3d run``, ``run-batch``, the ablation and the live viewer.

The commands parse their options and print; what a run does between its first and last frame is here:

- the caller holds the run folder's lock (:func:`ogscene3d.runs.run_directory`: one writer per folder);
- :meth:`MappingEngine.open` checks a resume against the run's recorded source and settings, and writes
  the run's ``config.yaml`` and ``run_id``;
- :meth:`MappingEngine.run` is the frame loop: progress, a stop request (Ctrl-C, SIGTERM, the viewer)
  honoured between two frames, the map saved when a bad frame or a stop ends the run early, the final
  pass and save, and the counts of the summary line.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import Config
from ..errors import DataError, OGSceneError
from ..progress import progress as progress_bar
from ..runs import EXPORTS, RunFolder, SaveError, StopRequest, resumed_run_id, start_run_dir
from .pose_jump import PoseJumpError
from .source import check_same_source, dataset_source, matching_pixel_centers, remove_run_temps

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------- summary
@dataclass
class RunSummary:
    """What one invocation of a run did (the counts of a resumed run's earlier invocations excluded)."""

    status: str  # "finished", "stopped" (a stop request; the map so far saved) or "up to date"
    out: Path | None
    data: str
    read: int = 0  # frame positions gone through, bad frames skipped included
    mapped: int = 0
    skipped: int = 0  # bad frames left out under data.on_bad_frame: skip
    untracked: int = 0
    pose_jumps: int = 0
    keyframes: int = 0  # of the whole run
    gaussians: int = 0
    seconds: float = 0.0  # the frame loop and the final pass
    device: str = ""
    saved: bool = False

    def line(self) -> str:
        """The summary line ``ogscene3d run`` prints."""
        left = ""
        for n, what in ((self.untracked, "untracked"), (self.pose_jumps, "pose jumps")):
            left += f", {n} {what} left out" if n else ""
        skipped = f", {self.skipped} skipped (data.on_bad_frame: skip)" if self.skipped else ""
        return (
            f"read {self.read} frames: {self.mapped} mapped{skipped} ({self.keyframes} keyframes in all)"
            f"{left}, in {self.seconds:.1f} s on {self.device}: {self.gaussians} Gaussians -> {self.out}"
        )


class MapSaveFailed(OGSceneError):
    """A save of the run directory failed (a full disk, a read-only folder): says what was written."""


# ----------------------------------------------------------------------------------------------- engine
def _counts(mapper: Any) -> dict:
    return dict(getattr(getattr(mapper, "timings", None), "counts", {}) or {})


class MappingEngine:
    """Runs ``mapper`` (a :class:`~ogscene3d.mapping.mapper.Mapper`, or anything with ``process(frame) ->
    bool``, ``finalize()``, ``save(dir)``, ``map``, ``frames_seen`` and ``keyframe_count``) over frames,
    into the run directory ``out`` (None: nothing is written, e.g. the live viewer without ``--out``).

    ``hooks``, called from the loop's thread: ``before_frame()`` (may block, e.g. while paused),
    ``after_frame(frame, is_keyframe)``, ``status_changed(text)``; ``guard``: a context manager held
    around each change of the mapper and each save (the live viewer's lock against its GUI's saves).

    ``observers`` watch the run without steering it (Rerun logging, the run-time estimate): each has
    ``keyframe(mapper, frame, seconds)``, called after every keyframe with the seconds its ``process`` took,
    and ``finished(mapper)``, after the final pass. One that raises is dropped with a warning: an observer
    never costs the run its map."""

    def __init__(
        self,
        mapper: Any,
        out: str | Path | None,
        data: str | Path = "",
        *,
        hooks: Any = None,
        guard: Callable[[], contextlib.AbstractContextManager] | None = None,
        observers: Iterable[Any] = (),
    ) -> None:
        self.mapper = mapper
        self.observers = list(observers)
        self.out = Path(out) if out is not None else None
        self.data = str(data)
        self.hooks = hooks
        self.guard = guard or contextlib.nullcontext
        self.start = 0
        self.resumed = False
        self.bounded = False  # the frames end before the whole sequence's (--max-frames)
        self.left_out = 0  # frames the dataset left out as it opened (see open)
        self.stop = StopRequest()
        self._given = 0  # frames given to the mapper by this run() so far
        self._last_index: int | None = None  # the position of the last one

    # ------------------------------------------------------------------ before the first frame
    def open(self, cfg: Config, ds: Any, *, resume: bool = False, bounded: bool = False) -> int:
        """Prepare the run over the dataset ``ds`` of ``cfg``: with ``resume``, restore ``OUT/map.npz``
        after checking that it maps these frames with these settings; then record the run in ``OUT``.
        ``bounded``: ``ds`` was cut short (``--max-frames``). -> the dataset position to go on from."""
        mapper, out = self.mapper, self.out
        # frames the dataset left out as it opened (a missing file, under data.on_bad_frame: skip) never reach
        # the frame loop: they count with the skipped ones, once (a resume opens the dataset again)
        self.left_out = 0 if resume else int(getattr(ds, "frames_left_out", 0) or 0)
        # a live camera (ds None) has no frames to name: its map cannot be resumed against them
        source = dataset_source(cfg, ds) if ds is not None else {}
        self.bounded = bounded
        if out is None:
            mapper.source = source
            return 0
        remove_run_temps(out)
        mapper.set_checkpoint_dir(out)
        run_id = None
        if resume:
            run_id = self._resume(cfg, ds, source)
        elif RunFolder(out).map.is_file():
            # config.yaml is rewritten now: should this run die before its first save, --resume refuses the
            # old map beside the new settings (resumed_run_id), so say so while the old map can still be kept
            log.warning(
                "%s holds a map from an earlier run: this run replaces it at its first save (--resume "
                "continues that map instead; a new --out keeps it)",
                out,
            )
        mapper.source = source
        source.update(start_run_dir(out, cfg, run_id))
        return self.start

    def _resume(self, cfg: Config, ds: Any, source: dict) -> str | None:
        mapper, out = self.mapper, self.out
        assert out is not None
        ckpt = RunFolder(out).map
        if not ckpt.is_file():
            raise DataError(f"{ckpt}: --resume needs a checkpoint from an earlier run in --out")
        mapper.load_checkpoint(ckpt)
        # first: with another run's config.yaml, the checks below would compare the map with the wrong data
        run_id = resumed_run_id(out, mapper.source, cfg)
        start = mapper.next_index
        check_same_source(
            ckpt, mapper.source, source, start, pixel_centers=lambda K: matching_pixel_centers(ds, K)
        )
        recorded_names = mapper.source.get("names")
        if len(source["names"]) < start:
            # a resume bounded short of where the map got (--max-frames): its checkpoint must still name every
            # frame the map has read, for a later resume and eval --held-out; a map of an older version names
            # none, and then neither does this one (a shorter list would read as frames removed since)
            if recorded_names is not None:
                source["names"] = recorded_names[:start]
            else:
                del source["names"]
        log.info(
            "resuming at frame %d (%d frames mapped, %d keyframes, %d Gaussians)",
            start,
            mapper.frames_seen,
            mapper.keyframe_count,
            len(mapper.map),
        )
        self.start, self.resumed = start, True
        return run_id

    # ------------------------------------------------------------------ the frame loop
    def run(
        self,
        frames: Iterable,
        *,
        total: int | None = None,
        progress: bool = False,
        desc: str = "mapping",
        finalize: bool = True,
    ) -> RunSummary:
        """Map ``frames`` (positions ``start`` on), then finish and save the run; see the class doc."""
        mapper = self.mapper
        seen0, counts0 = mapper.frames_seen, _counts(mapper)
        t0 = time.perf_counter()
        self._status("mapping")
        self._given, self._last_index = 0, None
        try:
            # log lines go through the bar while it is open, instead of being glued onto it
            with progress_bar(frames, desc=desc, total=total, disable=not progress) as it:
                self._loop(it)
        except DataError as e:
            # the bad frames skipped up to the last frame mapped count in the map saved now
            self._summary(self._given, self._last_index, seen0, counts0, None)
            self._save_on_error(e)
            raise
        given = self._given
        summary = self._summary(given, self._last_index, seen0, counts0, total)
        if self.stop.requested:
            summary.status = "stopped"
            summary.seconds = time.perf_counter() - t0
            summary.saved = self._save_partial()
            return summary
        if given == 0 and getattr(mapper, "finalized", False):
            summary.status = "up to date"
            self._write_stale_exports()
            return summary
        self._finish(given, finalize)
        summary.seconds = time.perf_counter() - t0
        if self.out is not None:
            self._save(self.out)
            summary.saved = True
        summary.status = "finished"
        summary.gaussians = len(mapper.map)
        return summary

    def _loop(self, it: Iterable) -> None:
        """The frame loop; counts the frames given to the mapper and keeps the position of the last one."""
        mapper = self.mapper
        for frame in it:
            self._before_frame()
            if self.stop.requested:
                break
            t0 = time.perf_counter()
            with self.guard():
                is_kf = mapper.process(frame)
            if is_kf:
                self._observe("keyframe", mapper, frame, time.perf_counter() - t0)
            self._given += 1
            self._last_index = getattr(frame, "index", None)
            if hasattr(it, "set_postfix"):
                it.set_postfix(gaussians=len(mapper.map), kf=mapper.keyframe_count)
            self._after_frame(frame, is_kf)
            if self.stop.requested:
                break

    def _finish(self, given: int, finalize: bool) -> None:
        """After the last frame: the final pass, unless nothing (or nothing new) could be mapped."""
        mapper = self.mapper
        if mapper.keyframe_count == 0:
            untracked = int(_counts(mapper).get("frames_untracked", 0))
            why = f", {untracked} of them untracked by odometry (see the warnings above)" if untracked else ""
            raise DataError(f"{self.data}: none of the {given} frames read could be mapped{why}")
        if given == 0 and self.resumed and self.bounded:
            log.warning(
                "--max-frames ends at or before frame %d, where the map already is: no frame to read; the "
                "map gets its final pass and is saved as it is (leave --max-frames out, or raise it, to map "
                "more frames)",
                self.start,
            )
        if finalize:
            self._status("finalizing")
            with self.guard():
                mapper.finalize()
        self._check_not_empty()
        self._observe("finished", mapper)

    def _observe(self, event: str, *args: Any) -> None:
        for obs in list(self.observers):
            try:
                getattr(obs, event)(*args)
            except Exception as e:  # noqa: BLE001 - watching the run must not end it
                log.warning("%s stopped after an error: %s: %s", type(obs).__name__, type(e).__name__, e)
                self.observers.remove(obs)

    def _before_frame(self) -> None:
        if self.hooks is not None:
            self.hooks.before_frame()

    def _after_frame(self, frame: Any, is_kf: bool) -> None:
        if self.hooks is not None:
            self.hooks.after_frame(frame, is_kf)

    def _status(self, text: str) -> None:
        if self.hooks is not None:
            self.hooks.status_changed(text)

    def _summary(self, given: int, last_index: int | None, seen0: int, counts0: dict, total: int | None):
        mapper = self.mapper
        counts = _counts(mapper)
        # a bad frame skipped by the dataset is a position no frame came from: counted from the positions
        # gone through (to the end of the frames, or to the last frame read before a stop)
        if self.stop.requested or total is None:
            through = (last_index + 1 - self.start) if last_index is not None else given
        else:
            through = total
        skipped = max(0, through - given) + self.left_out
        self.left_out = 0  # counted now, in this summary and in the timings
        if skipped and hasattr(mapper, "timings") and hasattr(mapper.timings, "add"):
            mapper.timings.add("frames_skipped_bad", skipped)  # in timings.json, across resumes

        def delta(key: str) -> int:
            return int(counts.get(key, 0) - counts0.get(key, 0))

        return RunSummary(
            status="",
            out=self.out,
            data=self.data,
            read=given + skipped,
            mapped=mapper.frames_seen - seen0,
            skipped=skipped,
            untracked=delta("frames_untracked"),
            pose_jumps=delta("frames_skipped_pose_jump"),
            keyframes=mapper.keyframe_count,
            gaussians=len(mapper.map),
            device=str(getattr(mapper, "device", "")),
        )

    def _check_not_empty(self) -> None:
        if len(self.mapper.map):
            return
        counts = _counts(self.mapper)
        no_depth = int(counts.get("keyframes_no_depth", 0))
        why = (
            f": {no_depth} of its {self.mapper.keyframe_count} keyframes had no valid depth pixel (depth 0 "
            "everywhere: a wrong data.depth_scale, or a dead depth sensor; see the warnings above)"
            if no_depth
            else " (see the warnings above)"
        )
        raise DataError(f"{self.data}: nothing could be mapped, the map has 0 Gaussians{why}")

    # ------------------------------------------------------------------ saving
    def _save_on_error(self, e: DataError) -> None:
        """A bad frame late in a long sequence must not cost the map built so far."""
        if self.out is None or not self.mapper.keyframe_count:
            return
        try:
            self._save(self.out)
        except MapSaveFailed as save_error:
            log.error("%s", save_error)
            return
        fix = (
            "fix the pose (or --set mapping.on_pose_jump=skip, or =warn to map it)"
            if isinstance(e, PoseJumpError)
            else "fix the frame (or --set data.on_bad_frame=skip)"
        )
        log.error("the map so far is in %s: %s, then --resume", RunFolder(self.out).map, fix)

    def _save_partial(self) -> bool:
        """After a stop: the map so far, with the files ``eval`` and the viewer read (not finalized: a
        ``run --resume`` goes on from it)."""
        if self.out is None or not self.mapper.keyframe_count:
            return False
        self._status("saving")
        self._save(self.out)
        return True

    def _save(self, out: Path) -> None:
        try:
            with self.guard():
                self.mapper.save(out)
        except SaveError as e:
            saved = ", ".join(e.written) if e.written else "nothing"
            fix = "free some space" if e.cause.errno in (errno.ENOSPC, errno.EDQUOT) else "fix that"
            ckpt = RunFolder(out).map
            if ckpt.name in e.written:
                go_on = f"{fix}, then `ogscene3d run --resume --out {out}` writes the rest"
            elif ckpt.is_file():
                go_on = (
                    f"{ckpt} holds an earlier checkpoint: {fix}, then `ogscene3d run --resume "
                    f"--out {out}` goes on from it"
                )
            else:
                go_on = f"{fix} (or give another --out) and run again"
            raise MapSaveFailed(
                f"could not write {out / e.failed}: {e.reason}; written: {saved}; {go_on}"
            ) from e.cause

    def _write_stale_exports(self) -> None:
        """A finished map whose exports are missing or older than it (its save was cut short after
        map.npz): write them again."""
        out = self.out
        if out is None:
            return
        ckpt = RunFolder(out).map
        stale = [
            name for name in EXPORTS if not (out / name).is_file()
            or (out / name).stat().st_mtime_ns < ckpt.stat().st_mtime_ns
        ]  # fmt: skip
        if stale:
            log.info("%s: writing %s again (the run's last save stopped before them)", out, ", ".join(stale))
            self._save(out)


def stopped_message(summary: RunSummary, command: str = "ogscene3d run") -> str:
    """The line printed after a stop."""
    if summary.saved and summary.out is not None:
        return (
            f"stopped after {summary.read} frames; the map so far is in {summary.out} "
            f"(`ogscene3d run --resume --out {summary.out}` goes on)"
        )
    if summary.out is None:
        return f"stopped after {summary.read} frames (no --out: nothing saved)"
    return f"stopped after {summary.read} frames, before any keyframe: nothing to save"
