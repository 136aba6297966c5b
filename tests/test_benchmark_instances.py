"""The ablation benchmark's instance scores and the offline view-consensus yardsticks, on hand-built cases."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from ogscene3d.eval.readers import GroundTruth

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
_instances = pytest.importorskip("_instances")
yardstick = pytest.importorskip("yardstick")
weak = pytest.importorskip("_maskclustering")


def three_boxes() -> GroundTruth:
    """Three instances of 100 points each, 1 m apart on x: a floor (1), a table (2), a cup (3)."""
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.uniform(0, 0.3, (100, 3)) + [x, 0, 0] for x in (0.0, 1.0, 2.0)])
    inst = np.repeat([1, 2, 3], 100)
    return GroundTruth(
        points=pts, classes=inst - 1, class_names=["floor", "table", "cup"], instances=inst,
        instance_classes={1: 0, 2: 1, 3: 2},
    )  # fmt: skip


def test_instance_miou_hungarian():
    gt = three_boxes()
    exact = _instances.instance_scores(gt.points, gt.instances * 10, gt)
    assert exact["miou"] == pytest.approx(1.0)
    assert exact["matched"] == {1: 10, 2: 20, 3: 30}
    # table and cup under one label: one of them matched (IoU 0.5), the other unmatched (0)
    merged = np.where(gt.instances == 3, 2, gt.instances)
    m = _instances.instance_scores(gt.points, merged, gt)
    assert m["miou"] == pytest.approx((1.0 + 0.5 + 0.0) / 3, abs=0.02)
    # the floor split in two labels by x: its best half matches, the other half is a false positive
    split = gt.instances.copy()
    split[(gt.instances == 1) & (gt.points[:, 0] > 0.15)] = 9
    s = _instances.instance_scores(gt.points, split, gt)
    assert 0.3 < s["iou"][1] < 0.7 and s["iou"][2] == pytest.approx(1.0)
    assert _instances.recovered(s["iou"], {2: "absorbed/merged", 7: "cut/missed"}) == (1, 1)  # 7 unscored
    unmatched = 3 if m["iou"][2] > 0 else 2
    assert _instances.recovered(m["iou"], {unmatched: "absorbed/merged"}) == (0, 1)


def test_class_miou_names_labels_by_overlap():
    gt = three_boxes()
    assert _instances.class_miou(gt.points, gt.instances + 5, gt, which="all") == pytest.approx(1.0)


def test_lost_objects_and_unlabelled_share():
    assert _instances.lost_objects({1: 0.9, 2: 0.6, 3: 0.4, 4: 0.5}, {1: 0.1, 2: 0.3, 3: 0.0}) == [1, 4]
    gt = three_boxes()
    labels = np.where(gt.instances == 3, -1, gt.instances)  # the cup's points carry no label
    assert _instances.unlabelled_share(gt.points, labels, gt) == pytest.approx(1 / 3)
    assert _instances.class_scores(gt.points, gt.instances, gt, which="all") == pytest.approx((1.0, 1.0))


def test_consensus_edges_and_components():
    # 4 masks over 5 frames: containers per frame (-2 not seen, -1 seen but in no mask)
    cont = np.array(
        [
            [7, 7, 8, -2, 9],  # mask 0
            [7, 7, 8, -1, 9],  # mask 1: always with mask 0 -> consensus 1
            [7, 5, 6, 4, 3],  # mask 2: with mask 0 in 1 of 4 shared frames
            [-2, -2, -2, -2, 3],  # mask 3: one shared frame only (< MIN_VIEWS)
        ]
    )
    edges = weak.consensus_edges(cont, 0.9)
    assert edges.tolist() == [[0, 1]]
    assert weak.consensus_edges(cont, 0.25).tolist() == [[0, 1], [0, 2], [1, 2]]
    comp = weak._components(4, edges)
    assert comp[0] == comp[1] and len({comp[1], comp[2], comp[3]}) == 3


def test_voxels_go_to_the_most_specific_claim():
    """A cup's voxel is covered by the table's cluster in 2 frames and by the cup's in 2: the smaller cup
    cluster wins; a table voxel only the table covers stays table."""
    cup = np.array([0.01, 0.01, 0.01])
    table = np.array([0.51, 0.01, 0.01])
    points = np.array([cup, cup, cup, cup, table, table, table, table, table])
    cluster = np.array([0, 0, 1, 1, 0, 0, 0, 0, 0])  # 0: table (7 points), 1: cup (2)
    frame = np.array([0, 1, 2, 3, 0, 1, 2, 3, 4])
    centres, lab = weak.assign_voxels(points, cluster, frame)
    at = {tuple(np.floor(c / weak.VOXEL).astype(int)): int(v) for c, v in zip(centres, lab)}
    assert at[tuple(np.floor(cup / weak.VOXEL).astype(int))] == 1
    assert at[tuple(np.floor(table / weak.VOXEL).astype(int))] == 0


def _views(masks_per_frame: list[list[np.ndarray]], n_voxels: int) -> yardstick.Views:
    """Hand-built views: every frame sees every voxel; ``masks_per_frame[g]`` lists its masks' voxels."""
    seen, mask, mframe = [], [], []
    k = 0
    for g, masks in enumerate(masks_per_frame):
        m = np.full(n_voxels, -1, np.int64)
        for vox in masks:
            m[vox] = k
            mframe.append(g)
            k += 1
        seen.append(np.arange(n_voxels))
        mask.append(m)
    points = np.stack([np.arange(n_voxels) * 0.1, np.zeros(n_voxels), np.zeros(n_voxels)], 1)
    return yardstick.Views(points, seen, mask, np.array(mframe), np.ones(k))


