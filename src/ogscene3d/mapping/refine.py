"""Global 3D refinement (paper Algorithm 1): cluster-level relabeling, then individual refinement.

Clusters are the connected components of the graph linking labeled Gaussians of the *same* label that lie
within ``r_search`` of each other. To keep the graph bounded on dense maps each Gaussian links to its
``graph_k`` nearest same-label neighbours within the radius (edges are symmetric), which keeps dense
surfaces connected exactly as the full radius graph does in practice. Components are found by a lock-free
union-find over the KNN edges (one kernel pass; ``ogscene3d.kernels.components``): min-label propagation
needed a round over every edge per hop of a component's diameter, hundreds on dense surfaces.

Cluster level: a cluster whose mean confidence A_k < tau_low takes the most frequent label among, for each
of its Gaussians, the nearest Gaussian *outside the cluster* with conf > tau_high (searched within
``cluster_radius``: the paper's search is unbounded, a finite radius keeps it a hash-grid query).
Only labels change; its Gaussians are then excluded from individual refinement. A low cluster that finds
no such Gaussian keeps its label and is not recorded as processed: Algorithm 1 would add it to P with an
undefined s_new (argmax over an empty L_k), while the text records only the Gaussians "that have been
refined", which we follow, so its low-confidence members may still be refined individually.

Individual level: every remaining labelled Gaussian with conf < tau_low (unlabeled ones too, whose
confidence is 0, with ``include_unlabeled`` / ``mapping.refine.unlabeled``, off by default: the paper's
unlabelled Gaussians do not exist at confidence 0) takes the label of the nearest Gaussian with
conf > tau_high within r_search and conf := 0.5.

Beyond the paper (``mapping.evidence.enabled``, on by default): Algorithm 1 decides from the views' evidence
(``evidence.EvidenceModel``). A cluster or a Gaussian does not take a label from which the views clearly
separated its own (``separated``): under SAM-like segments a small object's confidence is low from its birth
(a low SAM score) and falls in the views that absorb it into its support, and Algorithm 1 gave it the
table's or the wall's label although a view had shown it apart. Gaussians that the views put in another
label's segment (``exposed``, disputed) are not held back, and take the label of their nearest confident
Gaussian of *another* label at the individual level: their own label is what the views contradict, and the
nearest confident neighbour of a wide run-over part is often one of its own label's Gaussians. Where no
confident Gaussian of another label lies within ``r_search``, they take the label that the disputing views
put them in (``exposed_to``: the one holding most of the segments they put the Gaussian in): the middle of
a picture that an earlier view absorbed into the wall has the wall's Gaussians only, and the picture's own,
made later around them, are not yet confident.

Schedule (``mapper.py``): every ``mapping.refine.every`` = 6 keyframes, right after the long-term update,
as Sec. IV-A.4 states ("performed every 6 keyframes"); Sec. III-B.3's "intervals determined by cumulative
camera motion" is read as that, keyframes being selected by camera motion where ``keyframe_translation`` /
``keyframe_rotation_deg`` are set. Both operate on the whole map.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from .local import group_top2
from .neighbors import knn, knn_components, knn_int32
from .timings import Counters


def connected_clusters(
    means: torch.Tensor, labels: torch.Tensor, radius: float, graph_k: int = 8
) -> torch.Tensor:
    """Cluster id per Gaussian [N] int64 (0..C-1, compact; -1 for unlabeled Gaussians)."""
    n = means.shape[0]
    dev = means.device
    out = torch.full((n,), -1, dtype=torch.int64, device=dev)
    lab = torch.nonzero(labels >= 0).squeeze(1)
    m = int(lab.numel())
    if m == 0:
        return out
    pts = means[lab]
    grp = labels[lab]
    # +1: each point finds itself; two passes: the k nearest lie far inside the radius on dense surfaces
    nbr, _ = knn_int32(pts, pts, graph_k + 1, radius, grp, grp, "same", two_pass=True)
    root = knn_components(nbr).long()  # the smallest member of each component
    # compact ids in the order of the roots (as torch.unique would number them), without a sort
    is_root = root == torch.arange(m, device=dev)
    compact = (torch.cumsum(is_root, 0) - 1)[root]
    out[lab] = compact
    return out


@dataclass
class RefineStats(Counters):
    clusters: int = 0
    low_clusters: int = 0
    relabeled_clusters: int = 0
    cluster_gaussians: int = 0
    individual_gaussians: int = 0


def global_refinement(
    means: torch.Tensor,
    labels: torch.Tensor,
    conf: torch.Tensor,
    *,
    tau_low: float = 0.3,
    tau_high: float = 0.7,
    r_search: float = 0.1,
    cluster_radius: float = 0.3,
    graph_k: int = 8,
    include_unlabeled: bool = False,
    separated: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
    exposed: torch.Tensor | None = None,
    exposed_to: torch.Tensor | None = None,
) -> RefineStats:
    """Algorithm 1 on the map's tensors; ``labels`` [N] int32 and ``conf`` [N] are modified in place.
    ``include_unlabeled``: whether unlabeled Gaussians (label -1, confidence 0) take part in the individual
    refinement. ``separated(a, b)`` (beyond the paper, ``mapping.evidence``): [M] bool for label tensors
    a, b [M], whether the views clearly separated label a from label b; no cluster or Gaussian of label a
    takes label b then (``evidence.EvidenceModel.separation_test``). ``exposed`` [N] bool: Gaussians that
    the guard does not cover (the views disputed their label), which take another label than their own.
    ``exposed_to`` [N] int: for those, the label the disputing views put them in (-1: none), taken where no
    confident Gaussian of another label lies within ``r_search``."""
    stats = RefineStats()
    n = means.shape[0]
    if n == 0:
        return stats
    dev = means.device
    free = exposed.to(dev) if exposed is not None else torch.zeros(n, dtype=torch.bool, device=dev)

    processed = _cluster_level(
        means, labels, conf, stats, tau_low, tau_high, r_search, cluster_radius, graph_k, separated
    )
    cand = ~processed & (conf < tau_low)
    if not include_unlabeled:
        cand &= labels >= 0
    stats.individual_gaussians = _individual_level(
        means, labels, conf, cand, free, tau_high, r_search, separated, exposed_to
    )
    return stats


def _cluster_level(
    means, labels, conf, stats: RefineStats, tau_low, tau_high, r_search, cluster_radius, graph_k, separated
) -> torch.Tensor:
    """Algorithm 1's cluster level (in place): a low-confidence cluster takes the label most of its members'
    nearest confident Gaussians of other clusters carry, not across a clear separation. -> [N] bool, the
    Gaussians relabelled here."""
    n = means.shape[0]
    dev = means.device
    processed = torch.zeros(n, dtype=torch.bool, device=dev)
    cluster = connected_clusters(means, labels, r_search, graph_k)
    num_c = int(cluster.max()) + 1 if n else 0
    stats.clusters = num_c
    if not num_c:
        return processed
    inc = cluster >= 0
    csize = torch.bincount(cluster[inc], minlength=num_c).float()
    cmean = torch.bincount(cluster[inc], weights=conf[inc].float(), minlength=num_c) / csize.clamp(min=1)
    low = cmean < tau_low
    stats.low_clusters = int(low.sum())
    high = torch.nonzero((conf > tau_high) & (labels >= 0)).squeeze(1)
    if not stats.low_clusters or not high.numel():
        return processed
    q = torch.nonzero(inc & low[cluster.clamp(min=0)]).squeeze(1)
    idx, _ = knn(means[high], means[q], 1, cluster_radius, cluster[high], cluster[q], "different")
    found = idx[:, 0] >= 0
    qc = cluster[q][found]
    nl = labels[high[idx[found, 0]]]
    s_new, cnt, _, _ = group_top2(qc, nl, num_c)
    relabel = low & (cnt > 0)
    if separated is not None:  # not across a clear separation (a cluster is one label's)
        own = torch.full((num_c,), -1, dtype=torch.int64, device=dev)
        own[cluster[inc]] = labels[inc].long()
        c = torch.nonzero(relabel).squeeze(1)
        relabel[c[separated(own[c], s_new[c])]] = False
    members = inc & relabel[cluster.clamp(min=0)]
    labels[members] = s_new[cluster[members]].to(labels.dtype)
    processed |= members
    stats.relabeled_clusters = int(relabel.sum())
    stats.cluster_gaussians = int(members.sum())
    return processed


def _individual_level(means, labels, conf, cand, free, tau_high, r_search, separated, exposed_to=None) -> int:
    """Algorithm 1's individual level (in place, on the labels after the cluster level): each candidate
    takes its nearest confident Gaussian's label (a disputed one, in ``free``, another label than its own,
    or, with none within ``r_search``, the label its views put it in, ``exposed_to``). -> the number
    relabelled."""
    high = torch.nonzero((conf > tau_high) & (labels >= 0)).squeeze(1)
    if not high.numel():
        return 0
    done = 0
    wrong = free & cand
    for sel, other in ((cand & ~wrong, False), (wrong, True)):
        q = torch.nonzero(sel).squeeze(1)
        if q.numel() == 0:
            continue
        # an exposed Gaussian's own label is what the views contradict: it takes another one
        grp = (labels[high], labels[q], "different") if other else ()
        idx, _ = knn(means[high], means[q], 1, r_search, *grp, two_pass=True)
        found = idx[:, 0] >= 0
        tgt, src = q[found], high[idx[found, 0]]
        if separated is not None and not other:
            ok = ~separated(labels[tgt].long(), labels[src].long())
            tgt, src = tgt[ok], src[ok]
        new = labels[src]
        if other and exposed_to is not None:
            # a patch of an object that an earlier view gave its support's label (a picture absorbed into the
            # wall) has no confident Gaussian of the object's label near its middle: the views name it. Only
            # there: taking the views' label first lost cups and a bottle on the long scans
            # (docs/consistency.md measures both)
            rest = q[~found]
            rest = rest[(exposed_to[rest] >= 0) & (exposed_to[rest] != labels[rest].long())]
            tgt, new = torch.cat([tgt, rest]), torch.cat([new, exposed_to[rest].to(labels.dtype)])
        labels[tgt] = new
        conf[tgt] = 0.5
        done += int(tgt.numel())
    return done
