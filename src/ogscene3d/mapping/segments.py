"""A keyframe's 2D segments: the frame's precomputed ones, else those of the run's segmenter (built from
the config on first need), else none (geometry only); their borders moved onto the frame's depth edges
(``segmentation.depth_snap``, ``segmentation/depth_edges.py``), so that every stage reads those segments."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import torch

from ..config import Config
from ..errors import DataError
from ..frame import Frame
from ..segmentation import make_segmenter
from ..segmentation.depth_edges import snap_to_depth_edges
from .timings import Timings

log = logging.getLogger(__name__)


def segment_ids(ids, frame: Frame, source: str) -> np.ndarray:
    """The id map of ``frame``'s segments from ``source``, checked; negative ids (a common "background"
    value) count as no segment, as 0 does."""
    ids = np.asarray(ids)
    if ids.shape != frame.rgb.shape[:2]:
        raise DataError(
            f"frame {frame.index} ({frame.name or 'unnamed'}): {source} gave segment ids of shape "
            f"{ids.shape}, the image is {frame.rgb.shape[:2]}"
        )
    if not (np.issubdtype(ids.dtype, np.integer) or ids.dtype == np.bool_):
        raise DataError(
            f"frame {frame.index} ({frame.name or 'unnamed'}): {source} gave segment ids of dtype "
            f"{ids.dtype}; an integer id map is needed (0 = no segment)"
        )
    if ids.size and ids.min() < 0:
        ids = np.maximum(ids, 0)
    return ids


class KeyframeSegments:
    """``segments(frame)``: the keyframe's segment ids, scores and (where a detector named them) class
    names; ``segmenter`` is the one given, or the one built from ``config.segmentation`` for frames that
    carry no segments; ``device``: where the borders are moved onto the depth edges (the mapper's)."""

    def __init__(
        self, config: Config, segmenter, timings: Timings, device: torch.device | None = None
    ) -> None:
        self.config = config
        self.device = device if device is not None else torch.device("cpu")
        self.segmenter = segmenter
        self.timings = timings
        self._warned = False

    def __call__(self, frame: Frame) -> tuple[np.ndarray | None, dict[int, float], dict[int, str]]:
        ids, scores, names = self._segments(frame)
        margin = self.config.segmentation.depth_snap
        if ids is not None and margin > 0:
            with self.timings.section("segment"):
                ids = snap_to_depth_edges(ids, frame.depth, margin, device=self.device)
        return ids, scores, names

    def _segments(self, frame: Frame) -> tuple[np.ndarray | None, dict[int, float], dict[int, str]]:
        if frame.segments is not None:
            ids = segment_ids(frame.segments, frame, "frame.segments")
            return ids, dict(frame.segment_scores), dict(frame.segment_names)
        if self.segmenter is None:
            self.segmenter = default_segmenter(self.config, frame.K)
        if self.segmenter is not None:
            with self.timings.section("segment"):
                if hasattr(self.segmenter, "segment_frame"):  # the simulated segmenter reads ground truth
                    seg = self.segmenter.segment_frame(frame)
                else:
                    seg = self.segmenter(frame.rgb, frame.depth)
            ids = segment_ids(seg.ids, frame, type(self.segmenter).__name__)
            return ids, dict(seg.scores), dict(getattr(seg, "names", {}) or {})
        if not self._warned:
            log.warning("frames carry no segments and no segmenter was given: mapping geometry only")
            self._warned = True
        return None, {}, {}


def default_segmenter(config: Config, K: np.ndarray):
    """The live segmenter for frames that carry no precomputed segments (None: map geometry only)."""
    backend = config.segmentation.backend
    if backend == "none":
        return None
    if backend == "precomputed":
        log.warning("frames carry no precomputed segments: falling back to the classical segmenter")
        return make_segmenter(replace(config.segmentation, backend="classical"), K)
    return make_segmenter(config.segmentation, K)
