"""Multi-view co-segmentation evidence (mapping/evidence.py) on small hand-built scenes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ogscene3d.gaussians import GaussianMap
from ogscene3d.mapping.evidence import SegmentEvidence, spill_pixels

W, H = 64, 48
K = np.array([[50.0, 0, 32.0], [0, 50.0, 24.0], [0, 0, 1]], np.float32)
POSE = np.eye(4)
DEPTH = np.full((H, W), 2.0, np.float32)


def plane_map(device: str) -> tuple[GaussianMap, torch.Tensor]:
    """Gaussians on the plane z = 2 in front of the camera, all label 0 (a cabinet front that swallowed a
    vase); returns the map and the mask of the 'vase' patch (the Gaussians seen in pixels [16:25, 37:45])."""
    xs, ys = np.meshgrid(np.arange(-1.0, 1.0, 0.05), np.arange(-0.7, 0.7, 0.05))
    pts = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 2.0)], 1).astype(np.float32)
    gm = GaussianMap(device)
    n = len(pts)
    gm.append(
        torch.from_numpy(pts), torch.full((n, 3), 0.5), torch.full((n,), -3.0),
        labels=torch.zeros(n, dtype=torch.int32), confidences=torch.full((n,), 0.9),
    )  # fmt: skip
    u = np.floor(K[0, 0] * pts[:, 0] / 2.0 + K[0, 2])
    v = np.floor(K[1, 1] * pts[:, 1] / 2.0 + K[1, 2])
    vase = (u >= 37) & (u < 45) & (v >= 16) & (v < 25)  # the pixels of segment 2 below
    return gm, torch.from_numpy(vase).to(gm.device)


def segments_with_vase(cut: bool = False) -> np.ndarray:
    seg = np.ones((H, W), np.int32)
    seg[16:25, 37:45] = 2  # the vase's pixels
    if cut:
        seg[:, :20] = 3
    return seg


def test_aux_values_follow_append_and_prune(device):
    gm, _ = plane_map(device)
    ev = gm.aux("evidence_views")
    ev[:] = torch.arange(len(gm), dtype=torch.float32, device=gm.device)
    keep = torch.ones(len(gm), dtype=torch.bool, device=gm.device)
    keep[:10] = False
    gm.keep(keep)
    assert gm.aux("evidence_views")[0].item() == 10.0
    gm.append(torch.zeros((3, 3)), torch.zeros((3, 3)), torch.zeros(3))
    assert torch.all(gm.aux("evidence_views")[-3:] == 0)
    with pytest.raises(KeyError):
        gm.aux("labels")


def test_a_part_always_in_its_own_segment_gets_split_evidence(device):
    gm, vase = plane_map(device)
    ev = SegmentEvidence(gm.device)
    for _ in range(3):
        ev.observe(gm, segments_with_vase(), POSE, K, DEPTH)
    r = ev.split_ratio(gm, min_views=3)
    inner = vase & (r > 0)
    assert int(inner.sum()) >= 10  # the vase's inner Gaussians (off the segment boundary)
    assert torch.all(r[inner] == 1.0)
    assert torch.all(r[~vase] == 0.0)  # the cabinet: always in the label's main segment
    assert ev.split_ratio(gm, min_views=4).max() == 0  # not enough views yet


def test_quick_split_needs_two_unanimous_views_or_one_confident_one(device):
    """A book first seen in the last keyframes: fewer than min_views views decide with ``quick`` when all
    of them showed the part apart, and there were two, or one came from a segment scored ``confident``."""
    for scores, views, decided in (
        ({1: 0.97, 2: 0.9}, 1, False),  # one view, the vase's segment scored low (a cut, say)
        ({1: 0.97, 2: 0.97}, 1, True),  # one confident view
        ({1: 0.97, 2: 0.9}, 2, True),  # two views, both apart
    ):
        gm, vase = plane_map(device)
        ev = SegmentEvidence(gm.device)
        for _ in range(views):
            ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, scores=scores, confident=0.95)
        assert ev.split_ratio(gm, min_views=3).max() == 0  # the default: three views
        r = ev.split_ratio(gm, min_views=3, quick=True)
        assert bool((r[vase] == 1.0).any()) == decided
        assert torch.all(r[~vase] == 0.0)
        if decided:  # a quick decision does not wait for the long-term decrease (split_below)
            out = ev.split_and_merge(gm, merge=False, min_views=3, quick=True, split_below=0.3, r_search=0.08)
            assert out["split_labels"] == 1 and torch.all(gm.labels[~vase] == 0)
    # a view that showed it together with its label keeps it undecided
    gm, vase = plane_map(device)
    ev = SegmentEvidence(gm.device)
    ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, scores={1: 0.97, 2: 0.97})
    ev.observe(gm, np.ones((H, W), np.int32), POSE, K, DEPTH, scores={1: 0.97})
    assert ev.split_ratio(gm, min_views=3, quick=True).max() == 0


def test_random_cuts_give_no_split(device):
    """A SAM cut that moves from view to view puts a Gaussian in a minority piece in a few views only."""
    gm, _ = plane_map(device)
    ev = SegmentEvidence(gm.device)
    for k in range(6):
        seg = np.ones((H, W), np.int32)
        if k % 3 == 0:
            seg[:, 10 * k // 3 + 5 : 10 * k // 3 + 25] = 2
        ev.observe(gm, seg, POSE, K, DEPTH)
    assert ev.split_ratio(gm, min_views=3).max() < 0.5


def test_lower_then_split_off_as_new_label(device):
    gm, vase = plane_map(device)
    ev = SegmentEvidence(gm.device)
    for _ in range(3):
        ev.observe(gm, segments_with_vase(), POSE, K, DEPTH)
    n = ev.lower_confidences(gm, min_views=3, split_ratio=0.5)
    split = ev.split_ratio(gm, 3) >= 0.5
    assert n == int(split.sum()) > 0
    assert torch.all(gm.confidences[split] < 0.3) and torch.all(gm.confidences[~split] == 0.9)
    out = ev.split_and_merge(gm, merge=False, min_views=3, split_below=0.3, r_search=0.08)
    assert out["split_labels"] == 1 and out["split_gaussians"] == int(split.sum())
    new = gm.labels[split]
    assert torch.all(new == new[0]) and int(new[0]) == 1  # one new label for the connected part
    assert torch.all(gm.labels[~split] == 0)
    assert torch.all(gm.confidences[split] == 0.5)
    # split_below = tau_low: without low confidence (no long-term step) nothing is split; the default
    # (1.0) lets the views decide whatever the confidence
    gm2, _ = plane_map(device)
    ev2 = SegmentEvidence(gm2.device)
    for _ in range(3):
        ev2.observe(gm2, segments_with_vase(), POSE, K, DEPTH)
    assert ev2.split_and_merge(gm2, merge=False, min_views=3, split_below=0.3)["split_labels"] == 0
    out = ev2.split_and_merge(gm2, merge=False, min_views=3, r_search=0.08)
    assert out["split_labels"] == 1 and out["split_gaussians"] == int(split.sum())
    assert torch.all(gm2.confidences[split] == 0.5) and torch.all(gm2.labels[~split] == 0)


def test_spill_pixels_leave_small_segments_whole(device):
    """Boundary pixels are left out of big segments only: a segment of a few pixels is nearly all boundary."""
    seg = torch.ones((H, W), dtype=torch.int64, device=device)
    seg[10:13, 10:13] = 2  # 3x3: one inner pixel
    seg[20:40, 30:60] = 3
    out = spill_pixels(seg).cpu()
    assert not out[10:13, 10:13].any()
    assert out[20, 35] and out[39, 40] and not out[30, 45]  # 3's border is left out, its inside kept
    assert out[9, 11] and out[13, 11]  # 1's pixels next to the small segment are 1's boundary
    assert not out[0, 0]


def test_a_small_object_gets_split_evidence(device):
    """A light switch of 3x3 pixels, absorbed into the wall's label, is judged from its few boundary pixels
    (before small segments kept their boundary it got no evidence at all)."""
    gm, _ = plane_map(device)
    seg = np.ones((H, W), np.int32)
    seg[20:23, 30:33] = 2
    u = torch.floor(K[0, 0] * gm.means[:, 0] / 2.0 + K[0, 2])
    v = torch.floor(K[1, 1] * gm.means[:, 1] / 2.0 + K[1, 2])
    switch = (u >= 30) & (u < 33) & (v >= 20) & (v < 23)
    assert int(switch.sum()) >= 3
    ev = SegmentEvidence(gm.device)
    for _ in range(3):
        ev.observe(gm, seg, POSE, K, DEPTH)
    r = ev.split_ratio(gm, min_views=3)
    assert torch.all(r[switch] == 1.0) and torch.all(r[~switch] == 0.0)


def test_protected_labels_are_owners_and_the_unjudged(device):
    """A label that holds its segment alone in min_views views is an object (protected); one that is always
    a small part of another label's segment is not; one not judged in min_views views is kept for now."""
    gm, vase = plane_map(device)
    gm.labels[vase] = 2  # the vase: its own segment in every view
    x = gm.means[:, 0]
    frag = (~vase) & (x > -0.2) & (x < -0.05) & (gm.means[:, 1] > 0.3)
    gm.labels[frag] = 4  # a fragment of the cabinet front, inside the cabinet's segment
    ev = SegmentEvidence(gm.device)
    for k in range(3):
        ev.observe(gm, segments_with_vase(), POSE, K, DEPTH)
        if k == 1:
            assert ev.protected_labels(6, min_views=3).tolist() == [True] * 6  # nothing judged 3 times yet
    prot = ev.protected_labels(6, min_views=3).tolist()
    assert prot[2] and not prot[4]
    assert not ev.protected_labels(6, min_views=3, min_owned=4)[2]  # owned in 3 views only
    assert prot[0]  # the cabinet holds its segment (the fragment is a small share of it)
    assert prot[1] and prot[3] and prot[5]  # never seen: not judged
    assert ev.protected_labels(70, min_views=3)[69]  # labels newer than the counters


