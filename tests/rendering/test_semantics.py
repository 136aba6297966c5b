"""Semantic voting and rendering contribution against the dense one-hot / autograd reference."""

import math

import pytest
import torch
from reference_semantic import semantic_reference
from scenes import cameras, random_scene

from ogscene3d import render_semantics, rendering_contribution


def _compare(device, scene, labels, conf, width, height, pixel_mask=None, buffer_size=8, tile_size=16):
    vm, K = cameras(width, height, device=device)
    gaussians = (*scene, labels, conf)
    sizes = dict(buffer_size=buffer_size, tile_size=tile_size)
    sem = render_semantics(*gaussians, vm, K, width, height, **sizes)
    view = (vm[0], K[0], width, height)
    p = rendering_contribution(*gaussians, *view, pixel_mask=pixel_mask, **sizes)
    ref_lab, R, _, ref_p = semantic_reference(*gaussians, *view, pixel_mask=pixel_mask, tile_size=tile_size)
    got = sem.labels[0].cpu().long()
    # ties aside: pixels whose two best reference votes are within 1e-5 may legitimately differ
    if R.shape[1] >= 2:
        top2 = R.topk(2, dim=1).values
        clear = (top2[:, 0] - top2[:, 1] > 1e-5).reshape(height, width)
    else:
        clear = torch.ones(height, width, dtype=torch.bool)
    agree = (got == ref_lab)[clear].double().mean()
    assert agree >= 0.995, float(agree)
    ref_w = R.max(dim=1).values.reshape(height, width) if R.shape[1] else torch.zeros(height, width)
    assert (sem.weights[0].cpu().double() - ref_w).abs().max() < 1e-4
    assert p.shape == labels.shape and p.dtype == torch.float32
    assert (p.cpu().double() - ref_p).abs().max() < 1e-4
    assert float(p.min()) >= 0 and float(p.max()) <= 1
    return sem, p, ref_p


def _scene(n, seed, device):
    means, quats, scales, opac, _ = random_scene(n, seed=seed, device=device)
    return [means, quats, scales, opac]


def test_unlabelled_interleaved_in_depth(device):
    n = 300
    scene = _scene(n, 5, device)
    g = torch.Generator().manual_seed(5)
    labels = torch.randint(0, 6, (n,), generator=g, dtype=torch.int32)
    labels[::3] = -1  # every third Gaussian unlabelled, spread through depth
    conf = torch.rand(n, generator=g)
    sem, p, _ = _compare(device, scene, labels.to(device), conf.to(device), 64, 48)
    assert (p.cpu()[labels < 0] == 0).all()
    assert sem.meta["overflow_pixels"] == 0


def test_unlabelled_gaussians_do_not_occlude(device):
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 4.0]], device=device)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 2, device=device)
    scales = torch.full((2, 3), 0.5, device=device)
    opac = torch.full((2,), 0.95, device=device)
    labels = torch.tensor([-1, 7], dtype=torch.int32, device=device)
    conf = torch.tensor([1.0, 0.8], device=device)
    vm, K = cameras(24, 24, device=device)
    sem = render_semantics(means, quats, scales, opac, labels, conf, vm, K, 24, 24)
    assert int(sem.labels[0, 12, 12]) == 7
    assert abs(float(sem.weights[0, 12, 12]) - 0.8 * 0.95 * 0.99) < 0.05


def test_confidence_zero_and_one(device):
    n = 200
    scene = _scene(n, 9, device)
    g = torch.Generator().manual_seed(9)
    labels = torch.randint(0, 4, (n,), generator=g, dtype=torch.int32)
    conf = (torch.rand(n, generator=g) > 0.5).float()
    _, p, _ = _compare(device, scene, labels.to(device), conf.to(device), 48, 40)
    assert (p.cpu()[conf == 0] == 0).all()


def test_one_label_everywhere(device):
    n = 150
    scene = _scene(n, 13, device)
    labels = torch.full((n,), 42, dtype=torch.int32, device=device)
    conf = torch.rand(n, generator=torch.Generator().manual_seed(1)).to(device)
    sem, _, _ = _compare(device, scene, labels, conf, 40, 30)
    assert set(sem.labels.unique().tolist()) <= {-1, 42}


def test_pixel_mask_restricts_contribution(device):
    n = 200
    scene = _scene(n, 21, device)
    g = torch.Generator().manual_seed(21)
    labels = torch.randint(0, 5, (n,), generator=g, dtype=torch.int32).to(device)
    conf = torch.rand(n, generator=g).to(device)
    mask = torch.zeros(30, 40, dtype=torch.bool)
    mask[5:20, 10:30] = True
    _, p_masked, _ = _compare(device, scene, labels, conf, 40, 30, pixel_mask=mask.to(device))
    _, p_all, _ = _compare(device, scene, labels, conf, 40, 30)
    assert not torch.allclose(p_masked, p_all)


