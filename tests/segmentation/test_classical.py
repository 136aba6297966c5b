"""The weight-free ClassicalSegmenter: synthetic scenes with known regions and an exact Kruskal reference."""

from __future__ import annotations

import numpy as np
import pytest

from ogscene3d.segmentation.classical import ClassicalSegmenter, _grid_edges, graph_segment


def kruskal_reference(n: int, eu, ev, w, k: float, min_size: int) -> np.ndarray:
    """Felzenszwalb & Huttenlocher exactly as published: sequential Kruskal over sorted edges (slow)."""
    order = np.argsort(w, kind="stable")
    parent = list(range(n))
    size = [1] * n
    internal = [0.0] * n

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for e in order.tolist():
        a, b = find(int(eu[e])), find(int(ev[e]))
        if a != b and w[e] <= min(internal[a] + k / size[a], internal[b] + k / size[b]):
            parent[b] = a
            size[a] += size[b]
            internal[a] = max(internal[a], internal[b], float(w[e]))
    for e in order.tolist():
        a, b = find(int(eu[e])), find(int(ev[e]))
        if a != b and (size[a] < min_size or size[b] < min_size):
            parent[b] = a
            size[a] += size[b]
    return np.array([find(i) for i in range(n)])


def same_partition(a: np.ndarray, b: np.ndarray) -> float:
    """Rand index over all pixel pairs (1.0 = identical partitions)."""
    a, b = a.ravel(), b.ravel()
    sa = a[:, None] == a[None, :]
    sb = b[:, None] == b[None, :]
    return float((sa == sb).mean())


