"""A keyframe's segments (mapping/segments.py): their borders follow the depth edges unless turned off."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ogscene3d.config import Config
from ogscene3d.errors import DataError
from ogscene3d.frame import Frame
from ogscene3d.mapping.segments import KeyframeSegments
from ogscene3d.mapping.timings import Timings


def _frame(segments: np.ndarray) -> Frame:
    """A box 1.5 m away on a wall 3 m away, its segment one column too wide."""
    h, w = segments.shape
    depth = np.full((h, w), 3.0, np.float32)
    depth[4:12, 6:14] = 1.5
    K = np.array([[20.0, 0, w / 2], [0, 20.0, h / 2], [0, 0, 1]], np.float32)
    rgb = np.zeros((h, w, 3), np.uint8)
    return Frame(0, rgb, depth, K, np.eye(4), segments=segments, segment_scores={2: 0.9})


@pytest.mark.parametrize("margin", [0.05, 0.0])
def test_segments_follow_the_depth_edges_unless_turned_off(margin):
    seg = np.ones((16, 20), np.int32)
    seg[4:12, 6:15] = 2  # column 14 is the wall
    cfg = Config()
    cfg.segmentation.depth_snap = margin
    ids, scores, _ = KeyframeSegments(cfg, None, Timings(torch.device("cpu")))(_frame(seg))
    assert scores == {2: 0.9}
    assert (ids[4:12, 6:14] == 2).all()
    assert (ids[4:12, 14] == (1 if margin else 2)).all()


def test_segments_of_another_shape_are_named():
    frame = _frame(np.ones((16, 20), np.int32))
    frame.segments = np.ones((8, 20), np.int32)
    with pytest.raises(DataError, match=r"frame 0 .*shape \(8, 20\)"):
        KeyframeSegments(Config(), None, Timings(torch.device("cpu")))(frame)