def test_labels_mostly_in_one_segment_merge(device):
    """Left and right halves of one surface carry two labels; every view segments it whole: merged. A third
    label always in a segment of its own stays."""
    gm, vase = plane_map(device)
    x = gm.means[:, 0]
    gm.labels[x >= 0] = 1
    gm.labels[vase] = 2
    ev = SegmentEvidence(gm.device)
    for k in range(3):
        ev.observe(gm, segments_with_vase(), POSE, K, DEPTH)
        out = ev.split_and_merge(gm, split=False, min_views=3, merge_ratio=0.7)
        assert out["merged_labels"] == (1 if k == 2 else 0)
    assert torch.unique(gm.labels[~vase]).numel() == 1
    assert torch.all(gm.labels[vase] == 2)


def test_quick_merge_needs_firm_unanimous_views(device):
    """Two halves of a surface seen in fewer than min_views views: merged with ``quick_merge`` when every view
    held both in one segment, each a real part of it (``min_part``), and there were two such views or one
    confident one. A small object that a confident segment swallowed whole is too small a part to merge."""
    for scores, views, merged in (
        ({1: 0.9, 2: 0.97}, 1, False),  # one view, the shared segment scored low
        ({1: 0.97, 2: 0.97}, 1, True),  # one confident view
        ({1: 0.9, 2: 0.9}, 2, True),  # two unanimous views
    ):
        gm, vase = plane_map(device)
        gm.labels[gm.means[:, 0] >= 0] = 1
        gm.labels[vase] = 2
        ev = SegmentEvidence(gm.device)
        for _ in range(views):
            ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, scores=scores, confident=0.95, min_part=0.1)
        assert ev.split_and_merge(gm, split=False, min_views=3)["merged_labels"] == 0  # not without quick
        out = ev.split_and_merge(gm, split=False, min_views=3, quick_merge=True)
        assert out["merged_labels"] == int(merged)
        assert (torch.unique(gm.labels[~vase]).numel() == 1) == merged
        assert torch.all(gm.labels[vase] == 2)  # the vase always in a segment of its own
    # the vase swallowed by a confident segment (a whole-image one) in two views: a minor part, no merge
    gm, vase = plane_map(device)
    gm.labels[vase] = 2
    ev = SegmentEvidence(gm.device)
    for _ in range(2):
        ev.observe(gm, np.ones((H, W), np.int32), POSE, K, DEPTH, scores={1: 0.97}, min_part=0.1)
    assert ev.pair_together[0, 2] == 2 and ev.pair_firm[0, 2] == 0
    assert ev.split_and_merge(gm, split=False, min_views=3, quick_merge=True)["merged_labels"] == 0
    # a view that held them apart keeps them apart
    gm, vase = plane_map(device)
    gm.labels[gm.means[:, 0] >= 0] = 1
    ev = SegmentEvidence(gm.device)
    ev.observe(gm, np.ones((H, W), np.int32), POSE, K, DEPTH, scores={1: 0.97})
    halves = np.ones((H, W), np.int32)
    halves[:, 32:] = 2
    ev.observe(gm, halves, POSE, K, DEPTH, scores={1: 0.97, 2: 0.97})
    assert ev.split_and_merge(gm, split=False, min_views=3, quick_merge=True)["merged_labels"] == 0


