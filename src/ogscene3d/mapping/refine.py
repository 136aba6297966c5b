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
confidence is 0, with ``include_unlabeled`` / ``mapping.refine_unlabeled``, off by default: the paper's
unlabelled Gaussians do not exist at confidence 0) takes the label of the nearest Gaussian with
conf > tau_high within r_search and conf := 0.5.

Beyond the paper (``mapping.evidence_protect``, on by default): the mapper passes the labels that the views
show to be objects (``evidence.SegmentEvidence.protected_labels``), whose Gaussians keep their label at both
levels. Under SAM-like segments a small object's confidence is low from its birth (a low SAM score) and falls
in the views that absorb it into its support, so Algorithm 1 gave it the table's or the wall's label. The
Gaussians that the views put in another label's segment (``mapping.evidence_wrong``: ``exposed``) are not
kept, and take the label of their nearest confident Gaussian of *another* label at the individual level:
their own label is what the views contradict, and the nearest confident neighbour of a wide run-over part
is often one of its own label's Gaussians.

Schedule (``mapper.py``): every ``mapping.refine_every`` = 6 keyframes, right after the long-term update,
as Sec. IV-A.4 states ("performed every 6 keyframes"); Sec. III-B.3's "intervals determined by cumulative
camera motion" is read as that, keyframes being selected by camera motion where ``keyframe_translation`` /
``keyframe_rotation_deg`` are set. Both operate on the whole map.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .local import group_top2
from .neighbors import knn, knn_components, knn_int32


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


def _of_labels(labels: torch.Tensor, protected: torch.Tensor | None) -> torch.Tensor:
    """[N] bool: Gaussians whose label is marked in ``protected`` [L] (none when it is None; labels beyond
    L are not marked)."""
    out = torch.zeros(labels.shape[0], dtype=torch.bool, device=labels.device)
    if protected is None or protected.numel() == 0:
        return out
    lab = labels.long()
    ok = (lab >= 0) & (lab < protected.numel())
    out[ok] = protected.to(labels.device)[lab[ok]]
    return out


@dataclass
class RefineStats:
    clusters: int = 0
    low_clusters: int = 0
    relabeled_clusters: int = 0
    cluster_gaussians: int = 0
    individual_gaussians: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


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
    protected: torch.Tensor | None = None,
    exposed: torch.Tensor | None = None,
) -> RefineStats:
    """Algorithm 1 on the map's tensors; ``labels`` [N] int32 and ``conf`` [N] are modified in place.
    ``include_unlabeled``: whether unlabeled Gaussians (label -1, confidence 0) take part in the individual
    refinement. ``protected`` [L] bool per label (beyond the paper, ``mapping.evidence_protect``): the
    Gaussians of a protected label keep it at both levels, though they may still give their label to others
    (``evidence.SegmentEvidence.protected_labels`` says which labels the views show to be objects);
    ``exposed`` [N] bool: Gaussians that the protection does not cover (the views put them in another
    label's segment: ``mapping.evidence_wrong``)."""
    stats = RefineStats()
    n = means.shape[0]
    if n == 0:
        return stats
    dev = means.device
    processed = torch.zeros(n, dtype=torch.bool, device=dev)
    kept = _of_labels(labels, protected)
    if exposed is not None:
        kept &= ~exposed.to(dev)

    # ---- cluster level
    cluster = connected_clusters(means, labels, r_search, graph_k)
    num_c = int(cluster.max()) + 1 if n else 0
    stats.clusters = num_c
    if num_c:
        inc = cluster >= 0
        csize = torch.bincount(cluster[inc], minlength=num_c).float()
        cmean = torch.bincount(cluster[inc], weights=conf[inc].float(), minlength=num_c) / csize.clamp(min=1)
        low = cmean < tau_low
        stats.low_clusters = int(low.sum())
        high = torch.nonzero((conf > tau_high) & (labels >= 0)).squeeze(1)
        if stats.low_clusters and high.numel():
            q = torch.nonzero(inc & low[cluster.clamp(min=0)]).squeeze(1)
            idx, _ = knn(means[high], means[q], 1, cluster_radius, cluster[high], cluster[q], "different")
            found = idx[:, 0] >= 0
            qc = cluster[q][found]
            nl = labels[high[idx[found, 0]]]
            s_new, cnt, _, _ = group_top2(qc, nl, num_c)
            # a cluster is one label's, so a protected label's clusters are kept whole
            relabel = low & (cnt > 0)
            relabel[cluster[kept]] = False
            members = inc & relabel[cluster.clamp(min=0)]
            labels[members] = s_new[cluster[members]].to(labels.dtype)
            processed |= members
            stats.relabeled_clusters = int(relabel.sum())
            stats.cluster_gaussians = int(members.sum())

    # ---- individual level (uses the labels after the cluster level)
    high = torch.nonzero((conf > tau_high) & (labels >= 0)).squeeze(1)
    cand = ~processed & (conf < tau_low) & ~kept
    if not include_unlabeled:
        cand &= labels >= 0
    if high.numel():
        wrong = exposed.to(dev) & cand if exposed is not None else torch.zeros_like(cand)
        for sel, other in ((cand & ~wrong, False), (wrong, True)):
            q = torch.nonzero(sel).squeeze(1)
            if q.numel() == 0:
                continue
            # an exposed Gaussian's own label is what the views contradict: it takes another one
            grp = (labels[high], labels[q], "different") if other else ()
            idx, _ = knn(means[high], means[q], 1, r_search, *grp, two_pass=True)
            found = idx[:, 0] >= 0
            tgt = q[found]
            labels[tgt] = labels[high[idx[found, 0]]]
            conf[tgt] = 0.5
            stats.individual_gaussians += int(tgt.numel())
    return stats