def test_strong_yardstick_keeps_an_absorbed_cup_apart_from_its_table():
    """Voxels 0-19 are a table, 20-23 a cup on it. Four frames segment both as one mask (the cup absorbed),
    four show them apart: the separation rule keeps the two clusters apart, and the cup keeps its voxels.
    Two frames of eight showing them apart are under ``SEP_SHARE``: one cluster (consensus 6 of 8)."""
    table, cup, both = np.arange(20), np.arange(20, 24), np.arange(24)
    views = _views([[both]] * 4 + [[table, cup]] * 4, 24)
    clusters = yardstick.cluster(views)
    node_of_mask = clusters.node_of_mask
    assert len(set(node_of_mask[[0, 1, 2, 3, 4, 6, 8, 10]])) == 1  # the table with the absorbing masks
    assert len(set(node_of_mask[[5, 7, 9, 11]])) == 1 and node_of_mask[5] != node_of_mask[4]  # the cup apart
    lab = yardstick.vote(views, clusters)
    assert len(set(lab[table])) == 1 and set(lab[cup]) == {node_of_mask[5]}
    few = yardstick.cluster(_views([[both]] * 6 + [[table, cup]] * 2, 24)).node_of_mask
    assert len(set(few)) == 1


def test_strong_yardstick_a_frame_separates_two_large_neighbours():
    """A cabinet (voxels 0-19) beside the floor (20-79), each with a segment of its own in three frames:
    each frame separates them, though neither segment is small beside the other (the size rule alone would
    see no separation)."""
    cabinet, floor = np.arange(20), np.arange(20, 80)
    views = _views([[cabinet, floor]] * 3, 80)
    h = yardstick.holding(views, np.arange(views.n_masks), views.n_masks)
    _, frame = yardstick._separating_frames(h, np.array([0]), np.array([1]))
    assert sorted(set(frame.tolist())) == [0, 1, 2]


def test_strong_yardstick_a_cut_through_two_clusters_masks_does_not_separate_them(monkeypatch):
    """A floor (voxels 0-399) in two clusters: A of masks 0-199 (frame 0) and 150-399 (frame 1), B of mask
    250-399 (frame 2). Frames 3 and 4 cut the floor at 180: the first piece holds A's first mask, the second
    A's second and B's, so they separate a mask of A from B's (2 of the 4 frames that hold both). But the
    second piece holds most of what they see of both clusters, whose masks are mostly of ``CUT_VOXELS`` or
    more: a cut, not a separation; the clusters are not apart. With larger ``CUT_VOXELS`` they are, and so
    they are where A's masks are mostly small (three masks of 5 voxels that frames 5-7 made): a light
    switch's cluster that took in a mask of the wall has that mask for its main one."""
    near, far, tiny = np.arange(180), np.arange(180, 400), np.arange(5)
    frames = [[np.arange(200)], [np.arange(150, 400)], [np.arange(250, 400)], [near, far], [near, far]]
    views = _views(frames + [[tiny]] * 3, 400)
    h = yardstick.holding(views, np.arange(views.n_masks), views.n_masks)
    assert h.held[0, 3] == 3 and h.held[1, 3] == 4 and h.held[2, 3] == 4
    a, b, _ = yardstick._candidate_pairs(h, views.n_masks, views.n_masks)
    ev = yardstick._Evidence(views, h, a, b)
    assert sorted(set(ev.sep_frame[(ev.sep_a == 0) & (ev.sep_b == 2)].tolist())) == [3, 4]

    def apart(node: list[int]) -> bool:
        _, _, pa, pb = ev.of(np.array(node))
        return (0, 1) in set(zip(pa.tolist(), pb.tolist()))

    assert not apart([0, 0, 1, 2, 3, 4, 5, 6, 7, 8])
    assert apart([0, 0, 1, 2, 3, 4, 5, 0, 0, 0])  # A's masks mostly small
    monkeypatch.setattr(yardstick, "CUT_VOXELS", 1000)
    assert apart([0, 0, 1, 2, 3, 4, 5, 6, 7, 8])