def blocks_scene(h: int = 120, w: int = 160, seed: int = 0):
    """Three colour blocks, a depth step between left and right, mild noise everywhere."""
    rng = np.random.default_rng(seed)
    gt = np.zeros((h, w), np.int32)
    gt[:, w // 2 :] = 1
    gt[h // 2 :, : w // 2] = 2
    colors = np.array([[200, 60, 50], [40, 160, 70], [60, 70, 190]], np.float64)
    rgb = colors[gt] + rng.normal(0, 3, (h, w, 3))
    depth = np.where(gt == 1, 2.0, 1.0) + rng.normal(0, 0.002, (h, w))
    return np.clip(rgb, 0, 255).astype(np.uint8), depth.astype(np.float32), gt


def purity(ids: np.ndarray, gt: np.ndarray) -> float:
    """Fraction of pixels whose segment's majority ground-truth region is their own."""
    total = 0
    for s in np.unique(ids):
        total += np.bincount(gt[ids == s]).max()
    return total / gt.size


def test_matches_exact_kruskal_on_a_textured_image():
    rng = np.random.default_rng(1)
    h, w = 30, 40
    base = np.zeros((h, w))
    base[:, 20:] = 30.0
    base[15:, :20] = 60.0
    weights_img = base + rng.normal(0, 4, (h, w))
    eu, ev, _, _ = _grid_edges(h, w)
    weights = np.abs(weights_img.ravel()[eu] - weights_img.ravel()[ev]).astype(np.float32)
    for k, min_size in ((20.0, 5), (60.0, 20)):
        ref = kruskal_reference(h * w, eu, ev, weights, k, min_size)
        ours = graph_segment(h, w, weights, eu, ev, k, min_size, merge_thin=False)
        assert len(np.unique(ours)) == len(np.unique(ref))
        assert same_partition(ours, ref) > 0.995


def test_colour_blocks_are_recovered():
    rgb, depth, gt = blocks_scene()
    seg = ClassicalSegmenter()(rgb, depth)
    assert seg.ids.shape == gt.shape and seg.ids.dtype == np.int32
    assert 3 <= len(seg.scores) <= 6
    assert purity(seg.ids, gt) > 0.97
    assert set(seg.scores) == set(np.unique(seg.ids).tolist())
    assert all(0.88 <= s <= 1.0 for s in seg.scores.values())
    np.testing.assert_array_equal(ClassicalSegmenter()(rgb, depth).ids, seg.ids)  # deterministic


def test_depth_step_splits_a_uniform_colour():
    h, w = 60, 80
    rgb = np.full((h, w, 3), 128, np.uint8)
    depth = np.full((h, w), 1.0, np.float32)
    depth[:, 40:] = 1.6
    with_depth = ClassicalSegmenter(min_size=20)(rgb, depth)
    without = ClassicalSegmenter(min_size=20)(rgb, None)
    assert len(without.scores) == 1
    left, right = with_depth.ids[:, :38], with_depth.ids[:, 42:]
    assert np.unique(left).size == 1 and np.unique(right).size == 1 and left[0, 0] != right[0, 0]


def test_slanted_plane_stays_whole_and_a_crease_splits():
    h, w = 60, 80
    rgb = np.full((h, w, 3), 120, np.uint8)
    fx = 60.0
    v = np.arange(h, dtype=np.float32)[:, None] + 0.5 - h / 2
    u = np.arange(w, dtype=np.float32)[None, :] + 0.5 - w / 2
    # a floor-like plane seen at a grazing angle: depth changes fast from row to row
    floor = 1.0 / (0.2 + 0.012 * (v + h / 2)) + 0 * u
    seg = ClassicalSegmenter(min_size=20)(rgb, floor.astype(np.float32), fx=fx)
    assert len(seg.scores) == 1
    # a roof: two planes meeting at the centre column with continuous depth (only the normal changes)
    roof = (2.0 - 0.6 * np.abs(u) / fx * 2.0 + 0 * v).astype(np.float32)
    for dw, nw in ((300.0, 100.0), (0.0, 100.0)):  # the normal term alone sees it
        split = ClassicalSegmenter(min_size=20, depth_weight=dw, normal_weight=nw)(rgb, roof, fx=fx)
        assert np.unique(split.ids[:, :35]).size == 1 and np.unique(split.ids[:, 45:]).size == 1
        assert split.ids[0, 0] != split.ids[0, -1]
    flat = ClassicalSegmenter(min_size=20, depth_weight=0.0, normal_weight=0.0)(rgb, roof, fx=fx)
    assert len(flat.scores) == 1


def test_large_images_are_downsampled_and_labels_upsampled():
    rgb, depth, gt = blocks_scene(240, 320)
    seg = ClassicalSegmenter(max_side=80)(rgb, depth)
    assert seg.ids.shape == (240, 320)
    assert purity(seg.ids, gt) > 0.95
    assert sorted(seg.scores) == list(range(1, len(seg.scores) + 1))


def test_bad_inputs():
    rgb, depth, _ = blocks_scene(20, 30)
    seg = ClassicalSegmenter()
    bad = depth.copy()
    bad[3, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        seg(rgb, bad)
    with pytest.raises(ValueError, match="shape"):
        seg(rgb, depth[:10])
    with pytest.raises(ValueError, match="uint8"):
        seg(rgb.astype(np.float32), depth)
    with pytest.raises(ValueError):
        ClassicalSegmenter(k=0.0)
    # invalid depth (0) is fine: those pixels are segmented by colour alone
    holes = depth.copy()
    holes[:, :5] = 0.0
    assert seg(rgb, holes).ids.min() >= 1


def test_one_pixel_wide_images_with_depth():
    # np.gradient needs two samples per axis: a 1-pixel strip (also a thin image shrunk to max_side) with
    # depth raised a numpy ValueError; it has no normals, so colour and depth alone segment it
    seg = ClassicalSegmenter()
    for h, w in ((1, 1), (1, 7), (7, 1), (3, 2000)):
        rgb = np.zeros((h, w, 3), np.uint8)
        rgb[..., w // 2 :, :] = 200
        out = seg(rgb, np.ones((h, w), np.float32))
        assert out.ids.shape == (h, w) and out.ids.min() >= 1
        assert all(0.88 <= v <= 1.0 for v in out.scores.values())


def test_real_kinect_frame(shared_data):
    """7-Scenes (Kinect v1): the red cabinet front is one region, separate from the floor and the door."""
    import cv2

    folder = shared_data / "7scenes_redkitchen_stride20"
    rgb = cv2.imread(str(folder / "frame-000100.color.jpg"))[:, :, ::-1].copy()
    depth = cv2.imread(str(folder / "frame-000100.depth.png"), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000
    seg = ClassicalSegmenter(fx=585.0, fy=585.0)(rgb, depth)
    assert 10 <= len(seg.scores) <= 400

    def majority(patch: np.ndarray) -> tuple[int, float]:
        counts = np.bincount(patch.ravel())
        return int(counts.argmax()), counts.max() / patch.size

    cabinet, purity_cab = majority(seg.ids[150:250, 200:300])
    floor, _ = majority(seg.ids[420:470, 250:400])
    door, purity_door = majority(seg.ids[100:300, 0:60])
    assert purity_cab > 0.95 and purity_door > 0.6
    assert len({cabinet, floor, door}) == 3