def test_veto_undoes_a_relabel_between_labels_seen_apart(device):
    """A small object (label 2) always in its own segment keeps its label when Alg. 1 gives it the
    surrounding label 0; a relabel between labels never seen together in a view stands."""
    gm, vase = plane_map(device)
    gm.labels[vase] = 2
    ev = SegmentEvidence(gm.device)
    for _ in range(3):
        ev.observe(gm, segments_with_vase(), POSE, K, DEPTH)
    before = (gm.labels.clone(), gm.confidences.clone())
    gm.labels[vase] = 0  # what the individual refinement did
    gm.confidences[vase] = 0.5
    far = torch.nonzero(~vase).squeeze(1)[:5]
    gm.labels[far] = 7  # a label the evidence knows nothing about
    n = ev.veto(gm, *before, min_views=3, apart_ratio=0.3)
    assert n == int(vase.sum())
    assert torch.all(gm.labels[vase] == 2) and torch.all(gm.confidences[vase] == 0.9)
    assert torch.all(gm.labels[far] == 7)


def test_a_revisited_view_votes_only_for_gaussians_made_since(device):
    """The long-term step judges its memory views again: the Gaussians the view judged before get no second
    vote however often it is revisited, the ones made since get one, once; label counts are left alone."""
    gm, vase = plane_map(device)
    ev = SegmentEvidence(gm.device)
    ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, view=4)
    views = gm.aux("evidence_views").clone()
    seen = ev.label_seen.clone()
    ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, view=4, revisit=True)
    assert torch.equal(gm.aux("evidence_views"), views) and torch.equal(ev.label_seen, seen)
    n = len(gm)
    xs = torch.linspace(0.45, 0.75, 8)
    new = torch.stack([xs, torch.full((8,), -0.42), torch.full((8,), 2.0)], 1)  # inside the cabinet front
    gm.append(
        new, torch.full((8, 3), 0.5), torch.full((8,), -3.0),
        labels=torch.zeros(8, dtype=torch.int32), confidences=torch.full((8,), 0.9),
    )  # fmt: skip
    ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, view=4, revisit=True)
    v = gm.aux("evidence_views")
    assert torch.equal(v[:n], views[:n]) and torch.all(v[n:] == 1)
    ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, view=4, revisit=True)
    assert torch.all(gm.aux("evidence_views")[n:] == 1)


