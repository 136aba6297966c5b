import pytest
import torch

from ogscene3d.config import InitConfig
from ogscene3d.mapping.local import (
    CASE_AMBIGUOUS,
    CASE_MATCHED,
    CASE_NOVEL,
    associate_segments,
    eq5_update,
    fill_unlabeled,
    group_top2,
    rescale_sam_scores,
    update_confidences,
)


def _patch(x0: float, n: int = 4, spacing: float = 0.05) -> torch.Tensor:
    """n x n points on the z=0 plane starting at (x0, 0)."""
    u = torch.arange(n, dtype=torch.float32) * spacing
    xx, yy = torch.meshgrid(u + x0, u, indexing="ij")
    return torch.stack([xx.reshape(-1), yy.reshape(-1), torch.zeros(n * n)], 1)


class _Labels:
    def __init__(self, start: int) -> None:
        self.next = start

    def __call__(self, count: int) -> torch.Tensor:
        out = torch.arange(self.next, self.next + count, dtype=torch.int32)
        self.next += count
        return out


def _scene(device):
    a = _patch(0.0)  # label 3
    b = _patch(1.0)  # label 4
    means = torch.cat([a, b]).to(device)
    labels = torch.cat([torch.full((16,), 3), torch.full((16,), 4)]).int().to(device)
    conf = torch.full((32,), 0.6, device=device)
    return means, labels, conf


def test_three_association_cases(device):
    means, labels, conf = _scene(device)
    eps = torch.tensor([0.0, 0.0, 0.005])
    probes = torch.cat(
        [
            _patch(0.0) + eps,  # segment 0: on top of label 3 -> case (ii)
            _patch(0.0, n=2) + eps,  # segment 1: half on label 3 ...
            _patch(1.0, n=2) + eps,  # ... and half on label 4 -> r = 1 -> case (i)
            _patch(5.0) + eps,  # segment 2: nowhere near the scene -> case (iii)
        ]
    ).to(device)
    seg = torch.tensor([0] * 16 + [1] * 8 + [2] * 16, device=device)
    pconf = torch.full((40,), 0.9, device=device)
    res = associate_segments(probes, seg, pconf, 3, means, labels, conf, _Labels(10), k=1, radius=0.02)
    assert res.seg_case.tolist() == [CASE_MATCHED, CASE_AMBIGUOUS, CASE_NOVEL]
    assert res.seg_labels.tolist() == [3, -1, 10]
    torch.testing.assert_close(res.r.cpu(), torch.tensor([0.0, 1.0, 0.0]))
    torch.testing.assert_close(res.p.cpu(), torch.tensor([1.0, 0.5, 0.0]))
    # Eq. 5 only for the Gaussians matched by the case-(ii) segment: all 16 of label 3, consistent
    assert sorted(res.updated.tolist()) == list(range(16))
    torch.testing.assert_close(conf[:16].cpu(), torch.full((16,), 0.6 + 0.9 * 1.0 * 0.4))
    torch.testing.assert_close(conf[16:].cpu(), torch.full((16,), 0.6))  # case (i) updates nothing
    assert res.counts() == {"ambiguous": 1, "matched": 1, "novel": 1, "conf_updates": 16, "filled": 0}


def test_low_coherence_is_novel(device):
    """A segment mostly in empty space with a few consistent matches: r = 0 but p < tau_p -> new label."""
    means, labels, conf = _scene(device)
    probes = torch.cat([_patch(0.0, n=1), _patch(3.0, n=4)]).to(device)  # 1 of 17 probes matched
    seg = torch.zeros(17, dtype=torch.long, device=device)
    res = associate_segments(
        probes, seg, torch.ones(17, device=device), 1, means, labels, conf, _Labels(7), k=1, radius=0.02
    )
    assert res.seg_case.tolist() == [CASE_NOVEL] and res.seg_labels.tolist() == [7]
    torch.testing.assert_close(res.p.cpu(), torch.tensor([1 / 17]))
    assert res.updated.numel() == 0 and torch.all(conf == 0.6)


