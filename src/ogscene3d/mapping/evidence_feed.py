"""Feeding the views' evidence (``evidence.py``) from the mapper's stages: the part each new Gaussian
joins, each view's judgement (a keyframe once its Gaussians are in the map, the memory views again before
the long-term step), and what the long-term step and the global refinement take from it."""

from __future__ import annotations

import torch

from ..config import Config
from ..gaussians import GaussianMap
from .evidence import MIN_PART, EvidenceModel
from .local import group_top2, rescale_sam_scores
from .refine import connected_clusters
from .timings import Timings


class EvidenceFeed:
    """The run's :class:`EvidenceModel` and the mapper's calls into it. ``enabled``: whether the evidence
    is collected (where the global refinement runs and ``mapping.evidence.enabled`` is on); off, every call
    here does nothing."""

    def __init__(self, config: Config, device: torch.device, timings: Timings, enabled: bool) -> None:
        cfg = config.mapping
        self.enabled = enabled
        self.device = device
        self.timings = timings
        self.segmentation = config.segmentation
        self.margin = cfg.init.depth_margin
        self.r_search, self.graph_k = cfg.refine.r_search, cfg.refine.graph_k
        self.model = EvidenceModel(
            device, cfg.evidence, radius=cfg.refine.r_search, min_part=cfg.merge.min_part
        )
        self._labels_before_alg1: torch.Tensor | None = None  # set by before_refine, read by after_refine

    def new_parts(self, gm: GaussianMap, probes, sel: torch.Tensor, res) -> torch.Tensor:
        """Per probe: the evidence part its new Gaussian joins. A segment matched with a label (case ii)
        continues the part that most of its probes' nearest Gaussians of that label belong to; the new
        Gaussians of any other segment (novel, ambiguous, or matched without such a Gaussian), and those
        outside every segment, start a part per spatial component (linked within ``r_search``, as Algorithm
        1's clusters): a segment over two objects apart in space makes two parts, which the views that follow
        may hold together or keep apart."""
        S = int(res.seg_labels.numel())
        self.model.ensure_cells(gm)
        seg = probes.seg[sel]
        near = res.nearest
        hit = near >= 0
        same = torch.zeros_like(hit)
        same[hit] = gm.labels[near[hit]].long() == res.seg_labels[seg[hit]].long()
        cell = gm.aux("ev_cell", -1.0)[near[same]].long()
        top, cnt, _, _ = group_top2(seg[same], self.model.cell_part[cell.clamp(min=0)], S)
        seg_part = torch.where(cnt > 0, top, torch.full_like(top, -1))
        parts = torch.full((len(probes),), -1, dtype=torch.long, device=self.device)
        parts[sel] = seg_part[seg]
        fresh = torch.nonzero(probes.new & (parts < 0)).squeeze(1)
        if fresh.numel():
            group = torch.full((len(probes),), S, dtype=torch.int32, device=self.device)  # S: no segment
            group[sel] = seg.to(torch.int32)
            parts[fresh] = self._new_components(probes.means[fresh], group[fresh], S)
        return parts

    def _new_components(self, means: torch.Tensor, group: torch.Tensor, S: int) -> torch.Tensor:
        """New parts, one per spatial component of each segment (``group``, S: outside every segment, whose
        parts are flagged unsegmented); returns each point's part."""
        comp = self._components(means, group, S)
        ids = self.model.new_parts(int(comp.max()) + 1)
        self.model.part_unsegmented[ids[comp[group == S]]] = True
        return ids[comp]

    def _components(self, means: torch.Tensor, group: torch.Tensor, S: int) -> torch.Tensor:
        """Per point: its spatial component within its segment (``group``, S: none), numbered from 0. A few
        Gaussians apart from the rest of their segment (a hole the map did not explain) join the segment's
        largest component: a part too small to be judged says nothing."""
        comp = connected_clusters(means, group, self.r_search, self.graph_k)
        size = torch.bincount(comp)
        seg_of = torch.zeros_like(size).scatter_(0, comp, group.long())
        best = torch.zeros(S + 1, dtype=torch.long, device=self.device)
        best.scatter_reduce_(0, seg_of, size, reduce="amax")
        ids = torch.arange(size.numel(), device=self.device)
        is_best = size >= best[seg_of]
        main = torch.full((S + 1,), size.numel(), dtype=torch.long, device=self.device)
        main.scatter_reduce_(0, seg_of[is_best], ids[is_best], reduce="amin")
        comp = torch.where(size[comp] >= MIN_PART, comp, main[seg_of[comp]])
        return torch.unique(comp, return_inverse=True)[1]

    def assign(self, gm: GaussianMap, rows: slice | range, parts: torch.Tensor | None) -> None:
        """The Gaussians just appended (``rows`` of ``gm``) join their ``parts`` (None: the keyframe had no
        segments; they lie outside every segment, so they start unsegmented parts, one per spatial
        component, as such Gaussians of a segmented keyframe do)."""
        if not self.enabled:
            return
        with self.timings.section("evidence"):
            idx = torch.arange(rows.start, rows.stop, device=self.device)
            if idx.numel() == 0:
                return
            if parts is None:
                none = torch.zeros(idx.numel(), dtype=torch.int32, device=self.device)
                parts = self._new_components(gm.means[idx], none, 0)
            self.model.assign(gm, idx, parts)

    def judge(self, gm: GaussianMap, view: int, segments, scores: dict[int, float], source, revisit=False):
        """One view's evidence: ``source`` its Frame or MemoryEntry; its segments weighted by their rescaled
        SAM score (Eq. 5's c_sam)."""
        if not self.enabled or segments is None:
            return
        ids = list(scores)
        weights = {}
        if ids:
            w = rescale_sam_scores(
                torch.tensor([scores[i] for i in ids]),
                tuple(self.segmentation.sam_score_range),
                tuple(self.segmentation.conf_range),
            )
            weights = dict(zip(ids, w.tolist()))
        with self.timings.section("evidence"):
            seen = self.model.observe(
                gm, segments, source.pose, source.K, source.depth, weights=weights,
                margin=self.margin, view=view, revisit=revisit,
            )  # fmt: skip
        if not revisit:  # what the keyframe sees, for benchmarks/semantic_growth.py
            self.timings.note("visible_gaussians", seen)

    def before_longterm(self, gm: GaussianMap, views: list) -> None:
        """Before Eq. 16 (whose P_conf renders the lowered ones): the disputed Gaussians lowered, then the
        memory views judged again against the map as it is now (what was made since they were keyframes has
        had no word from them)."""
        if not self.enabled:
            return
        with self.timings.section("evidence"):
            self.timings.add("evidence_lowered", self.model.lower_disputed(gm))
        for entry in views:
            self.judge(gm, entry.keyframe, entry.segments, entry.scores, entry, revisit=True)

    def before_refine(
        self, gm: GaussianMap
    ) -> tuple[torch.Tensor | None, torch.Tensor | None, torch.Tensor | None]:
        """The merges and splits the views decide, then what guards Algorithm 1: (separated, exposed,
        exposed_to), None where the evidence is not collected."""
        if not self.enabled:
            return None, None, None
        with self.timings.section("evidence"):
            for k, v in self.model.decide(gm).items():
                self.timings.add(f"evidence_{k}", v)
            self._labels_before_alg1 = gm.labels.clone()  # what Algorithm 1 starts from
            exposed = self.model.disputed(gm)
            return self.model.separation_test(gm), exposed, self.model.disputed_labels(gm, exposed)

    def after_refine(self, gm: GaussianMap) -> None:
        """The Gaussians whose label Algorithm 1 changed (since ``before_refine``) are judged afresh under
        their new label."""
        before, self._labels_before_alg1 = self._labels_before_alg1, None
        if not self.enabled or before is None:
            return
        with self.timings.section("evidence"):
            self.model.restart_votes(gm, gm.labels != before)