def test_a_revisit_gives_no_vote_to_the_views_own_gaussians(device):
    """A keyframe's own segments made its Gaussians: revisiting it must not count as a second view of them
    (the first keyframe, judged on an empty map, included), while Gaussians made later get its vote."""
    full, _ = plane_map(device)
    gm = GaussianMap(full.device)
    ev = SegmentEvidence(gm.device)
    ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, view=0)  # the first keyframe: nothing to judge yet
    gm.append(full.means, full.colors, full.log_scales, labels=full.labels, confidences=full.confidences)
    ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, view=1)  # the next keyframe
    views = gm.aux("evidence_views").clone()
    assert views.max() == 1
    ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, view=0, revisit=True)
    assert torch.equal(gm.aux("evidence_views"), views)
    n = len(gm)
    xs = torch.linspace(0.45, 0.75, 8)
    gm.append(
        torch.stack([xs, torch.full((8,), -0.42), torch.full((8,), 2.0)], 1), torch.full((8, 3), 0.5),
        torch.full((8,), -3.0), labels=torch.zeros(8, dtype=torch.int32), confidences=torch.full((8,), 0.9),
    )  # fmt: skip
    ev.observe(gm, segments_with_vase(), POSE, K, DEPTH, view=0, revisit=True)
    after = gm.aux("evidence_views")
    assert torch.equal(after[:n], views[:n]) and torch.all(after[n:] == 1)