def test_new_object_matched_only_at_its_border_gets_a_label(device):
    """A door in a wall: 16 of its 18 probes are new, its 2 border probes lie on the wall edge (label 3) with
    a chair (label 4) a little farther. With the default k (one vote per probe) r = 0 and p < tau_p: a new
    label. With k = 5 each border probe also votes for the chair twice, r = 0.5 >= tau_valid, and the door
    would be left unlabelled at every view."""
    from ogscene3d.config import MappingConfig

    means = torch.tensor(
        [
            [0.0, 0.0, 0.0],
            [0.0, 0.1, 0.0],
            [0.0, 0.0, 0.016],
            [0.0, 0.0, -0.016],
            [0.0, 0.1, 0.016],
            [0.0, 0.1, -0.016],
        ]
    ).to(device)
    labels = torch.tensor([3, 3, 4, 4, 4, 4], dtype=torch.int32, device=device)
    border = torch.tensor([[0.01, 0.0, 0.0], [0.01, 0.1, 0.0]])
    probes = torch.cat([border, _patch(2.0)]).to(device)
    seg = torch.zeros(18, dtype=torch.long, device=device)
    default = MappingConfig().association.knn_k
    out = {}
    for k in (default, 5):
        conf = torch.full((6,), 0.6, device=device)
        out[k] = associate_segments(
            probes,
            seg,
            torch.ones(18, device=device),
            1,
            means,
            labels,
            conf,
            _Labels(7),
            k=k,
            radius=0.02,
            novel_before_ambiguous=False,  # the paper's order, where k decides
        )
    assert out[default].seg_case.tolist() == [CASE_NOVEL] and out[default].seg_labels.tolist() == [7]
    assert out[5].seg_case.tolist() == [CASE_AMBIGUOUS] and out[5].seg_labels.tolist() == [-1]
    torch.testing.assert_close(out[5].r.cpu(), torch.tensor([0.5]))


@pytest.mark.parametrize("novel_first", [True, False])
def test_small_new_object_between_two_surfaces(device, novel_first):
    """A bin on the floor (label 3) against a wall (label 4): 20 probes, two border probes lie on the floor
    and one on the wall, the rest are new. r = 1/2 >= tau_valid and p = 2/20 < tau_p. The default tests
    case (iii) first and gives the bin a new label; the paper's order leaves it unlabelled."""
    from ogscene3d.config import MappingConfig

    assert MappingConfig().association.novel_before_ambiguous
    means = torch.tensor([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 1.0, 0.0]], device=device)
    labels = torch.tensor([3, 3, 4], dtype=torch.int32, device=device)
    border = torch.tensor([[0.0, 0.0, 0.005], [0.05, 0.0, 0.005], [0.0, 1.0, 0.005]])
    probes = torch.cat([border, _patch(3.0, n=5)[:17]]).to(device)
    seg = torch.zeros(20, dtype=torch.long, device=device)
    conf = torch.full((3,), 0.6, device=device)
    res = associate_segments(
        probes,
        seg,
        torch.ones(20, device=device),
        1,
        means,
        labels,
        conf,
        _Labels(9),
        k=1,
        radius=0.02,
        novel_before_ambiguous=novel_first,
    )
    torch.testing.assert_close(res.r.cpu(), torch.tensor([0.5]))
    torch.testing.assert_close(res.p.cpu(), torch.tensor([0.1]))
    if novel_first:
        assert res.seg_case.tolist() == [CASE_NOVEL] and res.seg_labels.tolist() == [9]
    else:
        assert res.seg_case.tolist() == [CASE_AMBIGUOUS] and res.seg_labels.tolist() == [-1]
    assert res.updated.numel() == 0 and torch.all(conf == 0.6)  # neither case updates confidences


