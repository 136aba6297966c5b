"""Multi-view co-segmentation evidence (mapping/evidence.py) on small hand-built scenes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ogscene3d.gaussians import GaussianMap
from ogscene3d.mapping.evidence import SegmentEvidence

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
    out = ev.split_and_merge(gm, merge=False, min_views=3, tau_low=0.3, r_search=0.08)
    assert out["split_labels"] == 1 and out["split_gaussians"] == int(split.sum())
    new = gm.labels[split]
    assert torch.all(new == new[0]) and int(new[0]) == 1  # one new label for the connected part
    assert torch.all(gm.labels[~split] == 0)
    assert torch.all(gm.confidences[split] == 0.5)
    # without low confidence (no long-term step) nothing is split
    gm2, _ = plane_map(device)
    ev2 = SegmentEvidence(gm2.device)
    for _ in range(3):
        ev2.observe(gm2, segments_with_vase(), POSE, K, DEPTH)
    assert ev2.split_and_merge(gm2, merge=False, min_views=3, tau_low=0.3)["split_labels"] == 0


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