def test_a_label_run_over_into_a_neighbour_is_lowered_and_relabelled(device):
    """Label 1 holds the right half of the plane and a strip of the left half (a cabinet's label that took
    in the floor in front of it); every view segments the halves apart. The strip lies in the left half's
    segment, which is label 0's, away from label 1's main segment: wrong-label evidence. The long-term
    decrease brings it low, and Algorithm 1 relabels it though label 1 is protected; the rest stays."""
    from ogscene3d.mapping.refine import global_refinement

    gm, _ = plane_map(device)
    x = gm.means[:, 0]
    gm.labels[x >= 0] = 1
    strip = (x < 0) & (x >= -0.12)  # two columns of Gaussians
    gm.labels[strip] = 1
    halves = np.ones((H, W), np.int32)
    halves[:, 32:] = 2
    ev = SegmentEvidence(gm.device)
    for k in range(3):
        ev.observe(gm, halves, POSE, K, DEPTH)
        if k == 1:  # two views decide with wrong_views 2, not with 3
            assert ev.wrong_ratio(gm, min_views=3).max() == 0 and ev.wrong_ratio(gm, min_views=2).max() == 1
    r = ev.wrong_ratio(gm, min_views=3)
    inner = strip & (r > 0)
    assert int(inner.sum()) >= 10 and torch.all(r[inner] == 1.0)
    assert torch.all(r[~strip] == 0.0)
    assert ev.split_ratio(gm, min_views=3).max() == 0  # not a part in a segment of its own
    assert ev.lower_confidences(gm, min_views=3, split_ratio=0.5) == 0  # the rule off
    n = ev.lower_confidences(gm, min_views=3, split_ratio=0.5, wrong=True, wrong_views=3)
    assert n == int(inner.sum()) and torch.all(gm.confidences[inner] < 0.3)
    exposed = ev.wrong_ratio(gm, 3) >= 0.5
    protected = torch.ones(2, dtype=torch.bool, device=gm.device)
    # the nearest confident Gaussian is often label 1's, right of the strip: an exposed Gaussian takes another
    # label than its own, the one the views contradict
    global_refinement(gm.means, gm.labels, gm.confidences, tau_low=0.3, tau_high=0.7, r_search=0.12,
                      protected=protected, exposed=exposed)  # fmt: skip
    assert torch.all(gm.labels[inner] == 0)
    assert torch.all(gm.labels[x >= 0] == 1)


def two_part_map(device: str) -> tuple[GaussianMap, torch.Tensor]:
    """Label 0 over two patches of the plane z = 2, apart in space (a gap of 0.25 m): the larger one left of
    x = 0.18 (pixels u < 37), the smaller right of x = 0.43 (u >= 42), a chair that a first view gave the
    floor's label. Returns the map and the mask of the smaller patch."""
    gm, _ = plane_map(device)
    x = gm.means[:, 0]
    keep = (x < 0.18) | (x > 0.43)
    gm.keep(keep)
    return gm, gm.means[:, 0] > 0.43


def two_segments() -> np.ndarray:
    seg = np.ones((H, W), np.int32)
    seg[:, 40:] = 2  # the gap's pixels are 37..41: either side holds one patch
    return seg


def test_a_part_of_a_label_in_another_segment_in_every_view_is_partitioned_off(device):
    gm, small = two_part_map(device)
    ev = SegmentEvidence(gm.device)
    for _ in range(3):
        ev.observe(gm, two_segments(), POSE, K, DEPTH)
    assert ev.partition(gm, r_search=0.1) == 1
    assert torch.all(gm.labels[~small] == 0)  # the largest group keeps the label
    assert torch.all(gm.labels[small] == 1)
    assert torch.all(gm.confidences[small] == 0.5) and torch.all(gm.confidences[~small] == 0.9)
    assert torch.all(gm.aux("evidence_views")[small] == 0)  # a new label's views start afresh
    assert ev.partition(gm, r_search=0.1) == 0  # nothing left to do


def test_parts_that_views_join_stay_one_label(device):
    """Separate patches of one surface (a floor seen through the legs of a table) are in one segment in
    most views; a view that cuts between them is outvoted."""
    gm, _ = two_part_map(device)
    ev = SegmentEvidence(gm.device)
    for k in range(4):
        ev.observe(gm, two_segments() if k == 0 else np.ones((H, W), np.int32), POSE, K, DEPTH)
    assert ev.partition(gm, r_search=0.1) == 0
    assert torch.all(gm.labels == 0)