def test_more_labels_than_buffer(device):
    # 12 Gaussians with distinct labels stacked on the optical axis, front ones strongest
    n = 12
    means = torch.zeros(n, 3)
    means[:, 2] = torch.linspace(2.0, 5.0, n)
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1)
    scales = torch.full((n, 3), 0.6)
    opac = torch.full((n,), 0.3)
    labels = torch.arange(100, 100 + n, dtype=torch.int32)
    conf = torch.ones(n)
    scene = [t.to(device) for t in (means, quats, scales, opac)]
    vm, K = cameras(16, 16, device=device)
    small = render_semantics(
        *scene, labels.to(device), conf.to(device), vm, K, 16, 16, buffer_size=4, return_buffer=True
    )
    assert small.meta["overflow_pixels"] > 0 and small.meta["overflow_votes"] > 0
    assert small.buffer_labels.shape == (1, 16, 16, 4)
    ref_lab, _, _, _ = semantic_reference(*scene, labels, conf, vm[0], K[0], 16, 16)
    # the strongest votes survive eviction, so the winner is still right
    assert torch.equal(small.labels[0].cpu().long(), ref_lab)
    big = render_semantics(*scene, labels.to(device), conf.to(device), vm, K, 16, 16, buffer_size=16)
    assert big.meta["overflow_pixels"] == 0
    assert torch.equal(big.labels[0].cpu().long(), ref_lab)
    assert big.buffer_labels is None and big.buffer_weights is None  # not asked for: not written


def _emulate_buffer(votes, size):
    """The documented overflow policy on one pixel's (label, weight) votes in depth order: consecutive votes
    of one label are summed into a run; a run adds to its label's entry; a new label's run fills a free
    entry, or at a full buffer replaces the weakest entry (the first of the lowest weight) if it outweighs
    it, else is dropped. -> ({label: weight}, runs that met a full buffer)."""
    runs = []
    for lab, w in votes:
        if runs and runs[-1][0] == lab:
            runs[-1][1] += w
        else:
            runs.append([lab, w])
    labs, ws, dropped = [], [], 0
    for lab, w in runs:
        if lab in labs:
            ws[labs.index(lab)] += w
        elif len(labs) < size:
            labs.append(lab)
            ws.append(w)
        else:
            dropped += 1
            k = min(range(size), key=lambda i: (ws[i], i))
            if w > ws[k]:
                labs[k], ws[k] = lab, w
    return dict(zip(labs, ws)), dropped


@pytest.mark.parametrize("buffer_size", [1, 3, 4])
def test_overflow_keeps_the_documented_entries(device, buffer_size):
    """Many Gaussians from a small label alphabet stacked in depth, with random opacities and confidences:
    every pixel's buffer holds exactly what the policy gives (runs, matches into the weakest entry,
    evictions and dropped runs all occur), and the runs that met a full buffer and their pixels are
    counted."""
    from reference_raster import project

    g = torch.Generator().manual_seed(buffer_size)
    n, size = 60, 6
    means = torch.zeros(n, 3)
    means[:, 2] = torch.linspace(2.0, 8.0, n)
    means[:, :2] = (torch.rand(n, 2, generator=g) - 0.5) * 0.2
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1)
    scales = torch.full((n, 3), 0.5)
    opac = torch.rand(n, generator=g) * 0.3 + 0.02
    conf = torch.rand(n, generator=g)
    labels = torch.randint(0, 7, (n,), generator=g, dtype=torch.int32)
    vm, K = cameras(size, size)
    scene = [t.to(device) for t in (means, quats, scales, opac, labels, conf)]
    out = render_semantics(
        *scene, vm.to(device), K.to(device), size, size, buffer_size=buffer_size, return_buffer=True
    )
    f = torch.float64
    m2d, con, depth, _ = project(
        means.to(f),
        quats.to(f),
        scales.to(f),
        opac.to(f),
        vm[0].to(f),
        K[0].to(f),
        size,
        size,
        0.01,
        1e10,
        0.3,
    )
    order = torch.argsort(depth).tolist()
    total_dropped = merged = overflowed = 0
    for y in range(size):
        for x in range(size):
            T, votes = 1.0, []
            for i in order:
                dx, dy = float(m2d[i, 0]) - (x + 0.5), float(m2d[i, 1]) - (y + 0.5)
                sigma = (
                    0.5 * (float(con[i, 0]) * dx * dx + float(con[i, 2]) * dy * dy)
                    + float(con[i, 1]) * dx * dy
                )
                a = min(0.99, float(opac[i]) * math.exp(-sigma))
                if sigma < 0 or a < 1 / 255:
                    continue
                ca = float(conf[i]) * a
                if T * (1 - ca) <= 1e-4:
                    break
                votes.append((int(labels[i]), ca * T))
                T *= 1 - ca
            merged += sum(a[0] == b[0] for a, b in zip(votes, votes[1:]))
            expect, dropped = _emulate_buffer(votes, buffer_size)
            total_dropped += dropped
            overflowed += dropped > 0
            got = {
                int(lab): float(w)
                for lab, w in zip(out.buffer_labels[0, y, x].tolist(), out.buffer_weights[0, y, x].tolist())
                if lab >= 0
            }
            assert got.keys() == expect.keys(), (x, y)
            for lab, w in expect.items():
                assert got[lab] == pytest.approx(w, abs=1e-5)
    assert isinstance(out.meta["overflow_votes"], torch.Tensor)  # left on the device: no host sync
    assert int(out.meta["overflow_votes"]) == total_dropped > 0
    assert int(out.meta["overflow_pixels"]) == overflowed > 0
    assert merged > 0  # votes were summed into runs