def test_eq5_inconsistent_matches_lose_confidence(device):
    """10 matches of label 3 and 1 of label 4: r = 0.1 < tau_valid, p = 10/11 -> label 3; the label-4 scene
    Gaussian loses confidence by c_sam * p * conf, the label-3 ones gain c_sam * p * (1 - conf)."""
    a = _patch(0.0)[:10]
    b = torch.tensor([[0.5, 0.5, 0.0]])
    means = torch.cat([a, b]).to(device)
    labels = torch.tensor([3] * 10 + [4], dtype=torch.int32, device=device)
    conf = torch.tensor([0.4] * 10 + [0.8], device=device)
    probes = means + torch.tensor([0.0, 0.0, 0.001], device=device)
    seg = torch.zeros(11, dtype=torch.long, device=device)
    c_sam = torch.full((11,), 0.75, device=device)
    res = associate_segments(probes, seg, c_sam, 1, means, labels, conf, _Labels(5), k=1, radius=0.02)
    p = 10 / 11
    assert res.seg_labels.tolist() == [3]
    torch.testing.assert_close(res.r.cpu(), torch.tensor([0.1]))
    torch.testing.assert_close(conf[:10].cpu(), torch.full((10,), 0.4 + 0.75 * p * 0.6))
    torch.testing.assert_close(conf[10:].cpu(), torch.tensor([0.8 - 0.75 * p * 0.8]))


def test_eq5_deferred_runs_once_for_the_cases_as_they_stand(device):
    """eq5=False leaves confidences alone; update_confidences then updates the matches of every segment
    that is case (ii) by then (a caller may turn an ambiguous one into a matched one first), once."""
    means, labels, conf = _scene(device)
    eps = torch.tensor([0.0, 0.0, 0.005])
    probes = torch.cat([_patch(0.0, n=2) + eps, _patch(1.0, n=2) + eps]).to(device)
    seg = torch.zeros(8, dtype=torch.long, device=device)
    pconf = torch.full((8,), 0.9, device=device)
    res = associate_segments(
        probes, seg, pconf, 1, means, labels, conf, _Labels(10), k=1, radius=0.02, eq5=False
    )
    assert res.seg_case.tolist() == [CASE_AMBIGUOUS] and res.updated is None and torch.all(conf == 0.6)
    # as the mapper's merge does: labels 3 and 4 become one, the segment matched with p = 1
    labels[labels == 4] = 3
    res.seg_case[0], res.seg_labels[0], res.p[0] = CASE_MATCHED, 3, 1.0
    upd = update_confidences(res, pconf, labels, conf)
    assert sorted(upd.tolist()) == [0, 1, 4, 5, 16, 17, 20, 21]
    torch.testing.assert_close(conf[upd].cpu(), torch.full((8,), 0.6 + 0.9 * 0.4))
    assert res.counts()["conf_updates"] == 8
    with pytest.raises(RuntimeError, match="already ran"):
        update_confidences(res, pconf, labels, conf)


def test_naive_takes_majority_without_ambiguity_test(device):
    means, labels, conf = _scene(device)
    probes = torch.cat([_patch(0.0, n=3), _patch(1.0, n=2), _patch(8.0, n=2)]).to(device)
    seg = torch.tensor([0] * 13 + [1] * 4, device=device)
    res = associate_segments(
        probes,
        seg,
        torch.ones(17, device=device),
        2,
        means,
        labels,
        conf,
        _Labels(9),
        k=1,
        radius=0.02,
        naive=True,
    )
    # segment 0: 9 matches of 3 and 4 of 4 -> majority 3 (the paper's test would call r = 4/9 ambiguous)
    assert res.seg_labels.tolist() == [3, 9]
    assert torch.all(conf == 0.6)


def test_eq5_formula_and_bounds():
    conf = torch.tensor([0.2, 0.2, 1.0, 0.0])
    c = torch.tensor([1.0, 0.5, 1.0, 1.0])
    p = torch.tensor([0.5, 0.5, 1.0, 1.0])
    cons = torch.tensor([True, False, True, False])
    out = eq5_update(conf, c, p, cons)
    torch.testing.assert_close(out, torch.tensor([0.2 + 0.5 * 0.8, 0.2 - 0.25 * 0.2, 1.0, 0.0]))


def test_rescale_sam_scores():
    s = torch.tensor([0.5, 0.88, 0.94, 1.0, 1.2])
    torch.testing.assert_close(rescale_sam_scores(s), torch.tensor([0.5, 0.5, 0.75, 1.0, 1.0]))
    with pytest.raises(ValueError):
        rescale_sam_scores(s, (1.0, 0.88))


