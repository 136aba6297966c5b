import torch

from ogscene3d.mapping.refine import connected_clusters, global_refinement


def _patch(x0: float, n: int = 4, spacing: float = 0.05, y0: float = 0.0) -> torch.Tensor:
    u = torch.arange(n, dtype=torch.float32) * spacing
    xx, yy = torch.meshgrid(u + x0, u + y0, indexing="ij")
    return torch.stack([xx.reshape(-1), yy.reshape(-1), torch.zeros(n * n)], 1)


def test_connected_clusters(device):
    line = torch.stack([torch.arange(60) * 0.05, torch.zeros(60), torch.zeros(60)], 1)  # one long chain
    far = _patch(10.0)
    other = _patch(0.0, y0=0.05)  # touches the chain but has another label
    means = torch.cat([line, far, other]).to(device)
    labels = torch.tensor([1] * 60 + [1] * 16 + [2] * 16 + [], dtype=torch.int32, device=device)
    labels[-1] = -1
    c = connected_clusters(means, labels, radius=0.1, graph_k=4).cpu()
    assert len(set(c[:60].tolist())) == 1
    assert len(set(c[60:76].tolist())) == 1 and c[60] != c[0]
    assert len(set(c[76:91].tolist())) == 1 and c[76] not in (c[0], c[60])
    assert c[-1] == -1
    assert sorted(set(c[:91].tolist())) == [0, 1, 2]


def test_cluster_level_relabels_low_confidence_cluster(device):
    big = _patch(0.0, n=6)  # label 3, confident
    small = _patch(0.3, n=2)  # label 5, unreliable, adjacent to big along x
    means = torch.cat([big, small]).to(device)
    labels = torch.tensor([3] * 36 + [5] * 4, dtype=torch.int32, device=device)
    conf = torch.tensor([0.9] * 36 + [0.1, 0.2, 0.1, 0.2], device=device)
    stats = global_refinement(means, labels, conf, r_search=0.1, cluster_radius=0.3)
    assert labels.tolist() == [3] * 40
    # cluster level changes labels only, never confidences
    torch.testing.assert_close(conf[36:].cpu(), torch.tensor([0.1, 0.2, 0.1, 0.2]))
    assert stats.low_clusters == 1 and stats.relabeled_clusters == 1 and stats.cluster_gaussians == 4
    assert stats.individual_gaussians == 0  # the relabeled Gaussians are excluded from the individual level


def test_cluster_level_needs_a_high_confidence_neighbour(device):
    means = torch.cat([_patch(0.0), _patch(5.0)]).to(device)
    labels = torch.tensor([1] * 16 + [2] * 16, dtype=torch.int32, device=device)
    conf = torch.tensor([0.1] * 16 + [0.9] * 16, device=device)
    stats = global_refinement(means, labels, conf, cluster_radius=0.3)
    assert stats.low_clusters == 1 and stats.relabeled_clusters == 0
    assert labels.tolist() == [1] * 16 + [2] * 16


def test_individual_refinement(device):
    patch = _patch(0.0)  # label 3 cluster, mean confidence high
    means = torch.cat(
        [
            patch,
            torch.tensor([[0.075, 0.075, 0.0]]),  # index 16: label 3 but conf 0.1 (same cluster)
            torch.tensor([[0.075, 0.075, 0.01]]),  # index 17: label 4, conf 0.95, nearest to 16
            torch.tensor([[0.16, 0.0, 0.0]]),  # index 18: unlabeled (conf 0) at the patch border
            torch.tensor([[3.0, 3.0, 3.0]]),  # index 19: low confidence, nothing within r_search
        ]
    ).to(device)
    labels = torch.tensor([3] * 16 + [3, 4, -1, 6], dtype=torch.int32, device=device)
    conf = torch.tensor([0.9] * 16 + [0.1, 0.95, 0.0, 0.2], device=device)
    # index 19 alone forms a low cluster with no high-confidence Gaussian within cluster_radius
    before = labels.clone(), conf.clone()
    stats = global_refinement(
        means.clone(), before[0].clone(), before[1].clone(), r_search=0.1, cluster_radius=0.3
    )
    assert stats.individual_gaussians == 1  # unlabeled Gaussians are left alone by default
    stats = global_refinement(means, labels, conf, r_search=0.1, cluster_radius=0.3, include_unlabeled=True)
    assert labels[16:].tolist() == [4, 4, 3, 6]
    torch.testing.assert_close(conf[16:].cpu(), torch.tensor([0.5, 0.95, 0.5, 0.2]))
    assert stats.individual_gaussians == 2


