"""Segment borders moved onto depth edges: hand-built scenes, and the vectorised pass against a slow loop."""

from __future__ import annotations

import numpy as np
import pytest

from ogscene3d.segmentation.depth_edges import snap_to_depth_edges

H, W = 24, 32


def _reference(ids: np.ndarray, depth: np.ndarray, margin: float, rounds: int = 2) -> np.ndarray:
    """The rule written pixel by pixel, as the module's docstring states it."""
    out = ids.copy()
    h, w = ids.shape
    d = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float64)
    for _ in range(rounds):
        cur = out.copy()

        def border(v, u, cur=cur):
            if cur[v, u] <= 0:
                return False
            return any(
                0 <= v + a < h and 0 <= u + b < w and cur[v + a, u + b] != cur[v, u]
                for a, b in ((0, 1), (0, -1), (1, 0), (-1, 0))
            )

        moved = False
        for v in range(h):
            for u in range(w):
                s = cur[v, u]
                if not border(v, u) or d[v, u] <= 0:
                    continue
                own, other, other_id = np.inf, np.inf, 0
                for a, b in ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)):
                    p, q = (v + a, u + b), (v + 2 * a, u + 2 * b)
                    if not (0 <= q[0] < h and 0 <= q[1] < w) or d[p] <= 0 or d[q] <= 0:
                        continue
                    off = abs(d[v, u] - (2 * d[p] - d[q]))
                    if cur[p] == s and cur[q] == s and not border(*p) and not border(*q):
                        own = min(own, off)
                    elif cur[p] == cur[q] and cur[p] > 0 and cur[p] != s and off < other:
                        other, other_id = off, cur[p]
                if np.isfinite(own) and own > margin and other < margin and other < 0.5 * own:
                    out[v, u] = other_id
                    moved = True
        if not moved:
            break
    return out


def _wall_and_box() -> tuple[np.ndarray, np.ndarray]:
    """A wall (1) at 3 m, its depth slanting, with a box (2) at 1.5 m in front of it."""
    ids = np.ones((H, W), np.int64)
    depth = 3.0 + 0.01 * np.arange(W)[None, :] + 0.005 * np.arange(H)[:, None]
    ids[6:18, 10:22] = 2
    depth[6:18, 10:22] = 1.5 + 0.004 * np.arange(12)[None, :]
    return ids, depth


def test_a_mask_that_follows_the_depth_edge_is_left_alone():
    ids, depth = _wall_and_box()
    assert np.array_equal(snap_to_depth_edges(ids, depth, 0.05), ids)


def test_a_mask_run_past_the_edge_comes_back_to_it(device):
    ids, depth = _wall_and_box()
    seg = ids.copy()
    seg[6:18, 22] = 2  # one pixel onto the wall, on the right
    seg[18:20, 10:22] = 2  # two pixels onto the wall, below
    out = snap_to_depth_edges(seg, depth, 0.05, device=device)
    assert np.array_equal(out, ids)
    # one round takes the strip's outer pixels only
    once = snap_to_depth_edges(seg, depth, 0.05, rounds=1)
    assert (once[19, 10:22] == 1).all() and (once[18, 11:21] == 2).all()


def test_a_mask_that_stops_short_gives_the_object_its_edge_back():
    ids, depth = _wall_and_box()
    seg = ids.copy()
    seg[6:18, 10] = 1  # the wall's segment took the box's left column
    assert np.array_equal(snap_to_depth_edges(seg, depth, 0.05), ids)


def test_touching_surfaces_and_thin_objects_stay():
    # a cup on a table: the depth is continuous where they meet, so neither side moves
    ids = np.ones((H, W), np.int64)
    depth = 2.0 + 0.02 * np.arange(H)[:, None] * np.ones((1, W))
    ids[4:12, 12:18] = 2
    depth[4:12, 12:18] = depth[12, 12]  # the cup's front face, upright, meets the table at row 12
    assert np.array_equal(snap_to_depth_edges(ids, depth, 0.05), ids)
    # a leg two pixels wide in front of a wall has no interior to predict its depth: it is kept
    ids = np.ones((H, W), np.int64)
    depth = np.full((H, W), 3.0)
    ids[:, 15:17] = 2
    depth[:, 15:17] = 1.0
    depth[:, 17] = 1.0  # even with the leg's segment short of a column of it
    out = snap_to_depth_edges(ids, depth, 0.05)
    assert (out[:, 15:17] == 2).all()


def test_no_segment_and_no_depth_neither_move_nor_predict():
    ids, depth = _wall_and_box()
    seg = ids.copy()
    seg[6:18, 22] = 2
    seg[0, :] = 0  # unsegmented pixels are never moved, nor moved into
    depth = depth.copy()
    depth[10, 22] = 0.0  # a pixel without depth keeps its segment
    depth[12, 23] = np.nan  # and one beside it cannot predict
    out = snap_to_depth_edges(seg, depth, 0.05)
    assert (out[0] == 0).all()
    assert out[10, 22] == 2
    assert np.array_equal(out, _reference(seg, depth, 0.05))


def test_matches_the_reference_on_random_scenes(device):
    rng = np.random.default_rng(0)
    for _ in range(20):
        ids = np.ones((H, W), np.int64)
        depth = 3.0 + rng.uniform(-0.02, 0.02) * np.arange(W)[None, :] + np.zeros((H, 1))
        for k in range(2, 6):  # boxes in front of each other, their masks shifted by a pixel or two
            v, u = rng.integers(0, H - 6), rng.integers(0, W - 6)
            hh, ww = rng.integers(3, 10), rng.integers(3, 12)
            depth[v : v + hh, u : u + ww] = 3.0 - 0.4 * k + 0.01 * np.arange(min(ww, W - u))[None, :]
            sv, su = rng.integers(-2, 3, size=2)
            ids[max(0, v + sv) : v + hh + sv, max(0, u + su) : u + ww + su] = k
        ids[rng.uniform(size=ids.shape) < 0.03] = 0
        depth[rng.uniform(size=ids.shape) < 0.03] = 0.0
        depth = depth.astype(np.float32)  # a frame's depth; the rule compares in float64 from it
        expect = _reference(ids, depth, 0.05)
        for dtype in (np.int64, np.int32):  # an int32 map is the kernel's own type: still never written
            given = ids.astype(dtype)
            assert np.array_equal(snap_to_depth_edges(given, depth, 0.05, device=device), expect)
            assert np.array_equal(given, ids)


def test_bad_input_is_named():
    ids, depth = _wall_and_box()
    with pytest.raises(ValueError, match=r"ids \(24, 32\) and depth \(23, 32\)"):
        snap_to_depth_edges(ids, depth[:-1], 0.05)
    with pytest.raises(ValueError, match="32 bits"):
        snap_to_depth_edges(ids + 2**31, depth, 0.05)
    with pytest.raises(ValueError, match="margin"):
        snap_to_depth_edges(ids, depth, 0.0)
