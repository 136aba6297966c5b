"""Progress bars that log lines do not tear: the one helper every run loop uses for its bar.

A tqdm bar redraws its line in place (``\\r``) and never ends it, so a warning logged while it runs lands on
the bar's line ("mapping:   0%| ... WARNING ... falling back to the classical segmenter"). While a bar from
:func:`progress` is open, the console handlers of the root logger write through ``tqdm.write`` instead
(tqdm's own ``logging_redirect_tqdm``): the bar is cleared, the line printed, the bar redrawn below it. A
program that set up no logging gets a temporary handler for warnings, as Python's last-resort handler
would have printed them.

    with progress(ds.frames(start), desc="mapping", total=len(ds) - start) as frames:
        for frame in frames:
            ...
            frames.set_postfix(gaussians=n)
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
from collections.abc import Iterable, Iterator
from typing import Any

log = logging.getLogger(__name__)


@contextlib.contextmanager
def progress(
    iterable: Iterable[Any],
    *,
    desc: str,
    total: int | None = None,
    unit: str = "frame",
    disable: bool = False,
) -> Iterator[Any]:
    """A tqdm bar over ``iterable`` (``disable``: none, the iterable's items as they are), with logging
    routed through the bar while it is open. Yields the bar (iterate it; ``set_postfix`` works on it)."""
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    # smoothing 0: the remaining time from the mean rate since the start (frames cost unevenly: a keyframe
    # costs far more than the frames between, a recent rate swings with them)
    bar = tqdm(iterable, desc=desc, total=total, unit=unit, disable=disable, dynamic_ncols=True, smoothing=0)
    try:
        if disable:
            yield bar
            return
        root = logging.getLogger()
        fallback = None
        if not root.handlers:
            # what logging's last-resort handler prints (warnings and worse, the bare message), but as a
            # handler that logging_redirect_tqdm can route through the bar
            fallback = logging.StreamHandler(sys.stderr)
            fallback.setLevel(logging.WARNING)
            root.addHandler(fallback)
        try:
            with logging_redirect_tqdm(loggers=[root], tqdm_class=tqdm):
                yield bar
        finally:
            if fallback is not None:
                root.removeHandler(fallback)
    finally:
        bar.close()


# A run expected to take longer than this on a CPU is told what would make it faster.
LONG_RUN_S = 600.0


def duration(seconds: float) -> str:
    """``seconds`` in words: "45 s", "12 min", "3 h 20 min"."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 90 else f"{minutes // 60} h {minutes % 60:02d} min"


class RunTimeEstimate:
    """An observer of the mapping engine that says, after the second keyframe, how long the run will take: the
    first keyframe's time plus the second's times the keyframes after the first. The first keyframe is no
    measure of the rest: it carries one-time costs (Warp compiling its kernels, models loading) and has no
    earlier keyframes to optimise with, which every later one has (``mapping.optimize.memory_frames``). On a
    CPU, when the run would take longer than :data:`LONG_RUN_S`, it warns and names what would make it
    faster: a GPU, ``data.scale`` (the time scales about with the pixels), a smaller budget per keyframe
    (``configs/synthetic.yaml``'s). A run of one keyframe is told nothing: it is over by then.

    Args:
        frames: the frames the run will read.
        keyframe_every: ``mapping.keyframe_every`` (0: keyframes by camera motion, at most every frame).
        scale: ``data.scale`` now.
        opt_iters: ``mapping.optimize.iters`` now.
    """

    def __init__(self, frames: int, keyframe_every: int, scale: float = 1.0, opt_iters: int = 10) -> None:
        self.frames = int(frames)
        self.keyframe_every = int(keyframe_every)
        self.scale = float(scale)
        self.opt_iters = int(opt_iters)
        self.said: str | None = None  # the line logged (tests and callers read it)
        self._first: float | None = None  # the first keyframe's time

    def keyframe(self, mapper, frame, seconds: float) -> None:
        if self.said is not None:
            return
        every = self.keyframe_every
        keyframes = math.ceil(self.frames / every) if every > 0 else self.frames
        if self._first is None:
            self._first = float(seconds)
            return
        total = self._first + seconds * (keyframes - 1)
        device = str(getattr(mapper, "device", "cpu"))
        size = f"{frame.width}x{frame.height}" if hasattr(frame, "width") else "these images"
        count = f"{keyframes} keyframes" if every > 0 else f"up to {keyframes} keyframes (by camera motion)"
        self.said = (
            f"the first keyframes took {self._first:.1f} s and {seconds:.1f} s on {device} at {size}: "
            f"the run's {count} will take about {duration(total)}"
        )
        if device.startswith("cpu") and total > LONG_RUN_S:
            self.said += "; to go faster: " + "; ".join(self._remedies(total))
            log.warning("%s", self.said)
        else:
            log.info("%s", self.said)

    def _remedies(self, total: float) -> list[str]:
        out = ["map on a GPU (--device cuda)"]
        # the time goes about with the pixels: the largest scale (in steps of 0.05) that brings the run under
        # LONG_RUN_S, at least 0.25
        target = max(0.25, math.floor(20 * self.scale * math.sqrt(LONG_RUN_S / total)) / 20)
        if target < self.scale:
            factor = (target / self.scale) ** 2
            fewer = 1 / factor  # one decimal below 10x: a scale of 0.9 is 1.2x fewer pixels
            times = f"{fewer:.1f}" if fewer < 10 else f"{fewer:.0f}"
            pixels = f"{times}x fewer pixels: about {duration(total * factor)}"
            out.append(f"--set data.scale={target:g} ({pixels})")
        if self.opt_iters > 3:
            out.append(
                "a smaller budget per keyframe, as configs/synthetic.yaml has "
                "(--set mapping.optimize.iters=3 "
                "--set mapping.optimize.memory_frames=1)"
            )
        if self.keyframe_every == 1:
            out.append("fewer keyframes (--set mapping.keyframe_every=5)")
        return out

    def finished(self, mapper) -> None:
        pass
