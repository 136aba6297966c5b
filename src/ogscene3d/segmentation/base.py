"""The Segmenter protocol every 2D front-end implements (SAM, SAM+detector, classical, simulated)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass
class Segmentation:
    """One frame's open-set segmentation.

    Attributes:
        ids: segment ids, 0 (or negative) = no segment; per frame only (never consistent across frames).
            int32 [H, W]
        scores: {id: predicted IoU in [0, 1]} (SAM's, or the front-end's own estimate).
        names: {id: class name} for segments that came with a detector label.
    """

    ids: np.ndarray
    scores: dict[int, float] = field(default_factory=dict)
    names: dict[int, str] = field(default_factory=dict)

    def score_map(self) -> np.ndarray:
        """Per-pixel score (0 where there is no segment, negative ids included)."""
        lut = np.zeros(int(self.ids.max(initial=0)) + 1, dtype=np.float32)
        for k, v in self.scores.items():
            if 0 < k < lut.size:
                lut[k] = v
        return lut[np.maximum(self.ids, 0)]  # a negative id would index the lut from its end


@runtime_checkable
class Segmenter(Protocol):
    """What every 2D front-end is: ``segmenter(rgb, depth)`` gives one frame's :class:`Segmentation`.

    The front-ends (``SamOnnx``, ``SamDetectorSegmenter``, ``ClassicalSegmenter``) are built from the
    ``segmentation`` config section by ``ogscene3d.segmentation.make_segmenter``.
    """

    def __call__(self, rgb: np.ndarray, depth: np.ndarray | None = None) -> Segmentation:
        """Segment one frame.

        Args:
            rgb: the colour image. uint8 [H, W, 3]
            depth: its depth in metres (0 = invalid), for the front-ends that use it. float32 [H, W]

        Returns:
            The frame's segments.
        """
        ...