def test_partition_needs_the_views_to_keep_parts_apart_in_most_views(device):
    """apart 0.25: one joint view of five leaves the parts apart (0.2), one of four joins them (0.25)."""
    for views, joint, parts in ((5, 1, 1), (4, 1, 0)):
        gm, _ = two_part_map(device)
        ev = SegmentEvidence(gm.device)
        for k in range(views):
            ev.observe(gm, np.ones((H, W), np.int32) if k < joint else two_segments(), POSE, K, DEPTH)
        assert ev.partition(gm, r_search=0.1, apart=0.25) == parts, (views, joint)


def test_a_surface_cut_at_random_places_is_not_partitioned(device):
    """One connected surface is one component, however the views cut it."""
    gm, _ = plane_map(device)
    ev = SegmentEvidence(gm.device)
    for cut in (12, 24, 36, 48):
        seg = np.ones((H, W), np.int32)
        seg[:, cut:] = 2
        ev.observe(gm, seg, POSE, K, DEPTH)
    assert ev.partition(gm, r_search=0.1) == 0
    assert torch.all(gm.labels == 0)


def test_parts_never_seen_together_stay_with_their_label(device):
    """No view saw both parts: nothing says they are two objects."""
    gm, _ = two_part_map(device)
    ev = SegmentEvidence(gm.device)
    seg = two_segments()
    left_only = np.where(np.arange(W)[None, :] < 37, seg, 0).astype(np.int32)
    right_only = np.where(np.arange(W)[None, :] >= 42, seg, 0).astype(np.int32)
    for view in (left_only, right_only, left_only):
        ev.observe(gm, view, POSE, K, DEPTH)
    assert ev.partition(gm, r_search=0.1) == 0


def test_each_gaussian_remembers_its_latest_views(device):
    from ogscene3d.mapping.evidence import SLOTS, remember_segments

    gm, _ = plane_map(device)
    rows = torch.arange(3, device=gm.device)
    for view in range(SLOTS + 2):
        remember_segments(gm, rows, torch.full((3,), 10 + view, device=gm.device), view)
    seen = sorted(int(gm.aux(f"evidence_seen{k}")[0]) for k in range(SLOTS))
    assert seen == list(range(2, SLOTS + 2))
    assert all(
        int(gm.aux(f"evidence_seg{k}")[0]) == 10 + int(gm.aux(f"evidence_seen{k}")[0]) for k in range(SLOTS)
    )
    assert float(gm.aux("evidence_seen0")[5]) == -1.0  # never judged


def test_split_and_merge_partitions_first_when_asked(device):
    gm, small = two_part_map(device)
    ev = SegmentEvidence(gm.device)
    for _ in range(3):
        ev.observe(gm, two_segments(), POSE, K, DEPTH)
    out = ev.split_and_merge(gm, split=False, merge=False, r_search=0.1)
    assert out["partitioned_labels"] == 0 and torch.all(gm.labels == 0)
    out = ev.split_and_merge(gm, split=False, merge=False, r_search=0.1, partition=True)
    assert out["partitioned_labels"] == 1 and ev.stats.partitioned_labels == 1
    assert torch.all(gm.labels[small] == 1)


def test_the_long_term_step_lowers_a_part_the_views_keep_apart_and_the_gate_waits_for_it(device):
    gm, small = two_part_map(device)
    ev = SegmentEvidence(gm.device)
    for _ in range(3):
        ev.observe(gm, two_segments(), POSE, K, DEPTH)
    # the refinement gated at tau_low: nothing is low yet
    assert ev.partition(gm, r_search=0.1, below=0.3) == 0 and torch.all(gm.labels == 0)
    assert ev.lower_partitioned(gm, r_search=0.1) == int(small.sum())
    assert torch.all(gm.confidences[small] == 0.0)  # apart in every view: Eq. 16's decrease by 1
    assert torch.all(gm.confidences[~small] == 0.9)
    assert ev.partition(gm, r_search=0.1, below=0.3) == 1
    assert torch.all(gm.labels[small] == 1) and torch.all(gm.labels[~small] == 0)