def test_group_top2():
    g = torch.tensor([0, 0, 0, 1, 1, 2, 0])
    v = torch.tensor([5, 5, 3, 7, 7, 1, 3])
    top1, c1, top2, c2 = group_top2(g, v, 4)
    assert top1.tolist() == [3, 7, 1, -1] and c1.tolist() == [2, 2, 1, 0]
    assert top2.tolist() == [5, -1, -1, -1] and c2.tolist() == [2, 0, 0, 0]


def test_fill_unlabeled(device):
    """Unlabeled scene Gaussians under a labeled segment take its label and confidence; under an ambiguous
    segment or far from every probe they stay unlabeled."""
    means, labels, conf = _scene(device)
    extra = torch.cat([_patch(0.2, n=2), _patch(3.0, n=2)]).to(device)  # beside label 3 / far away
    means = torch.cat([means, extra])
    labels = torch.cat([labels, torch.full((8,), -1, dtype=torch.int32, device=device)])
    conf = torch.cat([conf, torch.zeros(8, device=device)])
    probes = torch.cat([_patch(0.0, n=6)]).to(device) + torch.tensor([0.0, 0.0, 0.005], device=device)
    seg = torch.zeros(36, dtype=torch.long, device=device)
    c_sam = torch.full((36,), 0.8, device=device)
    res = associate_segments(probes, seg, c_sam, 1, means, labels, conf, _Labels(9), k=1, radius=0.02)
    filled = fill_unlabeled(probes, seg, c_sam, res.seg_labels, means, labels, conf, 0.02)
    assert res.seg_labels.tolist() == [3] and filled == 4
    assert labels[32:].tolist() == [3, 3, 3, 3, -1, -1, -1, -1]
    torch.testing.assert_close(conf[32:36].cpu(), torch.full((4,), 0.8))


def test_probe_radius_matches_sparser_far_probes(device):
    """Probes 4 cm above the label-3 patch: outside the 2 cm fixed radius (a novel segment), inside a
    per-probe radius of 5 cm (the same object: case ii). A per-probe radius below ``radius`` never
    shrinks it."""
    means, labels, conf = _scene(device)
    probes = (_patch(0.0) + torch.tensor([0.0, 0.0, 0.04])).to(device)
    seg = torch.zeros(16, dtype=torch.long, device=device)
    pconf = torch.full((16,), 0.9, device=device)
    args = (probes, seg, pconf, 1, means, labels, conf.clone(), _Labels(10))
    fixed = associate_segments(*args, k=1, radius=0.02)
    assert fixed.seg_case.tolist() == [CASE_NOVEL] and fixed.seg_labels.tolist() == [10]
    wide = associate_segments(*args, k=1, radius=0.02, probe_radius=torch.full((16,), 0.05, device=device))
    assert wide.seg_case.tolist() == [CASE_MATCHED] and wide.seg_labels.tolist() == [3]
    torch.testing.assert_close(wide.p.cpu(), torch.tensor([1.0]))
    # half of the probes get a wide radius: p = 0.5 >= tau_p, still matched; the others find nothing
    half = torch.tensor([0.05] * 8 + [0.001] * 8, device=device)
    res = associate_segments(*args, k=1, radius=0.02, probe_radius=half)
    assert res.seg_labels.tolist() == [3]
    torch.testing.assert_close(res.p.cpu(), torch.tensor([0.5]))


