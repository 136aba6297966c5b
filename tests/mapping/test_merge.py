"""Merging duplicate scene labels (mapping/merge.py): the 2D containment test, the merge itself, and the
mapper using it on a wall whose left object was first over-segmented."""

import numpy as np
import torch

from ogscene3d.config import load_config
from ogscene3d.frame import Frame
from ogscene3d.mapping.mapper import Mapper
from ogscene3d.mapping.merge import duplicate_label_pairs, label_containment, merge_labels, visible_pixels

W, H, F = 32, 24, 24.0
K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]], dtype=np.float32)


def test_containment_decides_which_pairs_merge(device):
    # rendered labels: 5 on columns 0-3, 6 on columns 4-7, 7 on columns 8-15 (8 rows)
    rendered = torch.full((8, 16), 7, dtype=torch.int64)
    rendered[:, :4] = 5
    rendered[:, 4:8] = 6
    seg = torch.full((8, 16), -1, dtype=torch.int64)
    seg[:, :8] = 0  # segment 0 holds all of labels 5 and 6
    seg[:, 8:11] = 1  # segment 1 holds 3 of label 7's 8 columns ...
    top1 = torch.tensor([5, 7])
    top2 = torch.tensor([6, 6])  # ... and none of label 6
    pairs = duplicate_label_pairs(
        seg.to(device), rendered.to(device), torch.tensor([0, 1], device=device), top1.to(device),
        top2.to(device), tau_contain=0.8,
    )  # fmt: skip
    assert pairs.cpu().tolist() == [[5, 6]]
    share = label_containment(seg, rendered, torch.tensor([0, 1, 1]), torch.tensor([5, 7, 6]))
    assert share.tolist() == [1.0, 3 / 8, 0.0]
    # a label that spills out of the segment does not merge
    rendered[0, 12] = 5
    rendered[:4, 8] = 5  # label 5 now has 32 + 5 pixels, 5 of them outside segment 0 (86% inside)
    assert duplicate_label_pairs(seg, rendered, torch.tensor([0]), top1, top2, 0.9).shape == (0, 2)
    assert duplicate_label_pairs(seg, rendered, torch.tensor([0]), top1, top2, 0.8).tolist() == [[5, 6]]
    # no candidates, or a candidate without a second label
    assert duplicate_label_pairs(seg, rendered, torch.tensor([], dtype=torch.int64), top1, top2).shape == (
        0,
        2,
    )
    assert duplicate_label_pairs(seg, rendered, torch.tensor([0]), top1, torch.tensor([-1, -1])).shape == (
        0,
        2,
    )


def test_min_part_keeps_a_detail_the_segment_took_in_apart(device):
    # segment 0 holds all of label 5 (4 pixels: a chair far in front of a wall) and all of label 6 (60)
    rendered = torch.full((8, 8), 6, dtype=torch.int64)
    rendered[:2, :2] = 5
    seg = torch.zeros((8, 8), dtype=torch.int64)
    args = (seg.to(device), rendered.to(device), torch.tensor([0], device=device))
    tops = (torch.tensor([6], device=device), torch.tensor([5], device=device))
    assert duplicate_label_pairs(*args, *tops, 0.8, 0.0).cpu().tolist() == [[6, 5]]
    assert duplicate_label_pairs(*args, *tops, 0.8, 0.05).cpu().tolist() == [[6, 5]]  # 4 / 64 = 6 %
    assert duplicate_label_pairs(*args, *tops, 0.8, 0.1).shape == (0, 2)
    # unlabelled items (-1) do not count towards the segment's share
    rendered[2:, :] = -1
    cpu_tops = (tops[0].cpu(), tops[1].cpu())
    # 4 of 16 labelled items
    assert duplicate_label_pairs(seg, rendered, torch.tensor([0]), *cpu_tops, 0.8, 0.1).tolist() == [[6, 5]]


def test_visible_pixels_drop_occluded_and_outside_gaussians(device):
    depth = torch.full((H, W), 2.0)
    depth[0, 0] = 0.0  # no depth there
    c2w = torch.eye(4)
    c2w[0, 3] = 1.0  # camera 1 m along +x
    x0 = 1.0 + (0.5 - W / 2) / F * 2.0  # world x of the centre of column 0 at 2 m
    means = torch.tensor(
        [
            [1.0 + 0.5 / F * 2.0, 0.5 / F * 2.0, 2.0],  # on the surface: pixel (12, 16)
            [1.0, 0.0, 2.5],  # behind the observed surface: occluded
            [1.0, 0.0, 1.5],  # in front of it (a floater, or the surface moved)
            [1.0, 0.0, -2.0],  # behind the camera
            [9.0, 0.0, 2.0],  # outside the image
            [x0, (0.5 - H / 2) / F * 2.0, 2.0],  # pixel (0, 0): no depth
            [x0, (1.5 - H / 2) / F * 2.0, 2.05],  # pixel (1, 0), 5 cm off: within the margin
        ]
    )
    pix = visible_pixels(
        means.to(device), c2w.to(device), torch.as_tensor(K).to(device), depth.to(device), 0.1
    )
    assert pix.cpu().tolist() == [12 * W + 16, -1, -1, -1, -1, -1, 1 * W + 0]