def test_strong_yardstick_a_frame_that_left_a_node_unsegmented_does_not_hold_it():
    """A floor (voxels 0-59) is one segment in frame 0. Frame 1 sees it whole but segments only a counter
    (60-79) whose segment spills over floor voxels 0-4; the rest of the floor is in no segment. The counter's
    segment holds all of the floor's voxels that lie in a mask there, but the frame left the floor mostly
    unsegmented: it does not hold it. Where the rest of the floor lies on segment boundaries instead (pixels
    of two segments in each voxel: segmented, in no one mask), the counter's segment holds it."""
    floor, counter = np.arange(60), np.arange(60, 80)
    views = _views([[floor], [np.r_[counter, np.arange(5)]]], 80)
    views.mask[1][5:60] = yardstick.UNSEGMENTED
    h = yardstick.holding(views, np.arange(views.n_masks), views.n_masks)
    assert h.seen[0, 1] and h.held[0, 1] == -1
    views.mask[1][5:60] = -1  # a boundary (two segments in each voxel), not unsegmented
    h = yardstick.holding(views, np.arange(views.n_masks), views.n_masks)
    assert h.held[0, 1] == 1


def test_strong_yardstick_votes_by_share_of_views():
    """A shelf (voxels 0-19) absorbs a book (20-23) in four views and shows it apart in four: on the book's
    voxels the book's views are 4 of 4 that could have put them in it, the shelf's 4 of 8; counted, the two
    tie. The book keeps its voxels without the absorbing votes given back."""
    shelf, book, both = np.arange(20), np.arange(20, 24), np.arange(24)
    views = _views([[both]] * 4 + [[shelf, book]] * 4, 24)
    clusters = yardstick.cluster(views)
    book_cluster = clusters.node_of_mask[5]
    assert book_cluster != clusters.node_of_mask[4]
    lab = yardstick.vote(views, clusters, nested=False)
    assert set(lab[book]) == {book_cluster} and book_cluster not in set(lab[shelf])


def test_strong_yardstick_gives_absorbing_votes_only_to_an_object_two_views_showed():
    """A vase (voxels 0-29) is one segment in eight frames; one frame (two in the second case) cuts a piece
    (0-9) off it, a cluster the views keep apart from the vase's. The vase's masks hold the piece: their
    votes there go to the piece only where at least ``SEP_MIN`` views showed it on its own (a cup that the
    table's segment absorbs), not for a piece that one view cut off."""
    vase, piece, rest = np.arange(30), np.arange(10), np.arange(10, 30)
    for cuts, piece_wins in ((1, False), (yardstick.SEP_MIN, True)):
        views = _views([[vase]] * 8 + [[piece, rest]] * cuts, 30)
        node = np.zeros(views.n_masks, np.int64)
        node[8::2] = 1  # the pieces
        h = yardstick.holding(views, np.arange(views.n_masks), views.n_masks)
        lab = yardstick.vote(views, yardstick.Clusters(node, h, {(0, 1)}))
        assert set(lab[rest]) == {0}
        assert set(lab[piece]) == ({1} if piece_wins else {0}), cuts


def test_strong_yardstick_leaves_out_a_mask_over_two_objects():
    """A first view merges a refrigerator (voxels 0-9) with the floor (10-29); four later views show them
    apart: the merged mask is under-segmented (split in every view that sees it) and has no vote."""
    fridge, floor = np.arange(10), np.arange(10, 30)
    views = _views([[np.arange(30)]] + [[fridge, floor]] * 4, 30)
    clusters = yardstick.cluster(views)
    node_of_mask = clusters.node_of_mask
    assert node_of_mask[0] == -1
    assert len(set(node_of_mask[[1, 3, 5, 7]])) == 1 and len(set(node_of_mask[[2, 4, 6, 8]])) == 1
    lab = yardstick.vote(views, clusters)
    assert len(set(lab[fridge])) == 1 and set(lab[fridge]).isdisjoint(lab[floor])


