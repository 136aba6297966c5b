import numpy as np
import pytest
import torch

from ogscene3d.config import LongtermConfig
from ogscene3d.mapping.longterm import (
    MemoryBuffer,
    MemoryEntry,
    associate_pixels,
    class_iou_map,
    eq16_update,
    frustum_ratio,
    inner_pixels,
    label_edges,
    remap_segments,
)

W, H, F = 32, 24, 20.0
K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]], dtype=np.float32)


def _rot_y(deg: float, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    a = np.radians(deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    T[:3, 3] = t
    return T


def _entry(pose: np.ndarray, kf: int) -> MemoryEntry:
    return MemoryEntry(kf, np.zeros((H, W, 3), np.uint8), np.full((H, W), 2.0, np.float32), K, pose, None)


def test_frustum_ratio():
    from ogscene3d.mapping.longterm import camera_points

    pc = camera_points(np.full((H, W), 2.0, np.float32), K.astype(np.float64), 2)
    assert frustum_ratio(pc, np.eye(4), np.eye(4), K, W, H) == 1.0
    assert frustum_ratio(pc, _rot_y(180), np.eye(4), K, W, H) == 0.0  # behind M_r
    half = frustum_ratio(pc, np.eye(4), _rot_y(0, (1.6, 0, 0)), K, W, H)  # shifted by half the view width
    assert 0.3 < half < 0.7


def test_memory_both_criteria(device):
    mem = MemoryBuffer(tau_long=0.5, r_search=0.1, point_step=2)
    dev = torch.device(device)
    assert mem.consider(_entry(np.eye(4), 0), dev)  # first keyframe always joins
    # same view again: R_in = 1 -> frustum criterion fails
    r_in, r_ov, _ = mem.criteria(_entry(np.eye(4), 1), dev)
    assert r_in == 1.0 and r_ov == 1.0
    assert not mem.consider(_entry(np.eye(4), 1), dev)
    # turned around: nothing in M_r's frustum and no overlap -> joins
    assert mem.consider(_entry(_rot_y(180), 2), dev)
    # back to the first view: outside the most recent frame's frustum (R_in = 0) but it overlaps the
    # first memory frame's points -> the geometric overlap criterion rejects it
    r_in, r_ov, _ = mem.criteria(_entry(np.eye(4), 3), dev)
    assert r_in == 0.0 and r_ov == 1.0
    assert not mem.consider(_entry(np.eye(4), 3), dev)
    assert [e.keyframe for e in mem.entries] == [0, 2]
    assert [e.keyframe for e in mem.next_views(1)] == [0]
    assert [e.keyframe for e in mem.next_views(2)] == [2, 0]


def test_memory_max_size(device):
    mem = MemoryBuffer(tau_long=0.5, r_search=0.1, max_size=2, point_step=4)
    for i, deg in enumerate([0, 90, 180, 270]):
        mem.consider(_entry(_rot_y(deg), i), torch.device(device))
    assert [e.keyframe for e in mem.entries] == [2, 3]


def test_memory_cap_holds_after_a_resume_and_empty_views_stay_out(device):
    dev = torch.device(device)
    mem = MemoryBuffer(tau_long=0.5, r_search=0.1, max_size=2, point_step=4)
    for i, deg in enumerate([0, 90, 180]):  # a checkpoint written with a larger memory_max
        mem.restore(_entry(_rot_y(deg), i), dev)
    assert [e.keyframe for e in mem.entries] == [1, 2]
    blind = _entry(_rot_y(270), 3)
    blind.depth = np.zeros_like(blind.depth)  # no valid depth: could judge nothing, would evict a view
    assert not mem.consider(blind, dev)
    assert [e.keyframe for e in mem.entries] == [1, 2]


def test_remap_and_class_iou(device):
    seg = torch.tensor([[1, 1, 2, 2], [1, 1, 2, 2], [0, 0, 3, 3]], device=device)
    ren = torch.tensor([[7, 7, 7, 8], [7, 9, 8, 8], [7, 7, -1, -1]], device=device)
    remapped = remap_segments(seg, ren)
    assert remapped.cpu().tolist() == [[7, 7, 8, 8], [7, 7, 8, 8], [-1, -1, -1, -1]]
    p, per_class = class_iou_map(remapped, ren)
    # class 7: S=7 at 6 pixels, Seg'=7 at 4, both at 3 -> 3/7; class 8: 3 vs 4 pixels, both 3 -> 3/4; 9: 0
    assert per_class == pytest.approx({7: 3 / 7, 8: 3 / 4, 9: 0.0})
    expected = torch.tensor([[3 / 7, 3 / 7, 3 / 7, 3 / 4], [3 / 7, 0, 3 / 4, 3 / 4], [3 / 7, 3 / 7, 0, 0]])
    torch.testing.assert_close(p.cpu(), expected)


def test_eq16():
    conf = torch.tensor([0.5, 0.5, 0.8, 0.0])
    p2d3d = torch.tensor([0.6, 0.6, 1.0, 0.5])
    pconf = torch.tensor([0.5, 0.25, 1.0, 0.5])
    cons = torch.tensor([True, False, False, True])
    out = eq16_update(conf, p2d3d, pconf, cons)
    torch.testing.assert_close(out, torch.tensor([0.5 + 0.6 * 0.5 * 0.5, 0.5 - 0.6 * 0.75 * 0.5, 0.8, 0.25]))


def test_associate_pixels(device):
    means = torch.tensor([[0.0, 0, 0], [1.0, 0, 0], [5.0, 0, 0]], device=device)
    labels = torch.tensor([3, 4, 5], dtype=torch.int32, device=device)
    pts = torch.tensor([[0.01, 0, 0], [0.0, 0.01, 0], [0.0, 0, 0.02], [1.0, 0.01, 0]], device=device)
    p = torch.tensor([0.2, 0.4, 0.6, 1.0], device=device)
    seg_label = torch.tensor([3, 3, 9, 9], device=device)
    hit, p_i, cons = associate_pixels(means, labels, pts, p, seg_label, k=1, radius=0.05)
    assert hit.cpu().tolist() == [0, 1]
    torch.testing.assert_close(p_i.cpu(), torch.tensor([0.4, 1.0]))
    assert cons.cpu().tolist() == [True, False]


def _wall_map(device):
    """A wall at z = 2 of Gaussians every 5 cm, label 0 left of x = 0 and label 1 right of it, conf 0.6."""
    from ogscene3d.gaussians import GaussianMap

    xs = torch.arange(-1.3, 1.31, 0.05)
    ys = torch.arange(-0.95, 0.96, 0.05)
    xx, yy = torch.meshgrid(xs, ys, indexing="ij")
    means = torch.stack([xx.reshape(-1), yy.reshape(-1), torch.full((xx.numel(),), 2.0)], 1)
    labels = (means[:, 0] >= 0).int()
    gm = GaussianMap(device)
    gm.append(
        means.to(device),
        torch.full_like(means, 0.5).to(device),
        torch.full((len(means),), float(np.log(0.04))),
        labels=labels,
        confidences=torch.full((len(means),), 0.6),
        opacity_logits=torch.full((len(means),), 2.0),
    )
    return gm, labels


def _wall_entry(split_u: int) -> MemoryEntry:
    """A 32x24 view of the wall (f = 24, 2 m away) whose stored segmentation splits at column ``split_u``."""
    K2 = np.array([[24.0, 0, 16], [0, 24.0, 12], [0, 0, 1]], np.float32)
    u = np.arange(32)
    seg = np.broadcast_to(np.where(u < split_u, 1, 2)[None, :], (24, 32)).astype(np.int32)
    depth = np.full((24, 32), 2.0, np.float32)
    return MemoryEntry(0, np.zeros((24, 32, 3), np.uint8), depth, K2, np.eye(4), seg, {1: 0.95, 2: 0.95})


def test_label_edges():
    ids = torch.tensor([[1, 1, 2], [1, 1, 2], [3, 3, 3]])
    expect = torch.tensor([[0, 1, 1], [1, 1, 1], [1, 1, 1]], dtype=torch.bool)
    assert torch.equal(label_edges(ids), expect)
    assert not label_edges(torch.zeros(4, 5, dtype=torch.long)).any()


@pytest.mark.parametrize("skip_edges", [True, False])
def test_longterm_skips_boundary_pixels(device, skip_edges):
    """The stored segmentation splits the wall two pixels right of where the labels change (x = 0 is
    between u = 15 and 16, SAM's boundary between u = 17 and 18). Only the columns u = 16, 17 disagree,
    and each lies on a boundary: with ``skip_edges`` nothing loses confidence, without it the label-1
    Gaussians there do."""
    from ogscene3d.mapping.longterm import longterm_view_update

    gm, _ = _wall_map(device)
    cfg = LongtermConfig(knn_k=4, pixel_step=1, skip_edges=skip_edges)
    st = longterm_view_update(gm, _wall_entry(18), cfg, 0.08)
    assert st.updated > 0 and st.increased > 0
    if skip_edges:
        assert st.decreased == 0
    else:
        assert st.decreased > 0
        lost = gm.confidences.cpu() < 0.6
        assert bool((gm.labels.cpu()[lost] == 1).all())


def test_longterm_same_class_off_is_the_papers_rule(device):
    """Without ``same_class`` a pixel reaches its nearest Gaussians whatever their label (the paper's
    rule): near the label boundary more Gaussians are judged, and more lose confidence."""
    from ogscene3d.mapping.longterm import longterm_view_update

    stats = {}
    for same_class in (True, False):
        gm, _ = _wall_map(device)
        cfg = LongtermConfig(knn_k=4, pixel_step=1, skip_edges=False, same_class=same_class)
        stats[same_class] = longterm_view_update(gm, _wall_entry(18), cfg, 0.08)
    assert stats[False].updated > stats[True].updated
    assert stats[False].decreased > stats[True].decreased > 0


def test_longterm_view_update_eq16(device):
    """A wall with label 0 left of x = 0 and label 1 right of it; the stored segmentation puts the band
    0 <= x < 0.33 into the left segment, so label-1 Gaussians there become inconsistent and lose confidence
    while all others gain. Labels never change."""
    from ogscene3d.mapping.longterm import longterm_view_update

    gm, labels = _wall_map(device)
    entry = _wall_entry(20)  # x = 0.33 at u = 20
    st = longterm_view_update(gm, entry, LongtermConfig(knn_k=4, pixel_step=1, skip_edges=False), 0.08)
    assert st.updated > 0 and st.increased > 0 and st.decreased > 0
    conf = gm.confidences.cpu()
    x = gm.means[:, 0].cpu()
    assert torch.equal(gm.labels.cpu(), labels)
    # (a few Gaussians are nobody's k nearest: the pixel grid is coarser than the Gaussians; they keep 0.6)
    for region, gain in (
        ((x < -0.2) & (x > -1.2), True),
        ((x > 0.05) & (x < 0.25), False),
        ((x > 0.5) & (x < 1.2), True),
    ):
        c = conf[region]
        changed = c > 0.6 if gain else c < 0.6
        assert bool((changed | (c == 0.6)).all()) and float(changed.float().mean()) > 0.9


def test_associate_pixels_only_with_rendered_class(device):
    means = torch.tensor([[0.0, 0, 0], [0.01, 0, 0]], device=device)  # label 3 and, right beside it, label 4
    labels = torch.tensor([3, 4], dtype=torch.int32, device=device)
    pts = torch.tensor([[0.0, 0.0, 0.001]], device=device)
    p = torch.tensor([0.9], device=device)
    seg_label = torch.tensor([3], device=device)
    hit, _, _ = associate_pixels(means, labels, pts, p, seg_label, k=2, radius=0.05)
    assert hit.cpu().tolist() == [0, 1]  # plain KNN also reaches the neighbour of another class
    hit, p_i, cons = associate_pixels(
        means, labels, pts, p, seg_label, k=2, radius=0.05, pixel_rendered=torch.tensor([3], device=device)
    )
    assert hit.cpu().tolist() == [0] and cons.cpu().tolist() == [True]


def test_inner_pixels_are_off_segment_boundaries(device):
    segments = np.zeros((4, 6), dtype=np.int32)
    segments[:, 3:] = 5  # columns 2 and 3 touch the boundary
    # flat v * 6 + u of (v, u) = (0,0) (0,2) (0,3) (0,5) (1,1) (3,4)
    pix = torch.tensor([0, 2, 3, 5, 6 + 1, 18 + 4], device=device)
    for dtype in (np.int32, np.uint16):  # segment PNGs load as uint16
        inner = inner_pixels(segments.astype(dtype), pix)
        assert inner.tolist() == [True, False, False, True, True, True]