@pytest.mark.parametrize("value,message", [(1.5, "lie in"), (-0.1, "lie in"), (math.nan, "NaN")])
def test_confidence_values_are_checked(device, value, message):
    means, quats, scales, opac, _ = random_scene(4, device=device)
    vm, K = cameras(8, 8, device=device)
    conf = torch.full((4,), 0.5, device=device)
    conf[2] = value
    labels = torch.zeros(4, dtype=torch.int32, device=device)
    with pytest.raises(ValueError, match=f"confidences.*{message}"):
        render_semantics(means, quats, scales, opac, labels, conf, vm, K, 8, 8)
    with pytest.raises(ValueError, match=f"confidences.*{message}"):
        rendering_contribution(means, quats, scales, opac, labels, conf, vm[0], K[0], 8, 8)


def test_bad_semantic_inputs():
    means, quats, scales, opac, _ = random_scene(4)
    vm, K = cameras(8, 8)
    with pytest.raises(ValueError, match="labels"):
        render_semantics(means, quats, scales, opac, torch.zeros(4), torch.ones(4), vm, K, 8, 8)
    with pytest.raises(ValueError, match="confidences"):
        render_semantics(
            means, quats, scales, opac, torch.zeros(4, dtype=torch.int32), torch.full((4,), 1.5), vm, K, 8, 8
        )
    for wide in (2**31, -(2**31) - 1):  # would wrap around to another label as int32
        with pytest.raises(ValueError, match="labels must fit in int32"):
            render_semantics(
                means, quats, scales, opac, torch.tensor([0, 1, wide, 2]), torch.ones(4), vm, K, 8, 8
            )
    with pytest.raises(ValueError, match="pixel_mask"):
        rendering_contribution(
            means,
            quats,
            scales,
            opac,
            torch.zeros(4, dtype=torch.int32),
            torch.ones(4),
            vm[0],
            K[0],
            8,
            8,
            pixel_mask=torch.ones(4, 4, dtype=torch.bool),
        )


def test_contribution_can_return_the_label_map(device):
    n = 120
    means, quats, scales, opac = _scene(n, 31, device)
    g = torch.Generator().manual_seed(31)
    labels = torch.randint(-1, 5, (n,), generator=g, dtype=torch.int32).to(device)
    conf = torch.rand(n, generator=g).to(device)
    vm, K = cameras(40, 30, device=device)
    p, sem = rendering_contribution(
        means, quats, scales, opac, labels, conf, vm[0], K[0], 40, 30, return_semantics=True
    )
    alone = render_semantics(means, quats, scales, opac, labels, conf, vm, K, 40, 30)
    assert torch.equal(sem.labels, alone.labels) and torch.equal(sem.weights, alone.weights)
    # the same sums, in another order on CUDA (atomic adds)
    torch.testing.assert_close(
        p, rendering_contribution(means, quats, scales, opac, labels, conf, vm[0], K[0], 40, 30)
    )


@pytest.mark.parametrize("tile_size", [5, 32])
def test_other_tile_sizes_match_reference(device, tile_size):
    # on CUDA the 25 threads of a 5x5 tile are padded to a 32-lane warp, a 32x32 tile spans four blocks
    n = 150
    g = torch.Generator().manual_seed(17)
    labels = torch.randint(-1, 6, (n,), generator=g, dtype=torch.int32).to(device)
    conf = torch.rand(n, generator=g).to(device)
    _compare(device, _scene(n, 17, device), labels, conf, 45, 37, tile_size=tile_size)
