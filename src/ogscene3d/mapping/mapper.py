"""The incremental semantic mapper: runs the paper's per-keyframe loop on a stream of frames.

``process`` reads as the stages of a keyframe, each a method and one timed section of ``timings``:

1. ``_admit``: the frame's checks, tracking (``tracking.poses: odometry``) and pose-jump test
   (``pose_jump.py``); where the frame starts to count as read, the rule a resume depends on;
2. ``_begin_keyframe``: its segments (precomputed, else the segmenter: ``segments.py``);
3. ``_render_check``: the map rendered at its pose finds the pixels it does not explain (``init.py``);
4. ``_init``: probes, grid-subsampled back-projected pixels per segment (``init.make_probes``);
5. ``_local``: local 3D optimisation: KNN association, r(m)/p(m), the three cases (``local.py``), duplicate
   merging beyond the paper (``merge.py``), Eq. 5, unlabelled Gaussians under a labelled segment filled;
6. ``_add``: the unexplained probes become Gaussians (label, rescaled SAM confidence; 0 where unlabelled);
7. ``_observe_evidence``: the view's co-segmentation evidence (``evidence_feed.py``, ``evidence.py``);
8. ``_optimize``: geometry/appearance over the keyframe + memory frames, then pruning (``optimize.py``);
9. ``_memory``: memory buffer update (frustum + overlap criteria, ``longterm.py``);
10. ``_scheduled_passes``: every ``longterm_every`` keyframes the long-term Eq. 16 update, then every
    ``refine_every`` the global refinement (Alg. 1, ``refine.py``), in the same keyframe;
11. ``_graph_update``: the scene graph when ``config.graph.enabled`` (``graph_feed.py``; failures there
    never stop mapping), then ``_checkpoint`` (``mapping.checkpoint_every``, ``checkpoint.py``).

Ablations (``mapping.ablation``): "naive" (majority label of the KNN matches or a new label, no ambiguity
test, all confidences 1, no refinement, no long-term), "local", "local+global", "full".
Per-module wall time and counts are kept in ``timings`` (``timings.py``, written to ``timings.json``).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..config import Config, check_config, choices
from ..device import resolve_device
from ..errors import ConfigError, DataError
from ..frame import Frame, warn_implausible_depth
from ..gaussians import GaussianMap
from ..runs import RunFolder
from ..segmentation.base import Segmenter
from ..tracking import Tracker
from .evidence_feed import EvidenceFeed
from .graph_feed import GraphFeed
from .init import make_probes, render_coverage
from .keyframes import KeyframeSelector
from .local import associate_probes, fill_from_probes, update_confidences
from .longterm import MemoryBuffer, MemoryEntry, inner_pixels, longterm_view_update
from .merge import merge_duplicate_segments
from .optimize import optimize_map, training_views
from .persistence import MapperFiles
from .pose_jump import PoseJumpCheck
from .refine import global_refinement
from .segments import KeyframeSegments
from .timings import Timings

log = logging.getLogger(__name__)

ABLATIONS = choices("mapping.ablation")


def _ran_at(keyframe_count: int, every: int) -> bool:
    """Whether a step scheduled every ``every`` keyframes (0 = never) runs at keyframe ``keyframe_count``."""
    return every > 0 and keyframe_count % every == 0


@dataclass
class _Keyframe:
    """What the stages of one keyframe hand on to each other."""

    index: int
    frame: Frame
    segments: np.ndarray | None
    scores: dict[int, float]
    names: dict[int, str]
    rendered: tuple | None = None  # the map rendered at the keyframe's pose: alpha, depth (None: empty map)
    probes: Any = None
    labels: torch.Tensor | None = None  # per probe: scene label (-1: none) and confidence
    conf: torch.Tensor | None = None
    seg_to_label: tuple[np.ndarray, np.ndarray] | None = None  # segment ids -> their scene labels
    parts: torch.Tensor | None = None  # per probe: the evidence part its new Gaussian joins (evidence.py)


class Mapper(MapperFiles):
    """Incremental semantic Gaussian mapper: ``process(frame)`` per frame, ``finalize()``, ``save(dir)``.

    Args:
        config: the run's settings (``mapping`` above all; ``data``, ``segmentation``, ``graph`` and
            ``tracking`` for what they own); checked here too.
        device: ``cpu``, ``cuda``, ``cuda:N`` or a torch device; None: ``config.device``, else CUDA when
            available.
        segmenter: what segments the frames that carry no precomputed segments (None: built from
            ``config.segmentation`` on first need, or none under ``backend: none``).

    Attributes:
        map: the semantic Gaussians (:class:`~ogscene3d.gaussians.GaussianMap`).
        timings: per-module wall time and counters (written to ``timings.json``).
        keyframe_count: keyframes mapped so far; ``frames_seen``: frames mapped (keyframes or not).
        source: what the frames come from, kept in checkpoints (set by the caller).

    Raises:
        ConfigError: a setting out of its rules.
    """

    def __init__(
        self, config: Config, device: str | torch.device | None = None, segmenter: Segmenter | None = None
    ) -> None:
        check_config(config)  # the numeric ranges, also of a Config() built and changed in Python
        self.config = config
        self.cfg = cfg = config.mapping
        self.device = resolve_device(device if device is not None else config.device)
        self._tracker = None
        self.map = GaussianMap(self.device)
        self.keyframes = KeyframeSelector(
            cfg.keyframe_every, cfg.keyframe_translation, cfg.keyframe_rotation_deg
        )
        lt = cfg.longterm
        self.memory = MemoryBuffer(lt.tau_long, cfg.refine.r_search, lt.memory_max, lt.memory_point_step)
        self.pose_check = PoseJumpCheck(
            cfg.max_pose_step, cfg.max_pose_step_deg, cfg.on_pose_jump, stride=config.data.stride
        )
        self.recent: deque[MemoryEntry] = deque(maxlen=max(1, cfg.optimize.memory_frames))
        self.timings = Timings(self.device)
        self.segments = KeyframeSegments(config, segmenter, self.timings, self.device)
        self.frames_seen = 0
        # the dataset position after the latest frame given to process (mapped, untracked or not a
        # keyframe): where a resumed run goes on, also when frames were skipped
        self.next_index = 0
        self.keyframe_count = 0
        self.rng = np.random.default_rng(config.seed)
        # the views' co-segmentation evidence (evidence.py), collected where the refinement runs
        self.evidence = EvidenceFeed(
            config, self.device, self.timings, self.use_refine and cfg.evidence.enabled
        )
        self.graph_feed = GraphFeed(config, self.device, self.timings)
        self._checked_depth_range = False
        self._checkpoint_dir: Path | None = None
        # under odometry, the tracked pose of every frame given to process (None: untracked), for traj.txt
        self.trajectory: list[np.ndarray | None] = []
        # whether finalize ran after the latest keyframe (a resumed finished run has nothing left to do)
        self.finalized = False
        # what the frames come from (set by the caller, e.g. {"path", "frames", "first"}), kept in
        # checkpoints so that a resume can tell another sequence from the same one
        self.source: dict = {}

    # ------------------------------------------------------------------ switches
    @property
    def naive(self) -> bool:
        return self.cfg.ablation == "naive"

    @property
    def use_refine(self) -> bool:
        return self.cfg.ablation in ("local+global", "full")

    @property
    def use_longterm(self) -> bool:
        return self.cfg.ablation == "full"

    @property
    def graph(self):
        """The scene graph (``ogscene3d.graph.SceneGraph``) when ``config.graph.enabled``, else None (also
        after an error disabled it for the run)."""
        return self.graph_feed.active

    @property
    def segmenter(self):
        """The segmenter of the frames that carry no segments (the one given, or built on first need)."""
        return self.segments.segmenter

    def set_checkpoint_dir(self, out_dir: str | Path | None) -> None:
        """Where ``checkpoint_every`` writes ``map.npz`` during mapping."""
        self._checkpoint_dir = Path(out_dir) if out_dir is not None else None

    # ------------------------------------------------------------------ per frame
    def _track(self, frame: Frame) -> bool:
        """With ``tracking.poses: odometry``, replace the frame's pose by the tracked one (False: skip it)."""
        if self.config.tracking.poses == "gt":
            return True
        if self.config.tracking.poses != "odometry":
            raise ConfigError(
                f"tracking.poses must be 'gt' or 'odometry', got {self.config.tracking.poses!r}"
            )
        with self.timings.section("tracking"):
            pose = self._get_tracker().step(frame)
        if pose is None:
            self.timings.add("frames_untracked")
            return False
        frame.pose = pose
        return True

    def _get_tracker(self):
        if self._tracker is None:
            # device None: Open3D's CUDA when it has it
            self._tracker = Tracker(self.config.tracking, device=None, frame_step=self.config.data.stride)
        return self._tracker

    def process(self, frame: Frame) -> bool:
        """Map one frame (its pose checked, tracked under odometry; a keyframe runs every stage).

        Args:
            frame: the RGB-D frame, depth in metres, with its pose unless ``tracking.poses`` is odometry.

        Returns:
            True when it was a keyframe (the others are only counted).

        Raises:
            DataError: depth with NaN or inf, a frame without a pose, or bad segments.
            PoseJumpError: a pose jump under ``mapping.on_pose_jump: error``.
        """
        if not self._admit(frame) or not self.keyframes(frame.pose):
            return False
        k = self._begin_keyframe(frame)
        self._render_check(k)
        self._init(k)
        self._local(k)
        self._add(k)
        self._observe_evidence(k)
        self._optimize(k)
        self._memory(k)
        self._scheduled_passes()
        self._graph_update(k)
        self._count_map()
        self._checkpoint()
        self.timings.end_keyframe()
        return True

    # ------------------------------------------------------------------ stages of a frame
    def _admit(self, frame: Frame) -> bool:
        """Check, track and pose-check ``frame``, then count it as read. False: it is left out (untracked,
        or a pose jump under ``on_pose_jump: skip``).

        The resume rule: whatever can refuse a frame with an error runs before ``next_index`` moves past
        it (a resume after that error retries the frame); from the line that sets ``next_index`` on, the
        frame counts as read, and a checkpoint's resume goes on after it. A segmenter's bad output is
        found later, at a keyframe, so a resume goes on after that frame."""
        if not np.all(np.isfinite(frame.depth)):
            raise DataError(f"frame {frame.index} ({frame.name or 'unnamed'}): depth contains NaN or inf")
        odometry = self.config.tracking.poses == "odometry"
        if frame.pose is None and not odometry:
            raise DataError(
                f"frame {frame.index} ({frame.name or 'unnamed'}): no camera pose; use a dataset with "
                "poses or track them (--poses odometry, config tracking.poses: odometry)"
            )
        tracked = self._track(frame)
        jumped = tracked and self.pose_check.leave_out(
            frame.index, frame.pose, frame.name or "unnamed", self.timings
        )
        # ---- from here on the frame counts as read
        self.next_index = frame.index + 1
        if odometry:
            self.trajectory.append(np.array(frame.pose, dtype=np.float64) if tracked else None)
        if not tracked or jumped:
            return False
        self.graph_feed.camera_up.add(frame.pose)
        if not self._checked_depth_range:
            self._checked_depth_range = warn_implausible_depth(frame)
        self.frames_seen += 1
        self.timings.add("frames")
        return True

    def _begin_keyframe(self, frame: Frame) -> _Keyframe:
        self.timings.begin_keyframe(frame.index)
        segments, scores, names = self.segments(frame)
        k = _Keyframe(self.keyframe_count, frame, segments, scores, names)
        self.keyframe_count += 1
        self.finalized = False
        self.timings.add("keyframes")
        if not np.any(frame.depth > 0):
            # a dead sensor or a wrong depth scale: nothing of this view can enter the map
            log.warning(
                "frame %d (%s): keyframe without a valid depth pixel (depth 0 everywhere): nothing of it is "
                "mapped; check data.depth_scale and the depth images",
                frame.index,
                frame.name or "unnamed",
            )
            self.timings.add("keyframes_no_depth")
        return k

    def _render_check(self, k: _Keyframe) -> None:
        """The map rendered at the keyframe's pose (alpha + expected depth): the pixels it explains."""
        with self.timings.section("render_check"):
            k.rendered = render_coverage(self.map, k.frame)

    def _init(self, k: _Keyframe) -> None:
        """Probes: grid-subsampled back-projected pixels per segment, those the map explains marked."""
        cfg = self.cfg
        with self.timings.section("init"):
            seg, data = self.config.segmentation, self.config.data
            k.probes = make_probes(
                k.frame,
                k.segments,
                k.scores,
                self.device,
                cfg.init,
                score_range=tuple(seg.sam_score_range),
                conf_range=tuple(seg.conf_range),
                rendered=k.rendered,
                depth_range=(data.min_depth, data.max_depth),
                map_means=self.map.means,
            )

    def _local(self, k: _Keyframe) -> None:
        """Local 3D association (KNN, r(m)/p(m), the three cases), duplicate merging, Eq. 5, filling: the
        scene label and confidence of every probe."""
        cfg, probes = self.cfg, k.probes
        with self.timings.section("local"):
            k.labels = torch.full((len(probes),), -1, dtype=torch.int32, device=self.device)
            k.conf = torch.zeros(len(probes), dtype=torch.float32, device=self.device)
            in_seg = probes.seg >= 0
            if not (probes.seg_ids.numel() and bool(in_seg.any())):
                return
            sel = torch.nonzero(in_seg).squeeze(1)
            res = associate_probes(self.map, probes, sel, cfg.association, self.naive)
            merging = cfg.merge.enabled and not self.naive and k.segments is not None
            if merging and bool((self.map.labels >= 0).any()):  # labels in the map to merge
                merge_duplicate_segments(
                    self.map, k.frame, k.segments, k.scores, probes, res, cfg, self.timings
                )
            if not self.naive:
                inner = inner_pixels(k.segments, probes.pix[sel]) if cfg.association.eq5_skip_edges else None
                update_confidences(res, probes.conf[sel], self.map.labels, self.map.confidences, inner)
            if cfg.association.fill_unlabeled:
                res.filled = fill_from_probes(
                    self.map, probes, sel, res, cfg.association.knn_radius, self.naive
                )
            k.labels[sel] = res.seg_labels[probes.seg[sel]]
            k.seg_to_label = (probes.seg_ids.cpu().numpy(), res.seg_labels.cpu().numpy())
            if self.evidence.enabled:
                k.parts = self.evidence.new_parts(self.map, probes, sel, res)
            for name, v in res.counts().items():
                self.timings.add(f"segments_{name}", v)
            k.conf = torch.where(k.labels >= 0, 1.0 if self.naive else probes.conf, k.conf)

    def _add(self, k: _Keyframe) -> None:
        """The probes the map does not explain become Gaussians."""
        cfg, probes = self.cfg, k.probes
        with self.timings.section("add"):
            new = probes.new
            rows = self.map.append(
                probes.means[new],
                probes.colors[new],
                probes.log_scales[new],
                labels=k.labels[new],
                confidences=k.conf[new],
                opacity_logits=math.log(cfg.init.opacity / (1 - cfg.init.opacity)),
                origin_kf=k.index,
            )
            self.timings.add("gaussians_added", int(new.sum()))
        self.evidence.assign(self.map, rows, k.parts[new] if k.parts is not None else None)

    def _optimize(self, k: _Keyframe) -> None:
        """Geometry/appearance optimisation over the keyframe and memory views, then pruning."""
        cfg, frame = self.cfg, k.frame
        with self.timings.section("optimize"):
            pool = list(self.recent) + [e for e in self.memory.entries if e not in self.recent]
            views = training_views(frame, pool, cfg.optimize.memory_frames, self.rng, self.device)
            opt = optimize_map(self.map, views, cfg.optimize)
            removed = self.map.prune(cfg.optimize.prune_opacity, cfg.optimize.prune_scale)
            self.timings.add("gaussians_pruned", removed)
            if opt["iters"]:
                self.timings.counts["last_loss"] = opt["loss_last"]

    def _memory(self, k: _Keyframe) -> None:
        """The keyframe joins the recent views, and the memory buffer when it passes its criteria."""
        frame = k.frame
        entry = MemoryEntry(
            k.index, frame.rgb, frame.depth.astype(np.float32), frame.K, frame.pose, k.segments, k.scores
        )
        self.recent.append(entry)
        with self.timings.section("memory"):
            if self.memory.consider(entry, self.device):
                self.timings.add("memory_added")

    def _scheduled_passes(self) -> None:
        """The long-term update, then the global refinement, at the keyframes of their schedules."""
        if self.use_longterm and _ran_at(self.keyframe_count, self.cfg.longterm.every):
            self._longterm()
        if self.use_refine and _ran_at(self.keyframe_count, self.cfg.refine.every):
            self._refine()

    def _graph_update(self, k: _Keyframe) -> None:
        if self.config.graph.enabled and not self.graph_feed.failed:
            with self.timings.section("graph"):
                self.graph_feed.step(
                    self.map, k.index, k.frame, k.segments, k.seg_to_label, k.names, self.frames_seen
                )

    def _count_map(self) -> None:
        """The map's size counters in ``timings`` (after each keyframe, and from the final map)."""
        self.timings.counts["gaussians"] = len(self.map)
        self.timings.counts["labels"] = int(torch.unique(self.map.labels[self.map.labels >= 0]).numel())
        self.timings.counts["memory_size"] = len(self.memory)

    def _checkpoint(self) -> None:
        """``map.npz`` every ``checkpoint_every`` keyframes, into the checkpoint folder when one is set."""
        every = self.cfg.checkpoint_every
        if every <= 0 or self._checkpoint_dir is None or self.keyframe_count % every:
            return
        with self.timings.section("checkpoint"):
            try:
                self.save_checkpoint(RunFolder(self._checkpoint_dir).map)
            except OSError as e:
                # a safety net: a full disk must not stop the mapping (the previous checkpoint stays)
                log.warning(
                    "checkpoint not written (%s); mapping goes on, the next checkpoint tries again", e
                )
                self.timings.add("checkpoint_errors")

    def _observe_evidence(self, k: _Keyframe) -> None:
        """The keyframe's co-segmentation evidence, once its new Gaussians are in the map (its segments made
        them: the view is their first judge)."""
        self.evidence.judge(self.map, k.index, k.segments, k.scores, k.frame)

    def _longterm(self) -> None:
        """The long-term Eq. 16 update over the next memory views of the round-robin."""
        cfg = self.cfg
        views = self.memory.next_views(cfg.longterm.views)
        # the views this pass judges (fewer while the memory fills), for benchmarks/semantic_growth.py
        self.timings.note("memory_views", len(views))
        self.evidence.before_longterm(self.map, views)
        with self.timings.section("longterm"):
            for entry in views:
                st = longterm_view_update(self.map, entry, cfg.longterm, cfg.association.knn_radius)
                for k, v in st.as_dict().items():
                    if k != "mean_iou":
                        self.timings.add(f"longterm_{k}", v)

    def _refine(self) -> None:
        """Global 3D refinement (Algorithm 1), deciding from the views' evidence where it is collected
        (merges and splits first, then Algorithm 1 guarded by the same views); counts to the timings."""
        cfg = self.cfg
        separated, exposed, exposed_to = self.evidence.before_refine(self.map)
        with self.timings.section("refine"):
            st = global_refinement(
                self.map.means,
                self.map.labels,
                self.map.confidences,
                tau_low=cfg.refine.tau_low,
                tau_high=cfg.refine.tau_high,
                r_search=cfg.refine.r_search,
                cluster_radius=cfg.refine.cluster_radius,
                graph_k=cfg.refine.graph_k,
                include_unlabeled=cfg.refine.unlabeled,
                separated=separated,
                exposed=exposed,
                exposed_to=exposed_to,
            )
        self.evidence.after_refine(self.map)
        for k, v in st.as_dict().items():
            self.timings.add(f"refine_{k}", v)

    # ------------------------------------------------------------------ end, files
    def finalize(self) -> None:
        """End of stream: one last long-term pass and refinement (per the ablation), then pruning.

        Beyond the paper, whose schedule simply stops with the stream: the keyframes since the last scheduled
        pass (up to ``longterm_every`` / ``refine_every`` - 1 of them) get their long-term update and
        refinement too. It runs even where the last keyframe's scheduled pass just did: the long-term step
        then takes the next memory views of its round-robin, and a second refinement changes little
        (measured: docs/deviations.md, "final pass"), so the simpler rule stays."""
        cfg = self.cfg
        self.timings.end_keyframe()  # a keyframe that raised mid-way does not take the end's passes
        if self.keyframe_count == 0:
            return
        if self.use_longterm:
            self._longterm()
        if self.use_refine:
            self._refine()
        with self.timings.section("prune"):
            self.map.prune(cfg.optimize.prune_opacity, cfg.optimize.prune_scale)
        # timed with the per-keyframe updates ("graph")
        self.graph_feed.finalize(self.map, self.keyframe_count - 1, self.frames_seen)
        self._count_map()  # the final map's: pruning and refinement change the counts of the last keyframe
        self.finalized = True