def test_merge_keeps_the_larger_label_and_follows_chains(device):
    labels = torch.tensor([1, 1, 2, 2, 2, 3, 4, 4, -1], dtype=torch.int32, device=device)
    mapping = merge_labels(labels, torch.tensor([[1, 2], [3, 1]], device=device))
    assert mapping == {1: 2, 3: 2}
    assert labels.cpu().tolist() == [2, 2, 2, 2, 2, 2, 4, 4, -1]
    assert merge_labels(labels, torch.zeros((0, 2), dtype=torch.int64)) == {}


def _frame(i: int, seg: np.ndarray, scores: dict[int, float] | None = None) -> Frame:
    """The fronto-parallel wall 2 m ahead, seen from the same pose: red object left, blue one right."""
    left = np.broadcast_to(np.arange(W)[None, :] < W // 2, (H, W))
    rgb = np.where(left[..., None], np.array([200, 30, 30], np.uint8), np.array([30, 30, 200], np.uint8))
    ids = np.unique(seg[seg > 0])
    return Frame(
        i,
        np.ascontiguousarray(rgb),
        np.full((H, W), 2.0, np.float32),
        K,
        np.eye(4),
        name=f"f{i}",
        segments=seg.astype(np.int32),
        segment_scores=scores or {int(s): 0.97 for s in ids},
    )


def _halves() -> np.ndarray:
    seg = np.full((H, W), 2, np.int32)
    seg[:, : W // 2] = 1
    return seg


def _mapper(device, *overrides: str) -> Mapper:
    cfg = load_config(
        None,
        [
            "graph.enabled=false",
            "mapping.optimize.iters=0",
            "mapping.association.knn_radius=0.1",
            "mapping.ablation=local",
            *overrides,
        ],
    )
    return Mapper(cfg, device)


def test_mapper_merges_the_labels_of_an_over_segmented_object(device):
    first = _halves()
    first[H // 2 :, : W // 2] = 3  # the left object comes in two pieces: two novel labels
    for merge in (True, False):
        m = _mapper(device, f"mapping.merge.enabled={str(merge).lower()}")
        m.process(_frame(0, first))
        assert torch.unique(m.map.labels).numel() == 3
        m.process(_frame(1, _halves()))  # one confident segment now holds the left object whole
        left = m.map.means[:, 0].cpu() < 0
        labels = m.map.labels.cpu()
        c = m.timings.as_dict()["counts"]
        if merge:
            assert c["labels_merged"] == 1 and c["segments_merged"] == 1
            assert torch.unique(labels[left]).numel() == 1 and torch.unique(labels).numel() == 2
        else:  # the paper's rule: the segment is ambiguous and both labels stay
            assert "labels_merged" not in c and c["segments_ambiguous"] == 1
            assert torch.unique(labels[left]).numel() == 2


def test_mapper_keeps_objects_apart_when_a_segment_spills_over(device):
    m = _mapper(device)
    m.process(_frame(0, _halves()))
    spill = np.full((H, W), 2, np.int32)
    spill[:, : 3 * W // 4] = 1  # segment 1: the left object and a third of the right one
    m.process(_frame(1, spill))
    c = m.timings.as_dict()["counts"]
    assert c["segments_ambiguous"] >= 1 and "labels_merged" not in c
    assert torch.unique(m.map.labels[m.map.labels >= 0]).numel() == 2


def test_low_scored_segments_do_not_merge(device):
    first = _halves()
    first[H // 2 :, : W // 2] = 3
    m = _mapper(device)
    m.process(_frame(0, first))
    m.process(_frame(1, _halves(), {1: 0.9, 2: 0.97}))  # below mapping.merge.min_score (0.95)
    assert "labels_merged" not in m.timings.as_dict()["counts"]


def test_a_merged_segment_gets_the_eq5_update_of_a_matched_one(device):
    """The merge turns the left segment into case (ii) after the association: its matches must get Eq. 5
    like the right segment's, with p(m) counted over both merged labels (1 here, not 1/2)."""
    first = _halves()
    first[H // 2 :, : W // 2] = 3
    m = _mapper(device)
    m.process(_frame(0, first))
    before = m.map.confidences.clone()
    n0 = len(m.map)
    m.process(_frame(1, _halves()))  # same pose: every probe lies on a Gaussian of frame 0
    assert m.timings.as_dict()["counts"]["segments_merged"] == 1
    c_sam = 0.5 + 0.5 * (0.97 - 0.88) / 0.12  # segment score 0.97 rescaled into [0.5, 1]
    left = m.map.means[:n0, 0].cpu() < 0
    conf = m.map.confidences[:n0].cpu()
    want = before.cpu() + c_sam * 1.0 * (1 - before.cpu())
    assert left.any() and (~left).any()
    torch.testing.assert_close(conf[left], want[left])  # the merged segment: left unchanged before the fix
    torch.testing.assert_close(conf[~left], want[~left])  # the segment matched in the first place
    assert m.timings.as_dict()["counts"]["segments_conf_updates"] == n0


def _wall_view(i: int, seg: np.ndarray, z_cam: float) -> Frame:
    """The wall at world z = 2 seen head-on from (0, 0, z_cam), one grey colour."""
    return Frame(
        i,
        np.full((H, W, 3), 128, np.uint8),
        np.full((H, W), 2.0 - z_cam, np.float32),
        K,
        np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, z_cam], [0, 0, 0, 1]], np.float64),
        name=f"f{i}",
        segments=seg.astype(np.int32),
        segment_scores={int(s): 0.97 for s in np.unique(seg[seg > 0])},
    )


def _far_mapper(device, *overrides: str) -> Mapper:
    """``_mapper`` for the step-back views: no pose-jump check (6 m in one step), no scale pruning (the far
    view's Gaussians are large)."""
    return _mapper(device, "mapping.max_pose_step=0", "mapping.optimize.prune_scale=0", *overrides)


def test_merge_novel_joins_a_cut_surface_seen_further(device):
    """Frame 0 sees a patch of the wall cut in two (labels A, B); frame 1, from 6 m further back, sees the
    whole wall as one confident segment of which the patch is a few percent (p < tau_p: novel). By default
    the wall gets a third label; with ``mapping.merge.novel`` the segment shows A and B whole, each a large
    part of what is mapped in it, so they merge and the new wall takes the merged label."""
    for novel in (False, True):
        m = _far_mapper(device, f"mapping.merge.novel={str(novel).lower()}", "mapping.merge.min_part=0.1")
        m.process(_wall_view(0, _halves(), 0.0))
        assert torch.unique(m.map.labels).numel() == 2
        m.process(_wall_view(1, np.ones((H, W), np.int32), -6.0))
        c = m.timings.as_dict()["counts"]
        n_labels = torch.unique(m.map.labels[m.map.labels >= 0]).numel()
        if novel:
            assert c["labels_merged"] == 1 and c["segments_merged"] == 1
            assert n_labels == 1
        else:
            assert "labels_merged" not in c and c["segments_novel"] == 3  # 2 in frame 0
            assert n_labels == 3


def test_merge_novel_extends_the_one_label_a_segment_holds_whole(device):
    """Frame 0 maps a patch of the wall as one label; from 6 m further back the patch is a few percent of
    a confident segment (p < tau_p) whose matches all fall on that label: with ``mapping.merge.novel`` the
    segment takes it. Cut down the middle, neither half holds the patch whole (each about half of it), and
    both halves stay novel."""
    whole = np.ones((H, W), np.int32)
    for novel in (False, True):
        m = _far_mapper(device, f"mapping.merge.novel={str(novel).lower()}")
        m.process(_wall_view(0, whole, 0.0))
        m.process(_wall_view(1, whole, -6.0))
        c = m.timings.as_dict()["counts"]
        n_labels = torch.unique(m.map.labels[m.map.labels >= 0]).numel()
        assert (n_labels, c.get("segments_extended", 0)) == ((1, 1) if novel else (2, 0))
    m = _far_mapper(device)
    m.process(_wall_view(0, whole, 0.0))
    m.process(_wall_view(1, _halves(), -6.0))
    assert m.timings.as_dict()["counts"].get("segments_extended", 0) == 0
    assert torch.unique(m.map.labels[m.map.labels >= 0]).numel() == 3
    # a segment below mapping.merge.min_score does not take the label either
    m = _far_mapper(device)
    m.process(_wall_view(0, whole, 0.0))
    low = _wall_view(1, whole, -6.0)
    low.segment_scores = {1: 0.9}
    m.process(low)
    assert torch.unique(m.map.labels[m.map.labels >= 0]).numel() == 2


def test_merge_novel_extends_the_most_matched_label_it_holds_whole(device):
    """From 6 m back the patch of frame 0 (labels A left, B right) spans columns 12-20. A segment over
    columns 0-17 holds all of A and a quarter of B (r >= tau_valid, no merge: B is not inside it) and takes
    A; the segment over the rest holds three quarters of B only, and is novel."""
    seg = np.full((H, W), 2, np.int32)
    seg[:, :18] = 1
    m = _far_mapper(device)
    m.process(_wall_view(0, _halves(), 0.0))
    a = int(m.map.labels[m.map.means[:, 0] < 0][0])
    m.process(_wall_view(1, seg, -6.0))
    c = m.timings.as_dict()["counts"]
    assert c["segments_extended"] == 1 and "labels_merged" not in c
    far_left = m.map.means[:, 0] < -2.0  # new wall, left of the patch
    assert torch.all(m.map.labels[far_left] == a)
    assert torch.unique(m.map.labels[m.map.labels >= 0]).numel() == 3