def test_probe_updates_limit_eq5_to_inner_probes(device):
    """A table (label 3) with a cup (label 4) at its edge: the table's segment, case (ii), has one probe at
    the cup's base whose nearest Gaussian is the cup's. Where that probe may update (no mask) the cup loses
    confidence at every such view; with ``probe_updates`` false for it (it lies on the segment boundary)
    only the table's Gaussians are updated."""
    table = _patch(0.0)
    cup = torch.tensor([[0.2, 0.0, 0.0]])
    means = torch.cat([table, cup]).to(device)
    labels = torch.tensor([3] * 16 + [4], dtype=torch.int32, device=device)
    probes = torch.cat([table, cup]).to(device) + torch.tensor([0.0, 0.0, 0.005], device=device)
    seg = torch.zeros(17, dtype=torch.long, device=device)
    inner = torch.tensor([True] * 16 + [False], device=device)
    out = {}
    for name, mask in (("all", None), ("inner", inner)):
        conf = torch.full((17,), 0.6, device=device)
        res = associate_segments(
            probes,
            seg,
            torch.ones(17, device=device),
            1,
            means,
            labels,
            conf,
            _Labels(9),
            k=1,
            radius=0.02,
            probe_updates=mask,
        )
        assert res.seg_labels.tolist() == [3]
        out[name] = (conf.cpu(), sorted(res.updated.tolist()))
    conf_all, upd_all = out["all"]
    conf_inner, upd_inner = out["inner"]
    assert upd_all == list(range(17)) and upd_inner == list(range(16))
    assert float(conf_all[16]) < 0.6 and float(conf_inner[16]) == pytest.approx(0.6)
    torch.testing.assert_close(conf_all[:16], conf_inner[:16])


def test_make_probes_negative_segment_ids_are_no_segment(device):
    # Frame.segments: 0 or negative = no segment. A negative id must not shift the other segments' indices
    import numpy as np

    from ogscene3d.frame import Frame
    from ogscene3d.mapping.init import make_probes

    h, w = 4, 6
    ids = np.zeros((h, w), dtype=np.int32)
    ids[:, :2] = -1
    ids[:, 2:4] = 5
    ids[:, 4:] = 7
    K = np.array([[10.0, 0, w / 2], [0, 10.0, h / 2], [0, 0, 1]], dtype=np.float32)
    frame = Frame(0, np.zeros((h, w, 3), np.uint8), np.ones((h, w), np.float32), K, np.eye(4), segments=ids)
    probes = make_probes(
        frame, ids, {5: 0.88, 7: 1.0}, torch.device(device), InitConfig(pixels_per_gaussian=1)
    )
    assert probes.seg_ids.tolist() == [5, 7]
    col = (probes.pix % w).cpu()
    seg = probes.seg.cpu()
    assert (seg[col < 2] == -1).all()
    assert (seg[(col >= 2) & (col < 4)] == 0).all()
    assert (seg[col >= 4] == 1).all()
    conf = probes.conf.cpu()
    assert torch.allclose(conf[col < 2], torch.tensor(0.0))
    assert torch.allclose(conf[(col >= 2) & (col < 4)], torch.tensor(0.5))
    assert torch.allclose(conf[col >= 4], torch.tensor(1.0))