def test_empty_map(device):
    e = torch.zeros(0, 3, device=device)
    stats = global_refinement(
        e, torch.zeros(0, dtype=torch.int32, device=device), torch.zeros(0, device=device)
    )
    assert stats.clusters == 0


def test_no_relabel_across_a_clear_separation(device):
    """Beyond the paper (mapping.evidence.enabled): a label the views separated from its neighbour's keeps its
    low-confidence Gaussians at both levels, and still gives its label to others; a disputed (exposed)
    Gaussian is not held back. The same map without the guard loses the small label."""
    big = _patch(0.0, n=6)  # label 3, confident
    small = _patch(0.3, n=2)  # label 5: a small object with a low SAM score, next to big
    stray = _patch(0.0, n=1, y0=0.3)  # label 7: one low Gaussian beside big
    means = torch.cat([big, small, stray]).to(device)
    base = torch.tensor([3] * 36 + [5] * 4 + [7], dtype=torch.int32, device=device)
    conf0 = torch.tensor([0.9] * 36 + [0.1, 0.2, 0.1, 0.2] + [0.1], device=device)

    def separated(a, b):
        return ((a == 5) & (b == 3)) | ((a == 3) & (b == 5))

    labels, conf = base.clone(), conf0.clone()
    stats = global_refinement(means, labels, conf, r_search=0.1, cluster_radius=0.3, separated=separated)
    assert labels[36:40].tolist() == [5] * 4 and torch.equal(conf[36:40], conf0[36:40])
    assert labels[40].item() == 3  # not separated: relabelled as before
    assert stats.individual_gaussians + stats.cluster_gaussians == 1
    exposed = torch.zeros(41, dtype=torch.bool, device=device)
    exposed[36] = True
    labels, conf = base.clone(), conf0.clone()
    global_refinement(
        means, labels, conf, r_search=0.1, cluster_radius=0.3, separated=separated, exposed=exposed
    )
    assert labels[36].item() == 3 and labels[37:40].tolist() == [5] * 3
    labels, conf = base.clone(), conf0.clone()
    global_refinement(means, labels, conf, r_search=0.1, cluster_radius=0.3)
    assert labels.tolist() == [3] * 41


def test_an_exposed_gaussian_with_no_confident_neighbour_takes_the_label_its_views_name(device):
    """A disputed (exposed) Gaussian takes its nearest confident Gaussian's label of another label; where none
    lies within r_search (the middle of a picture that an earlier view made with the wall's label, the
    picture's own Gaussians not yet confident) it takes ``exposed_to``, the label its views put it in, and
    without one keeps its own."""
    wall = _patch(0.0, n=6)  # label 3, confident; 30 is its Gaussian at x = 0.25, y = 0
    shelf = _patch(0.3, n=2)  # label 9, confident, 5 cm from the wall's edge
    picture = _patch(0.8, n=3)  # label 5, made later, not yet confident; 44 is its middle
    means = torch.cat([wall, shelf, picture]).to(device)
    labels = torch.tensor([3] * 36 + [9] * 4 + [5] * 9, dtype=torch.int32, device=device)
    conf = torch.tensor([0.9] * 40 + [0.5] * 9, device=device)
    labels[44], conf[44] = 3, 0.0  # made by a view that absorbed the picture into the wall
    conf[30] = 0.0
    exposed = torch.zeros(49, dtype=torch.bool, device=device)
    exposed[[30, 44]] = True
    to = torch.full((49,), -1, dtype=torch.int64, device=device)
    to[30], to[44] = 5, 5

    def refine(exposed_to):
        la, ca = labels.clone(), conf.clone()
        global_refinement(
            means, la, ca, r_search=0.1, cluster_radius=0.3, exposed=exposed, exposed_to=exposed_to
        )
        others = torch.ones(49, dtype=torch.bool, device=device)
        others[[30, 44]] = False
        assert torch.equal(la[others], labels[others])
        return la[30].item(), la[44].item(), ca[44].item()

    assert refine(None) == (9, 3, 0.0)  # the shelf's, its nearest confident other label; the middle keeps 3
    assert refine(to) == (9, 5, 0.5)  # the confident neighbour first; the middle takes its views' label
    to[44] = 3  # its own label: nothing to take
    assert refine(to) == (9, 3, 0.0)