def test_strong_yardstick_keeps_a_small_mask_that_one_view_of_three_splits():
    """A book (voxels 0-9) on a shelf (10-29), seen in four frames; in one of them boundary noise gives half
    the book to the shelf's segment. The first frame's book mask is split in 1 of the 3 other frames that
    see it: not more than ``SPLIT_SMALL`` of them, so it is no mask over two objects and joins the book's
    cluster. A mask of ``SPLIT_SMALL_VOXELS`` split the same way is left out (``SPLIT``)."""
    book, shelf = np.arange(10), np.arange(10, 30)
    noisy = [np.arange(5), np.arange(5, 30)]
    views = _views([[book, shelf]] * 3 + [noisy], 30)
    h = yardstick.holding(views, np.arange(views.n_masks), views.n_masks)
    assert h.split[0].sum() == 1
    node_of_mask = yardstick.cluster(views).node_of_mask
    assert node_of_mask[0] >= 0 and node_of_mask[0] == node_of_mask[2] == node_of_mask[4]
    n = yardstick.SPLIT_SMALL_VOXELS
    big, rest = np.arange(n), np.arange(n, 3 * n)
    views = _views([[big, rest]] * 3 + [[np.arange(n // 2), np.arange(n // 2, 3 * n)]], 3 * n)
    h = yardstick.holding(views, np.arange(views.n_masks), views.n_masks)
    assert h.split[0].sum() == 1 and yardstick.undersegmented(h, views)[0]


def test_strong_yardstick_distinct_is_numpy_unique():
    rng = np.random.default_rng(0)
    for x in (rng.integers(0, 50, 1000), np.zeros(0, np.int64), np.array([7])):
        assert np.array_equal(yardstick._distinct(x), np.unique(x))


def test_strong_yardstick_views_from_frames():
    """Two frames of a flat wall 2 m away, left and right halves segmented apart in the first and as one in
    the second: one set of voxels, three masks with their scores."""
    from types import SimpleNamespace

    K = np.array([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]])
    seg0 = np.ones((12, 16), np.int32)
    seg0[:, 8:] = 2
    scores = {1: 0.9, 2: 0.97}
    frames = [
        SimpleNamespace(depth=np.full((12, 16), 2.0), K=K, pose=np.eye(4), segments=s, segment_scores=scores)
        for s in (seg0, np.ones((12, 16), np.int32))
    ]
    views = yardstick.build_views(frames)
    assert views.n_masks == 3 and views.mask_frame.tolist() == [0, 0, 1]
    assert views.mask_score.tolist() == [0.9, 0.97, 0.9]
    assert len(views.seen[0]) == len(views.seen[1]) == len(views.points)
    assert (views.mask[1] == 2).all() and {0, 1} <= set(views.mask[0].tolist())
    assert np.allclose(views.points[:, 2], 2.0)


def test_strong_yardstick_labels_at_a_maps_points():
    """Three voxels labelled 0, 1 and -1: each query point takes its nearest voxel's label; no voxels, no
    labels."""
    points = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    labels = np.array([0, 1, -1])
    query = np.array([[0.2, 0, 0], [0.9, 0.1, 0], [1.8, 0, 0], [-5.0, 0, 0]])
    assert yardstick.at_points(points, labels, query).tolist() == [0, 1, -1, 0]
    assert yardstick.at_points(np.zeros((0, 3)), np.zeros(0, np.int64), query).tolist() == [-1] * 4


def test_strong_yardstick_reads_the_segments_as_the_mapper_moves_them(tmp_path):
    """The yardstick's frames carry the segments moved onto the depth edges by the mapper's setting (the
    default, or the one given; 0: as stored)."""
    from ogscene3d.config import Config
    from ogscene3d.datasets import make_synthetic_scene
    from ogscene3d.segmentation import snap_to_depth_edges

    scene = make_synthetic_scene(tmp_path / "room", 1, 4, 64, 48)
    stored = yardstick._frames(scene, 0.0)
    moved = yardstick._frames(scene)
    margin = Config().segmentation.depth_snap
    changed = 0
    for a, b in zip(stored, moved, strict=True):
        assert np.array_equal(b.segments, snap_to_depth_edges(a.segments, a.depth, margin))
        changed += int((a.segments != b.segments).sum())
    assert changed > 0  # the simulated segments run past some edges