def test_make_probes_small_segments_get_every_pixel(device):
    """A segment with fewer grid probes than ``dense_below`` (a book a few pixels across) gets a probe at
    every valid-depth pixel, each one pixel's footprint; the other segments keep the grid."""
    import math

    import numpy as np

    from ogscene3d.frame import Frame
    from ogscene3d.mapping.init import make_probes

    h, w = 16, 16
    ids = np.ones((h, w), dtype=np.int32)
    ids[5:8, 9:12] = 2  # 9 pixels, 2 or so grid probes at step 2
    depth = np.full((h, w), 2.0, np.float32)
    depth[7, 11] = 0.0  # no depth: no probe
    K = np.array([[20.0, 0, w / 2], [0, 20.0, h / 2], [0, 0, 1]], dtype=np.float32)
    frame = Frame(0, np.zeros((h, w, 3), np.uint8), depth, K, np.eye(4), segments=ids)
    dev = torch.device(device)
    sparse = make_probes(frame, ids, {}, dev, InitConfig(pixels_per_gaussian=4, dense_below=0))
    dense = make_probes(frame, ids, {}, dev, InitConfig(pixels_per_gaussian=4, dense_below=8))
    seg_of = lambda p: p.seg_ids[p.seg.clamp(min=0)].cpu()  # noqa: E731
    assert int((seg_of(sparse) == 2).sum()) < 8
    small = seg_of(dense) == 2
    assert int(small.sum()) == 8
    assert sorted(dense.pix[small].tolist()) == sorted(
        v * w + u for v in range(5, 8) for u in range(9, 12) if (v, u) != (7, 11)
    )
    assert int((seg_of(dense) == 1).sum()) == int((seg_of(sparse) == 1).sum())  # the big one: the grid
    on_grid = (dense.pix // w % 2 == 1) & (dense.pix % w % 2 == 1)
    off = small.to(dense.pix.device) & ~on_grid
    assert off.any()
    torch.testing.assert_close(
        dense.log_scales[off].cpu(), torch.full((int(off.sum()),), math.log(2.0 * 1 / 20.0))
    )
    big_enough = make_probes(frame, ids, {}, dev, InitConfig(pixels_per_gaussian=4, dense_below=2))
    assert torch.equal(big_enough.pix, sparse.pix)


def test_make_probes_small_segment_uncovered_pixels_become_gaussians(device):
    """A small segment's pixels that the map explains (alpha) but where no Gaussian centre lies within a
    pixel's footprint become new Gaussians (a book that an earlier view merged with its shelf is covered by
    the shelf's Gaussians, a grid cell or more apart), except one whose depth is the background's; with a
    centre at every pixel, none do."""
    import numpy as np

    from ogscene3d.frame import Frame
    from ogscene3d.mapping.init import DENSE_DEPTH, make_probes

    h, w = 16, 16
    ids = np.ones((h, w), dtype=np.int32)
    ids[5:8, 9:12] = 2
    depth = np.full((h, w), 2.0, np.float32)
    depth[7, 10] = 2.0 + 2 * DENSE_DEPTH  # the wall seen past the object's edge
    K = np.array([[20.0, 0, w / 2], [0, 20.0, h / 2], [0, 0, 1]], dtype=np.float32)
    frame = Frame(0, np.zeros((h, w, 3), np.uint8), depth, K, np.eye(4), segments=ids)
    dev = torch.device(device)
    explained = (torch.ones(h, w), torch.full((h, w), 2.0))  # alpha 1, the observed depth: every pixel
    vv, uu = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    centres = torch.stack(
        [(uu + 0.5 - w / 2) / 20.0 * 2.0, (vv + 0.5 - h / 2) / 20.0 * 2.0, 2.0 + 0 * uu], -1
    )
    everywhere = centres.reshape(-1, 3).float().to(dev)
    away = ((vv - 6).abs() > 3) | ((uu - 10).abs() > 3)  # none within 3 pixels of the small segment
    coarse = centres[away].reshape(-1, 3).float().to(dev)
    cfg = InitConfig(pixels_per_gaussian=4, dense_below=8)
    kw = {"rendered": explained}
    assert not make_probes(frame, ids, {}, dev, cfg, **kw).new.any()
    assert not make_probes(frame, ids, {}, dev, cfg, map_means=everywhere, **kw).new.any()
    p = make_probes(frame, ids, {}, dev, cfg, map_means=coarse, **kw)
    small = (p.seg_ids[p.seg.clamp(min=0)] == 2) & (p.seg >= 0)
    on_grid = (p.pix // w % 2 == 1) & (p.pix % w % 2 == 1)
    background = p.pix == 7 * w + 10
    assert torch.equal(p.new.cpu(), (small & ~on_grid & ~background).cpu())  # grid probes: not tested
    assert int(p.new.sum()) == 9 - 4 - 1


def test_segment_medians_match_torch_median(device):
    """The per-segment median depth, sorted once for all segments, is ``torch.median`` of each segment's
    depths (the lower middle for an even count); a segment without probes reads 0."""
    from ogscene3d.mapping.init import _segment_medians

    g = torch.Generator().manual_seed(3)
    z = torch.rand(200, generator=g, dtype=torch.float64) * 4
    seg = torch.randint(-1, 6, (200,), generator=g)
    seg[seg == 4] = 5  # segment 4: no probes
    got = _segment_medians(z.to(device), seg.to(device), 7).cpu()
    for s in range(7):
        want = z[seg == s].median() if (seg == s).any() else torch.tensor(0.0, dtype=z.dtype)
        assert got[s] == want, s
