"""The incremental semantic mapper: runs the paper's per-keyframe loop on a stream of frames.

Per keyframe:
1. segments (the frame's precomputed ones, else the optional segmenter; none -> geometry only);
2. render the map at the frame's pose (alpha + expected depth) to find the pixels it does not explain;
3. probes: grid-subsampled back-projected pixels per segment (``init.make_probes``);
4. local 3D optimization: KNN association, r(m)/p(m), three cases (``local.associate_segments``);
   beyond the paper, an ambiguous confident segment that holds the whole visible extent of its two labels
   merges them and becomes case (ii) (``merge.py``, ``mapping.merge_duplicates``); then Eq. 5 for every
   case-(ii) segment, merged ones included (``local.update_confidences``); unlabeled Gaussians under a
   now-labeled segment take its label (``mapping.fill_unlabeled``);
5. the unexplained probes become Gaussians with their segment's label and rescaled SAM confidence
   (unlabeled Gaussians, from ambiguous segments or pixels outside every segment, get confidence 0, so
   the individual refinement may label them: ``mapping.refine_unlabeled``);
6. geometry/appearance optimization over the keyframe + memory frames, then pruning;
7. memory buffer update (frustum + overlap criteria);
8. every ``longterm_every`` keyframes the long-term Eq. 16 update over a few memory views, then every
   ``refine_every`` keyframes the global refinement (Alg. 1): the long-term step lowers confidences of
   inconsistent Gaussians and the refinement relabels them in the same keyframe;
9. scene-graph observation/update when ``config.graph.enabled`` (failures there never stop mapping).

``process`` reads as these stages, each a method and one timed section of ``timings``: ``_admit`` (the
frame's checks, tracking and pose-jump test; where the frame starts to count as read, the rule a resume
depends on), ``_render_check`` (2), ``_init`` (3), ``_local`` (4), ``_add`` (5), ``_optimize`` (6),
``_memory`` (7), ``_scheduled_passes`` (8: ``_longterm``, ``_refine``), ``_graph_update`` (9) and
``_checkpoint`` (``mapping.checkpoint_every``).

Every frame's pose (the dataset's, or the tracker's under ``tracking.poses: odometry``) is first compared
with the last accepted frame's: a jump beyond ``mapping.max_pose_step`` / ``max_pose_step_deg`` warns, leaves
the frame out or stops the run (``mapping.on_pose_jump``, ``pose_jump.py``).

Ablations (``mapping.ablation``): "naive" (majority label of the KNN matches or a new label, no ambiguity
test, all confidences 1, no refinement, no long-term), "local", "local+global", "full".
Per-module wall time and counts are kept in ``timings`` (written to ``timings.json``).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..config import Config, check_config, choices
from ..device import resolve_device
from ..errors import ConfigError, DataError, OGSceneError
from ..frame import Frame, implausible_median_depth
from ..gaussians import GaussianMap, corrupt_npz_message
from ..runs import RunFolder, save_run
from ..up_axis import AGREE_DEG, CameraUp, angle_deg, axis_name, is_auto
from .checkpoint import CheckpointArrays, read_checkpoint
from .evidence import MIN_PART, EvidenceModel
from .init import make_probes
from .keyframes import KeyframeSelector
from .local import (
    CASE_AMBIGUOUS,
    CASE_MATCHED,
    CASE_NOVEL,
    associate_segments,
    coherence,
    fill_unlabeled,
    group_top2,
    rescale_sam_scores,
    update_confidences,
)
from .longterm import MemoryBuffer, MemoryEntry, label_edges, longterm_view_update
from .memory_files import load_view, manifest, read_manifest, remove_unreferenced, store_view
from .merge import duplicate_label_pairs, label_containment, merge_labels, relabel, visible_pixels
from .optimize import View, optimize_map
from .pose_jump import PoseJumpCheck, PoseJumpError
from .refine import connected_clusters, global_refinement

log = logging.getLogger(__name__)

ABLATIONS = choices("mapping.ablation")


def _segment_ids(ids, frame: Frame, source: str) -> np.ndarray:
    """The id map of ``frame``'s segments from ``source``, checked; negative ids (a common "background"
    value) count as no segment, as 0 does."""
    ids = np.asarray(ids)
    if ids.shape != frame.rgb.shape[:2]:
        raise DataError(
            f"frame {frame.index} ({frame.name or 'unnamed'}): {source} gave segment ids of shape "
            f"{ids.shape}, the image is {frame.rgb.shape[:2]}"
        )
    if not (np.issubdtype(ids.dtype, np.integer) or ids.dtype == np.bool_):
        raise DataError(
            f"frame {frame.index} ({frame.name or 'unnamed'}): {source} gave segment ids of dtype "
            f"{ids.dtype}; an integer id map is needed (0 = no segment)"
        )
    if ids.size and ids.min() < 0:
        ids = np.maximum(ids, 0)
    return ids


def _name_votes(segments: np.ndarray, lut: np.ndarray, names: dict[int, str]) -> dict[int, dict[str, int]]:
    """{scene label: {detector class name: pixels}} from a keyframe's named segments (``lut``: segment id
    -> scene label, -1 = none)."""
    area = np.bincount(segments.reshape(-1).astype(np.int64), minlength=len(lut))
    votes: dict[int, dict[str, int]] = {}
    for sid, name in names.items():
        if not 0 < sid < len(lut) or lut[sid] < 0 or area[sid] == 0:
            continue
        d = votes.setdefault(int(lut[sid]), {})
        d[name] = d.get(name, 0) + int(area[sid])
    return votes


class Timings:
    """Accumulated wall time (s) and call counts per module, plus free-form counters, and each keyframe's
    time per module (``per_keyframe``: how a module's cost grows along the stream)."""

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self.counts: dict[str, float] = {}
        # per keyframe of the stream: its frame index and the wall and CPU seconds of each module in its
        # process (CPU time: the process's, all threads; steadier than wall time on a shared machine)
        self.per_keyframe: list[dict] = []
        self._keyframe: dict | None = None

    def begin_keyframe(self, frame_index: int) -> None:
        """The sections from here to :meth:`end_keyframe` make a new row of ``per_keyframe``."""
        self._keyframe = {"frame": int(frame_index), "wall": {}, "cpu": {}}
        self.per_keyframe.append(self._keyframe)

    def end_keyframe(self) -> None:
        self._keyframe = None

    @contextmanager
    def section(self, name: str):
        sync = self.device.type == "cuda"
        if sync:
            torch.cuda.synchronize(self.device)
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            if sync:
                torch.cuda.synchronize(self.device)
            dt = time.perf_counter() - t0
            self.seconds[name] = self.seconds.get(name, 0.0) + dt
            self.calls[name] = self.calls.get(name, 0) + 1
            if self._keyframe is not None:
                wall, cpu = self._keyframe["wall"], self._keyframe["cpu"]
                wall[name] = wall.get(name, 0.0) + dt
                cpu[name] = cpu.get(name, 0.0) + time.process_time() - c0

    def add(self, name: str, value: float = 1) -> None:
        self.counts[name] = self.counts.get(name, 0) + value

    def state(self) -> dict:
        return {
            "seconds": self.seconds,
            "calls": self.calls,
            "counts": self.counts,
            "per_keyframe": self.per_keyframe,
        }

    def load_state(self, state: dict) -> None:
        self.seconds = {str(k): float(v) for k, v in state.get("seconds", {}).items()}
        self.calls = {str(k): int(v) for k, v in state.get("calls", {}).items()}
        self.counts = {str(k): v for k, v in state.get("counts", {}).items()}
        self.per_keyframe = [
            {"frame": int(row["frame"]), "wall": dict(row["wall"]), "cpu": dict(row["cpu"])}
            for row in state.get("per_keyframe", [])
        ]
        self._keyframe = None

    def as_dict(self) -> dict:
        kf = max(1, int(self.counts.get("keyframes", 0)))
        return {
            "seconds": {k: round(v, 6) for k, v in self.seconds.items()},
            "calls": dict(self.calls),
            "ms_per_keyframe": {k: round(1000 * v / kf, 3) for k, v in self.seconds.items()},
            "counts": {k: (int(v) if float(v).is_integer() else v) for k, v in self.counts.items()},
            # each keyframe's frame index, and per module its wall and CPU milliseconds in each keyframe in
            # order (0: it did not run there); the end of stream's passes (finalize) are in "seconds" only
            "per_keyframe_frame": [row["frame"] for row in self.per_keyframe],
            "per_keyframe_ms": self._series("wall"),
            "per_keyframe_cpu_ms": self._series("cpu"),
        }

    def _series(self, kind: str) -> dict[str, list[float]]:
        names = sorted({n for row in self.per_keyframe for n in row[kind]})
        return {n: [round(1000 * row[kind].get(n, 0.0), 3) for row in self.per_keyframe] for n in names}

    def table(self) -> str:
        """A per-module timing table (text)."""
        kf = max(1, int(self.counts.get("keyframes", 0)))
        rows = [f"{'module':<14}{'calls':>7}{'total s':>10}{'ms/keyframe':>13}"]
        for k, v in sorted(self.seconds.items(), key=lambda kv: -kv[1]):
            rows.append(f"{k:<14}{self.calls.get(k, 0):>7}{v:>10.2f}{1000 * v / kf:>13.1f}")
        return "\n".join(rows)


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
    alpha: torch.Tensor | None = None  # the map rendered at the keyframe's pose (None: empty map)
    depth: torch.Tensor | None = None
    probes: Any = None
    labels: torch.Tensor | None = None  # per probe: scene label (-1: none) and confidence
    conf: torch.Tensor | None = None
    seg_to_label: tuple[np.ndarray, np.ndarray] | None = None  # segment ids -> their scene labels
    parts: torch.Tensor | None = None  # per probe: the evidence part its new Gaussian joins (evidence.py)


class Mapper:
    """Incremental semantic Gaussian mapper: ``process(frame)`` per frame, ``finalize()``, ``save(dir)``."""

    def __init__(self, config: Config, device: str | torch.device | None = None, segmenter=None) -> None:
        check_config(config)  # the numeric ranges, also of a Config() built and changed in Python
        self.config = config
        self.cfg = cfg = config.mapping
        if cfg.ablation not in ABLATIONS:
            raise ConfigError(f"mapping.ablation must be one of {ABLATIONS}, got {cfg.ablation!r}")
        self.device = resolve_device(device if device is not None else config.device)
        self.segmenter = segmenter
        self._tracker = None
        self.map = GaussianMap(self.device)
        self.keyframes = KeyframeSelector(
            cfg.keyframe_every, cfg.keyframe_translation, cfg.keyframe_rotation_deg
        )
        self.memory = MemoryBuffer(cfg.tau_long, cfg.r_search, cfg.memory_max, cfg.memory_point_step)
        self.pose_check = PoseJumpCheck(
            cfg.max_pose_step, cfg.max_pose_step_deg, cfg.on_pose_jump, stride=config.data.stride
        )
        self.recent: deque[MemoryEntry] = deque(maxlen=max(1, cfg.opt_memory_frames))
        self.timings = Timings(self.device)
        self.frames_seen = 0
        # the dataset position after the latest frame given to process (mapped, untracked or not a
        # keyframe): where a resumed run goes on, also when frames were skipped
        self.next_index = 0
        self.keyframe_count = 0
        self.rng = np.random.default_rng(config.seed)
        # the views' co-segmentation evidence (evidence.py), collected where the refinement runs
        self.evidence = EvidenceModel(
            self.device, cell=cfg.evidence_cell, radius=cfg.r_search, separation=cfg.evidence_separation,
            split_ratio=cfg.evidence_split_ratio, min_part=cfg.merge_min_part,
            min_views=cfg.evidence_dispute_views,
        )  # fmt: skip
        # built now, so that a mistake in the graph's settings (captioner, relations, confidence model)
        # stops the run before its first frame instead of disabling the graph hours into it
        self._graph = self._new_graph() if config.graph.enabled else None
        self._up_checked = False
        self._graph_failed = False
        self._warned_no_segments = False
        self._checked_depth_range = False
        self._checkpoint_dir: Path | None = None
        # under odometry, the tracked pose of every frame given to process (None: untracked), for traj.txt
        self.trajectory: list[np.ndarray | None] = []
        # whether finalize ran after the latest keyframe (a resumed finished run has nothing left to do)
        self.finalized = False
        # what the frames come from (set by the caller, e.g. {"path", "frames", "first"}), kept in
        # checkpoints so that a resume can tell another sequence from the same one
        self.source: dict = {}
        # the mapped cameras' up direction in the world: chooses graph.up_axis auto, or checks a given one
        self._camera_up = CameraUp()

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
        return None if self._graph_failed else self._graph

    def set_checkpoint_dir(self, out_dir: str | Path | None) -> None:
        """Where ``checkpoint_every`` writes ``map.npz`` during mapping."""
        self._checkpoint_dir = Path(out_dir) if out_dir is not None else None

    # ------------------------------------------------------------------ per frame
    def _new_graph(self):
        from ..graph import SceneGraph

        return SceneGraph(self.config.graph)

    def _check_up_axis(self) -> None:
        """At the first graph update (the cameras over the frames mapped until then): choose graph.up_axis
        when it is still auto (nothing told it when the run opened: a recording tracked by odometry, a live
        camera), logged; else warn (once) when the given one is far from where the cameras' up points:
        relations (on, under) and floor / wall / ceiling tags would then use a wrong vertical (worlds differ:
        Replica's and ScanNet's are z-up, an OpenCV camera's first frame is -y up).
        :data:`~ogscene3d.up_axis.AGREE_DEG` leaves room for cameras pitched down at a table."""
        if self._up_checked:
            return
        self._up_checked = True
        cam_up = self._camera_up.estimate()
        if is_auto(self.config.graph.up_axis):
            if cam_up is None:
                return  # no camera mapped yet: the provisional up stays
            self.config.graph.up_axis = [float(v) for v in cam_up]
            if self._graph is not None:
                self._graph.set_up_axis(cam_up)
            log.info(
                "graph.up_axis auto: %s (the cameras' up direction over the %d frames mapped)",
                axis_name(cam_up),
                self._camera_up.count,
            )
            return
        up = np.asarray(self.config.graph.up_axis, dtype=np.float64)
        if cam_up is None or up.shape != (3,) or not np.linalg.norm(up) > 0:
            return
        angle = angle_deg(up, cam_up)
        if angle > AGREE_DEG:
            axis = int(np.argmax(np.abs(cam_up)))
            guess = [0.0, 0.0, 0.0]
            guess[axis] = 1.0 if cam_up[axis] > 0 else -1.0
            log.warning(
                "graph.up_axis %s is %.0f deg from the cameras' mean up direction %s over %d frames: the "
                "scene graph's on/under relations and floor/wall/ceiling tags would use a wrong vertical; if "
                "this world is %s-up, set --set graph.up_axis=%s (or leave graph.up_axis auto)",
                up.tolist(),
                angle,
                np.round(cam_up, 2).tolist(),
                self.frames_seen,
                "xyz"[axis] if guess[axis] > 0 else "-" + "xyz"[axis],
                "[" + ",".join(f"{v:g}" for v in guess) + "]",
            )

    def _segments(self, frame: Frame) -> tuple[np.ndarray | None, dict[int, float], dict[int, str]]:
        """The keyframe's segment ids, scores and (where a detector named them) class names."""
        if frame.segments is not None:
            ids = _segment_ids(frame.segments, frame, "frame.segments")
            return ids, dict(frame.segment_scores), dict(frame.segment_names)
        if self.segmenter is None:
            self.segmenter = _default_segmenter(self.config, frame.K)
        if self.segmenter is not None:
            with self.timings.section("segment"):
                if hasattr(self.segmenter, "segment_frame"):  # the simulated segmenter reads ground truth
                    seg = self.segmenter.segment_frame(frame)
                else:
                    seg = self.segmenter(frame.rgb, frame.depth)
            ids = _segment_ids(seg.ids, frame, type(self.segmenter).__name__)
            return ids, dict(seg.scores), dict(getattr(seg, "names", {}) or {})
        if not self._warned_no_segments:
            log.warning("frames carry no segments and no segmenter was given: mapping geometry only")
            self._warned_no_segments = True
        return None, {}, {}

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

    def _pose_jumped(self, frame: Frame) -> bool:
        """Check the frame's pose against the last accepted frame's (``pose_jump.py``). True: leave the frame
        out (``on_pose_jump: skip``); raises :class:`PoseJumpError` under ``on_pose_jump: error``."""
        jump = self.pose_check.check(frame.index, frame.pose, frame.name or "unnamed")
        if jump is not None:
            action = self.pose_check.action
            if action == "error":
                raise PoseJumpError(
                    f"{jump.describe()}; fix the pose, or set mapping.on_pose_jump to skip (leave the frame "
                    "out) or warn (map it anyway)"
                )
            self.timings.add("pose_jumps")
            if action == "skip":
                log.warning("%s: frame left out (mapping.on_pose_jump: skip)", jump.describe())
                self.timings.add("frames_skipped_pose_jump")
                return True
            log.warning("%s: mapped anyway (mapping.on_pose_jump: warn)", jump.describe())
        self.pose_check.accept(frame.index, frame.pose)
        return False

    def _get_tracker(self):
        if self._tracker is None:
            from ..tracking import Tracker

            # device None: Open3D's CUDA when it has it
            self._tracker = Tracker(self.config.tracking, device=None, frame_step=self.config.data.stride)
        return self._tracker

    def process(self, frame: Frame) -> bool:
        """Map one frame. Returns True when it was a keyframe (non-keyframes are only counted)."""
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
        jumped = tracked and self._pose_jumped(frame)  # may raise (mapping.on_pose_jump: error)
        # ---- from here on the frame counts as read
        self.next_index = frame.index + 1
        if odometry:
            self.trajectory.append(np.array(frame.pose, dtype=np.float64) if tracked else None)
        if not tracked or jumped:
            return False
        self._camera_up.add(frame.pose)
        self._check_depth_range(frame)
        self.frames_seen += 1
        self.timings.add("frames")
        return True

    def _check_depth_range(self, frame: Frame) -> None:
        if self._checked_depth_range or not np.any(frame.depth > 0):
            return
        self._checked_depth_range = True
        # a dataset's frame: the dataset has warned already, naming the setting to fix
        median = None if frame.depth_scale_checked else implausible_median_depth(frame.depth)
        if median is not None:
            log.warning(
                "frame %d (%s): median depth %.3g m is implausible for an RGB-D camera; Frame.depth "
                "must be in metres (0 = invalid), or the map will be empty or wrong",
                frame.index,
                frame.name or "unnamed",
                median,
            )

    def _begin_keyframe(self, frame: Frame) -> _Keyframe:
        self.timings.begin_keyframe(frame.index)
        segments, scores, names = self._segments(frame)
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
        from ..rendering import rasterization

        with self.timings.section("render_check"):
            if len(self.map) == 0:
                return
            gm, frame = self.map, k.frame
            viewmat = torch.as_tensor(np.linalg.inv(frame.pose), dtype=torch.float32, device=self.device)[
                None
            ]
            K = torch.as_tensor(frame.K, dtype=torch.float32, device=self.device)[None]
            with torch.no_grad():
                depth, alpha, _ = rasterization(
                    gm.means,
                    gm.quats,
                    gm.scales,
                    gm.opacities,
                    gm.colors[:, :1],
                    viewmat,
                    K,
                    frame.width,
                    frame.height,
                    render_mode="ED",
                )
            k.alpha, k.depth = alpha[0, ..., 0], depth[0, ..., 0]

    def _init(self, k: _Keyframe) -> None:
        """Probes: grid-subsampled back-projected pixels per segment, those the map explains marked."""
        cfg = self.cfg
        with self.timings.section("init"):
            k.probes = make_probes(
                k.frame,
                k.segments,
                k.scores,
                self.device,
                step=max(1, round(math.sqrt(cfg.pixels_per_gaussian))),
                score_range=tuple(self.config.segmentation.sam_score_range),
                conf_range=tuple(self.config.segmentation.conf_range),
                rendered_alpha=k.alpha,
                rendered_depth=k.depth,
                alpha_thresh=cfg.init_alpha_thresh,
                depth_margin=cfg.init_depth_margin,
                min_depth=self.config.data.min_depth,
                max_depth=self.config.data.max_depth,
                dense_below=cfg.init_dense_below,
            )

    def _local(self, k: _Keyframe) -> None:
        """Local 3D association (KNN, r(m)/p(m), the three cases), duplicate merging, Eq. 5, filling: the
        scene label and confidence of every probe."""
        cfg, probes = self.cfg, k.probes
        with self.timings.section("local"):
            k.labels = torch.full((len(probes),), -1, dtype=torch.int32, device=self.device)
            k.conf = torch.zeros(len(probes), dtype=torch.float32, device=self.device)
            S = int(probes.seg_ids.numel())
            in_seg = probes.seg >= 0
            if not (S and bool(in_seg.any())):
                return
            sel = torch.nonzero(in_seg).squeeze(1)
            res = associate_segments(
                probes.means[sel],
                probes.seg[sel],
                probes.conf[sel],
                S,
                self.map.means,
                self.map.labels,
                self.map.confidences,
                self.map.new_labels,
                k=cfg.knn_k,
                radius=cfg.knn_radius,
                tau_valid=cfg.tau_valid,
                tau_p=cfg.tau_p,
                naive=self.naive,
                novel_before_ambiguous=cfg.novel_before_ambiguous,
                # a probe's log-scale is log(grid spacing at its depth): see init.make_probes
                probe_radius=(
                    torch.exp(probes.log_scales[sel]) * cfg.knn_radius_spacing
                    if cfg.knn_radius_spacing > 0
                    else None
                ),
                eq5=False,  # below, once the merge has turned some ambiguous segments into matched ones
            )
            if self._merging(k.segments):
                self._merge_duplicates(k.frame, k.segments, k.scores, probes, res)
            if not self.naive:
                update_confidences(
                    res,
                    probes.conf[sel],
                    self.map.labels,
                    self.map.confidences,
                    self._inner_probes(k.segments, probes.pix[sel]) if cfg.eq5_skip_edges else None,
                )
            if cfg.fill_unlabeled:
                pconf = probes.conf[sel]
                res.filled = fill_unlabeled(
                    probes.means[sel],
                    probes.seg[sel],
                    torch.ones_like(pconf) if self.naive else pconf,  # naive: every confidence is 1
                    res.seg_labels,
                    self.map.means,
                    self.map.labels,
                    self.map.confidences,
                    cfg.knn_radius,
                )
            k.labels[sel] = res.seg_labels[probes.seg[sel]]
            k.seg_to_label = (probes.seg_ids.cpu().numpy(), res.seg_labels.cpu().numpy())
            if self._collects_evidence():
                k.parts = self._new_parts(probes, sel, res)
            for name, v in res.counts().items():
                self.timings.add(f"segments_{name}", v)
            k.conf = torch.where(k.labels >= 0, 1.0 if self.naive else probes.conf, k.conf)

    def _new_parts(self, probes, sel: torch.Tensor, res) -> torch.Tensor:
        """Per probe: the evidence part its new Gaussian joins (``evidence.py``). A segment matched with a
        label (case ii) continues the part that most of its probes' nearest Gaussians of that label belong
        to; the new Gaussians of any other segment (novel, ambiguous, or matched without such a Gaussian),
        and those outside every segment, start a part per spatial component (linked within ``r_search``, as
        Algorithm 1's clusters): a segment over two objects apart in space makes two parts, which the views
        that follow may hold together or keep apart."""
        gm, S = self.map, int(res.seg_labels.numel())
        self.evidence.ensure_cells(gm)
        seg = probes.seg[sel]
        near = res.nearest
        hit = near >= 0
        same = torch.zeros_like(hit)
        same[hit] = gm.labels[near[hit]].long() == res.seg_labels[seg[hit]].long()
        cell = gm.aux("ev_cell", -1.0)[near[same]].long()
        top, cnt, _, _ = group_top2(seg[same], self.evidence.cell_part[cell.clamp(min=0)], S)
        seg_part = torch.where(cnt > 0, top, torch.full_like(top, -1))
        parts = torch.full((len(probes),), -1, dtype=torch.long, device=self.device)
        parts[sel] = seg_part[seg]
        fresh = torch.nonzero(probes.new & (parts < 0)).squeeze(1)
        if fresh.numel():
            group = torch.full((len(probes),), S, dtype=torch.int32, device=self.device)  # S: no segment
            group[sel] = seg.to(torch.int32)
            comp = connected_clusters(
                probes.means[fresh], group[fresh], self.cfg.r_search, self.cfg.refine_graph_k
            )
            # a few Gaussians apart from the rest of their segment (a hole the map did not explain) join the
            # segment's largest component: a part too small to be judged says nothing
            size = torch.bincount(comp)
            seg_of = torch.zeros_like(size).scatter_(0, comp, group[fresh].long())
            best = torch.zeros(S + 1, dtype=torch.long, device=self.device)
            best.scatter_reduce_(0, seg_of, size, reduce="amax")
            ids = torch.arange(size.numel(), device=self.device)
            is_best = size >= best[seg_of]
            main = torch.full((S + 1,), size.numel(), dtype=torch.long, device=self.device)
            main.scatter_reduce_(0, seg_of[is_best], ids[is_best], reduce="amin")
            comp = torch.where(size[comp] >= MIN_PART, comp, main[seg_of[comp]])
            _, comp = torch.unique(comp, return_inverse=True)
            parts[fresh] = self.evidence.new_parts(int(comp.max()) + 1)[comp]
        return parts

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
                opacity_logits=math.log(cfg.init_opacity / (1 - cfg.init_opacity)),
                origin_kf=k.index,
            )
            self.timings.add("gaussians_added", int(new.sum()))
        if self._collects_evidence():
            with self.timings.section("evidence"):
                idx = torch.arange(rows.start, rows.stop, device=self.device)
                parts = k.parts[new] if k.parts is not None else None
                if parts is None:  # no segments: one part for the keyframe's Gaussians
                    parts = self.evidence.new_parts(1).expand(idx.numel())
                self.evidence.assign(self.map, idx, parts)

    def _optimize(self, k: _Keyframe) -> None:
        """Geometry/appearance optimisation over the keyframe and memory views, then pruning."""
        cfg, frame = self.cfg, k.frame
        with self.timings.section("optimize"):
            views = [View.from_arrays(frame.rgb, frame.depth, frame.pose, frame.K, self.device)]
            pool = list(self.recent) + [e for e in self.memory.entries if e not in self.recent]
            pool = [e for e in pool if e.depth.shape == frame.depth.shape]
            if pool and cfg.opt_memory_frames > 0:
                pick = self.rng.choice(len(pool), size=min(cfg.opt_memory_frames, len(pool)), replace=False)
                views += [
                    View.from_arrays(pool[i].rgb, pool[i].depth, pool[i].pose, pool[i].K, self.device)
                    for i in sorted(pick)
                ]
            opt = optimize_map(self.map, views, cfg)
            removed = self.map.prune(cfg.prune_opacity, cfg.prune_scale)
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
        if self.use_longterm and _ran_at(self.keyframe_count, self.cfg.longterm_every):
            self._longterm()
        if self.use_refine and _ran_at(self.keyframe_count, self.cfg.refine_every):
            self._refine()

    def _graph_update(self, k: _Keyframe) -> None:
        if self.config.graph.enabled and not self._graph_failed:
            with self.timings.section("graph"):
                self._graph_step(k.index, k.frame, k.segments, k.seg_to_label, k.names)

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

    def _inner_probes(self, segments: np.ndarray, pix: torch.Tensor) -> torch.Tensor:
        """[P] bool: probes whose pixel is off every segment boundary (they may make Eq. 5 updates)."""
        ids = torch.from_numpy(np.ascontiguousarray(segments, dtype=np.int64)).to(self.device)
        return ~label_edges(ids).reshape(-1)[pix]

    def _merging(self, segments: np.ndarray | None) -> bool:
        return (
            self.cfg.merge_duplicates
            and not self.naive
            and segments is not None
            and bool((self.map.labels >= 0).any())
        )

    def _merge_duplicates(
        self, frame: Frame, segments: np.ndarray, scores: dict[int, float], probes, res
    ) -> None:
        """Merge scene labels that one confident ambiguous segment shows to be one object (``merge.py``);
        the segment then takes the merged label (case ii), and this keyframe's segment labels follow. With
        ``merge_novel`` a would-be novel segment is judged too: over two labels it may merge them, and when
        it holds its most matched label whole it takes that label. Runs before Eq. 5, so that the merged
        segments' matches get their confidence update too."""
        cfg = self.cfg
        seg_ids = probes.seg_ids
        score = torch.tensor(
            [scores.get(int(i), 1.0) for i in seg_ids.tolist()], dtype=torch.float32, device=self.device
        )
        confident = score >= cfg.merge_min_score
        novel = (res.seg_case == CASE_NOVEL) & confident & bool(cfg.merge_novel)
        # ambiguous segments, and novel ones whose few matches fall on two labels, may merge those; a novel
        # one may hold its most matched label whole
        amb = torch.nonzero(
            (res.seg_case == CASE_AMBIGUOUS) & confident | novel & (res.r >= cfg.tau_valid)
        ).squeeze(1)
        ext = torch.nonzero(novel & (res.top_label >= 0)).squeeze(1)
        if amb.numel() == 0 and ext.numel() == 0:
            return
        with self.timings.section("merge"):
            ids = torch.as_tensor(np.asarray(segments), dtype=torch.int64, device=self.device)
            top = max(int(ids.max()), int(seg_ids.max())) + 1
            lut = torch.full((top,), -1, dtype=torch.int64, device=self.device)
            lut[seg_ids] = torch.arange(seg_ids.numel(), device=self.device)
            seg_index = lut[ids.clamp(min=0)].masked_fill(ids <= 0, -1).reshape(-1)
            pick = torch.nonzero(self.map.labels >= 0).squeeze(1)  # all: min_part counts the segment's labels
            pix = visible_pixels(
                self.map.means[pick],
                torch.as_tensor(frame.pose, dtype=torch.float32, device=self.device),
                torch.as_tensor(frame.K, dtype=torch.float32, device=self.device),
                torch.as_tensor(frame.depth, dtype=torch.float32, device=self.device),
                cfg.init_depth_margin,
            )
            vis = pix >= 0
            items, item_labels = seg_index[pix[vis]], self.map.labels[pick[vis]]
            if ext.numel():
                # it shows more of that object (a small one seen closer, whose few probes missed its
                # Gaussians): the segment takes its label instead of a new one
                held = label_containment(items, item_labels, ext, res.top_label[ext])
                grow = ext[held >= cfg.merge_contain]
                res.seg_labels[grow] = res.top_label[grow].to(torch.int32)
                res.seg_case[grow] = CASE_MATCHED
                self.timings.add("segments_extended", int(grow.numel()))
            pairs = duplicate_label_pairs(
                items,
                item_labels,
                amb,
                res.top_label,
                res.second_label,
                cfg.merge_contain,
                cfg.merge_min_part,
            )
            mapping = merge_labels(self.map.labels, pairs)
            if not mapping:
                return
            res.top_label = relabel(res.top_label, mapping)
            res.second_label = relabel(res.second_label, mapping)
            res.seg_labels = relabel(res.seg_labels, mapping)
            merged = amb[res.top_label[amb] == res.second_label[amb]]
            res.seg_labels[merged] = res.top_label[merged].to(torch.int32)
            res.seg_case[merged] = CASE_MATCHED
            # p(m) as Eq. 5 must see it now: the probes on either merged label agree with l*_m (a merged
            # segment's p counted only one of the two; a matched one's may have had probes on a dropped label)
            res.match_labels = relabel(res.match_labels, mapping)
            p = coherence(res.match_labels, res.probe_seg, res.top_label, int(res.seg_case.numel()))
            res.p = torch.where(res.seg_case == CASE_MATCHED, p, res.p)
            self.timings.add("labels_merged", len(mapping))
            self.timings.add("segments_merged", int(merged.numel()))

    def _collects_evidence(self) -> bool:
        """Whether the views' evidence is collected (``evidence.py``): where the refinement runs."""
        return self.use_refine and self.cfg.evidence

    def _observe_evidence(self, k: _Keyframe) -> None:
        """The keyframe's co-segmentation evidence, once its new Gaussians are in the map (its segments made
        them: the view is their first judge)."""
        if self._collects_evidence():
            self._judge(k.index, k.segments, k.scores, k.frame)

    def _judge(self, view: int, segments, scores: dict[int, float], source, revisit: bool = False) -> None:
        """One view's evidence (``evidence.py``): ``source`` its Frame or MemoryEntry; its segments weighted
        by their rescaled SAM score (Eq. 5's c_sam)."""
        if segments is None:
            return
        ids = list(scores)
        weights = {}
        if ids:
            w = rescale_sam_scores(
                torch.tensor([scores[i] for i in ids]),
                tuple(self.config.segmentation.sam_score_range),
                tuple(self.config.segmentation.conf_range),
            )
            weights = dict(zip(ids, w.tolist()))
        with self.timings.section("evidence"):
            self.evidence.observe(
                self.map, segments, source.pose, source.K, source.depth, weights=weights,
                margin=self.cfg.init_depth_margin, view=view, revisit=revisit,
            )  # fmt: skip

    def _longterm(self) -> None:
        """The long-term Eq. 16 update over the next memory views of the round-robin."""
        cfg = self.cfg
        if self._collects_evidence():  # before Eq. 16, whose P_conf renders the lowered ones
            with self.timings.section("evidence"):
                self.timings.add("evidence_lowered", self.evidence.lower_disputed(self.map))
        views = self.memory.next_views(cfg.longterm_views)
        if self._collects_evidence():
            # the memory views judged again, against the map as it is now: what was made since they were
            # keyframes has had no word from them
            for entry in views:
                self._judge(entry.keyframe, entry.segments, entry.scores, entry, revisit=True)
        with self.timings.section("longterm"):
            for entry in views:
                st = longterm_view_update(
                    self.map,
                    entry,
                    k=cfg.longterm_knn_k,
                    radius=cfg.knn_radius,
                    pixel_step=cfg.longterm_pixel_step,
                    skip_edges=cfg.longterm_skip_edges,
                    same_class=cfg.longterm_same_class,
                )
                for k, v in st.as_dict().items():
                    if k != "mean_iou":
                        self.timings.add(f"longterm_{k}", v)

    # ------------------------------------------------------------------ scene graph
    def _graph_step(
        self,
        kf: int,
        frame: Frame,
        segments: np.ndarray | None,
        seg_to_label: tuple[np.ndarray, np.ndarray] | None,
        names: dict[int, str] | None = None,
    ) -> None:
        """Feed the scene graph; any failure there disables it for the run, mapping goes on.

        The keyframe's label map is its segmentation with each segment replaced by the scene label it was
        given (exact SAM boundaries); without segments, the map's rendered labels. A detector's class
        ``names`` of segments vote, by area, for the name of the scene label each segment was given."""
        try:
            name_votes: dict[int, dict[str, int]] = {}
            if segments is not None and seg_to_label is not None:
                ids, labs = seg_to_label
                lut = np.full(int(max(ids.max(initial=0), segments.max(initial=0))) + 1, -1, dtype=np.int32)
                lut[ids] = labs
                label_map = lut[np.asarray(segments)]
                if names:
                    name_votes = _name_votes(np.asarray(segments), lut, names)
            else:
                label_map = self._render_labels(frame)
            self._graph.observe(kf, frame, label_map, name_votes=name_votes)
            if self._graph.is_due(kf):
                self._check_up_axis()
                gm = self.map
                self._graph.update(kf, gm.means, gm.labels, gm.confidences, gm.colors)
        except Exception as e:  # noqa: BLE001 - the graph is optional; mapping must go on
            log.warning("scene graph disabled for this run after an error: %s: %s", type(e).__name__, e)
            self._graph_failed = True
            self.timings.add("graph_errors")

    def _render_labels(self, frame: Frame) -> np.ndarray:
        """The map's label per pixel [H,W] int32 (-1 where nothing labelled renders) at the frame's pose."""
        from ..rendering import render_semantics

        gm = self.map
        viewmat = torch.as_tensor(np.linalg.inv(frame.pose), dtype=torch.float32, device=self.device)[None]
        K = torch.as_tensor(frame.K, dtype=torch.float32, device=self.device)[None]
        with torch.no_grad():
            sem = render_semantics(
                gm.means,
                gm.quats,
                gm.scales,
                gm.opacities,
                gm.labels,
                gm.confidences,
                viewmat,
                K,
                frame.width,
                frame.height,
            )
        return sem.labels[0].cpu().numpy()

    # ------------------------------------------------------------------ end, files
    def _refine(self) -> None:
        """Global 3D refinement (Algorithm 1), deciding from the views' evidence where it is collected, with
        its relabelling counts added to the timings."""
        cfg = self.cfg
        separated = exposed = None
        if self._collects_evidence():  # merges and splits first, then Algorithm 1 guarded by the same views
            with self.timings.section("evidence"):
                for k, v in self.evidence.decide(self.map).items():
                    self.timings.add(f"evidence_{k}", v)
                separated = self.evidence.separation_test(self.map)
                exposed = self.evidence.disputed(self.map)
        with self.timings.section("refine"):
            st = global_refinement(
                self.map.means,
                self.map.labels,
                self.map.confidences,
                tau_low=cfg.tau_low,
                tau_high=cfg.tau_high,
                r_search=cfg.r_search,
                cluster_radius=cfg.refine_cluster_radius,
                graph_k=cfg.refine_graph_k,
                include_unlabeled=cfg.refine_unlabeled,
                separated=separated,
                exposed=exposed,
            )
        for k, v in st.as_dict().items():
            self.timings.add(f"refine_{k}", v)

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
            self.map.prune(cfg.prune_opacity, cfg.prune_scale)
        if self._graph is not None and not self._graph_failed:
            # timed with the per-keyframe updates: in a run of fewer than graph.init_keyframes keyframes this
            # is the only update there is
            with self.timings.section("graph"):
                try:
                    self._check_up_axis()
                    gm = self.map
                    self._graph.finalize(
                        self.keyframe_count - 1, gm.means, gm.labels, gm.confidences, gm.colors
                    )
                except Exception as e:  # noqa: BLE001
                    log.warning("final scene-graph update failed: %s: %s", type(e).__name__, e)
                    self._graph_failed = True
        self._count_map()  # the final map's: pruning and refinement change the counts of the last keyframe
        self.finalized = True

    def state(self) -> dict[str, np.ndarray]:
        """The mapper's state besides the Gaussians, as the arrays of a checkpoint (``checkpoint.py``): its
        counters and random stream, and the ``state()`` of its parts."""
        nan = np.full((4, 4), np.nan)
        state = {
            "mapper_frames_seen": np.array(self.frames_seen),
            "mapper_next_index": np.array(self.next_index),
            "mapper_keyframe_count": np.array(self.keyframe_count),
            "mapper_memory_cursor": np.array(self.memory._cursor),
            "mapper_finalized": np.array(self.finalized),
            # a resumed run draws the same random numbers as one that was never interrupted
            "mapper_rng": np.array(json.dumps(self.rng.bit_generator.state)),
            "mapper_source": np.array(json.dumps(self.source)),
            # the module times of a run go on across resumes (ms per keyframe divides by all keyframes)
            "mapper_timings": np.array(json.dumps(self.timings.state())),
            "mapper_trajectory": np.stack([nan if p is None else p for p in self.trajectory])
            if self.trajectory
            else np.zeros((0, 4, 4)),
            "mapper_recent": np.array([e.keyframe for e in self.recent], dtype=np.int64),
        }
        state.update(self.keyframes.state())
        state.update(self.pose_check.state())
        if self._tracker is not None:
            state.update(self._tracker.state())  # the odometry goes on in the same trajectory
        if self._graph is not None and not self._graph_failed:
            # captions (possibly paid VLM calls), first_seen and the update schedule go on after a resume
            state["graph_state"] = np.array(json.dumps(self._graph.state()))
        return state

    def save_checkpoint(self, path: str | Path) -> None:
        """Write ``map.npz``: the Gaussians plus the mapper state needed to resume (atomically), and the
        memory views it does not have on disk yet, each in its own file (``memory_files``)."""
        path = Path(path)
        extra = self.state()
        mem = self.memory.entries
        # the keyframes the next one is optimised with (opt_memory_frames) that are not in the memory
        recent = [e for e in self.recent if not any(e is m for m in mem)]
        # the order makes a kill at any point safe: the views the new map.npz names are on disk before it,
        # and the evicted views go only once it has replaced the map.npz that named them
        files = [store_view(path, e) for e in mem]
        recent_files = [store_view(path, e) for e in recent]
        extra.update(manifest(mem, files))
        extra.update(manifest(recent, recent_files, prefix="recent"))
        self.map.save_npz(path, extra=extra)
        for f in remove_unreferenced(path, files + recent_files):
            log.debug("removed %s, a view no longer in the memory", f)

    def load_checkpoint(self, path: str | Path) -> None:
        """Restore the map and mapper state from ``map.npz`` (written by ``save``/``save_checkpoint``, by
        this version or, upgraded by ``checkpoint.upgrade``, an older one)."""
        p = Path(path)
        self.map = GaussianMap.load_npz(p, self.device)
        self.load_state(read_checkpoint(p, self.config.seed), p)

    def load_state(self, state: CheckpointArrays, path: Path) -> None:
        """Restore :meth:`state` (read from the checkpoint ``path`` by ``checkpoint.read_checkpoint``),
        and the memory views its lists name (from their files beside ``path``)."""
        p = path
        try:
            self.frames_seen = int(state["mapper_frames_seen"])
            self.next_index = int(state["mapper_next_index"])
            self.keyframe_count = int(state["mapper_keyframe_count"])
            self.finalized = bool(state["mapper_finalized"])
            self.rng.bit_generator.state = json.loads(str(state["mapper_rng"]))
            self.source = json.loads(str(state["mapper_source"]))
            self.timings.load_state(json.loads(str(state["mapper_timings"])))
            self.trajectory = [None if np.isnan(t).any() else t for t in state["mapper_trajectory"]]
            self.keyframes.load_state(state)
            self.pose_check.load_state(state)
            cursor = int(state["mapper_memory_cursor"])
            views = read_manifest(state, p)
            recent_views = read_manifest(state, p, "recent")
            recent = [int(k) for k in state["mapper_recent"]]
        except DataError:
            raise
        except KeyError as e:
            raise DataError(f"{p}: not a mapper checkpoint (missing {e})") from e
        except (ValueError, TypeError) as e:  # a damaged array
            raise DataError(corrupt_npz_message(p, e)) from e
        self.memory.entries = []
        for entry in state.get("mem_inline", []):  # an older checkpoint's inline views (checkpoint.upgrade)
            self.memory.restore(entry, self.device)
        # a smaller memory_max keeps the newest views: the older ones are not even read
        for record in views[max(0, len(views) - self.memory.max_size) :]:
            self.memory.restore(load_view(p, record), self.device)  # one file read per view
        self.memory._cursor = cursor % max(1, len(self.memory.entries))
        # the recent keyframes in the memory are its entries (one object, as while mapping); the others, and
        # any that a smaller memory_max left out of it, are read from their own files
        in_memory = {e.keyframe: e for e in self.memory.entries}
        records = {r.keyframe: r for r in views + recent_views}
        self.recent.clear()
        for kf in recent[max(0, len(recent) - (self.recent.maxlen or 0)) :]:  # a smaller opt_memory_frames
            entry = in_memory.get(kf)
            if entry is None and kf in records:
                entry = load_view(p, records[kf])
            if entry is not None:
                self.recent.append(entry)
        self._load_graph_state(state.get("graph_state"), p)
        self._load_tracker_state({k: v for k, v in state.items() if k.startswith("trk_")}, p)
        self.timings.counts["keyframes"] = self.keyframe_count
        self.timings.counts["frames"] = self.frames_seen

    def _load_graph_state(self, graph_state: np.ndarray | None, p: Path) -> None:
        self._graph_failed = False
        if not self.config.graph.enabled:
            return
        # the graph built with the Mapper takes the checkpoint's state (its models are loaded once)
        if self._graph is None or self._graph.num_updates or self._graph.nodes:
            self._graph = self._new_graph()
        if graph_state is None:
            return
        try:
            self._graph.load_state(json.loads(str(graph_state)), source=f"{p} (graph_state)")
        except Exception as e:  # noqa: BLE001 - the graph is optional: the map resumes without it
            log.warning(
                "scene graph not restored (%s: %s): the next update builds it anew", type(e).__name__, e
            )
            self._graph = self._new_graph()

    def _load_tracker_state(self, tracker_state: dict[str, np.ndarray], p: Path) -> None:
        self._tracker = None
        if self.config.tracking.poses != "odometry":
            return
        if tracker_state:
            try:
                self._get_tracker().load_state(tracker_state)
            except (ValueError, OGSceneError) as e:
                raise DataError(f"{p}: cannot restore the tracker: {e}") from e
        elif self.frames_seen:
            log.warning(
                "%s holds no tracker state (written with dataset poses, or by an older version): "
                "odometry restarts at the next frame's own pose, or the identity where it has none",
                p,
            )

    def save(self, out_dir: str | Path) -> Path:
        """Write the run directory: config.yaml and map.npz (with its memory views in map_memory/) first,
        which is what a resume needs, then the exports: gaussians.ply, timings.json, under odometry traj.txt
        (the tracked poses, one row-major c2w 4x4 per frame read) and graph.json. A save cut short (a full
        disk) thus leaves a map that ``run --resume`` writes the exports from. Saved outside a run that
        records its id (``source["run_id"]``), an earlier run's ``run_id`` file there is removed. The run
        folder's files and their order are :func:`ogscene3d.runs.save_run`'s.

        Raises:
            SaveError: a write failed; it names the file and those written before it.
        """
        return save_run(
            out_dir,
            config=self.config,
            checkpoint=self.save_checkpoint,
            gaussians=self.map.export_ply,
            timings=self._timings_doc,
            trajectory=self._trajectory_text,
            graph=self._graph_doc,
            keeps_run_id="run_id" in self.source,
        )

    def _timings_doc(self) -> dict:
        timings = self.timings.as_dict()
        timings["device"] = str(self.device)
        timings["ablation"] = self.cfg.ablation
        timings["finalized"] = self.finalized  # False: the map of a stopped run, which --resume goes on from
        return timings

    def _trajectory_text(self) -> str | None:
        from ..tracking import hold_last_good, trajectory_text

        filled = hold_last_good(self.trajectory)  # as `ogscene3d track` writes it: one pose per frame read
        return trajectory_text(filled) if filled else None

    def _graph_doc(self) -> dict:
        graph = None
        if self._graph is not None and not self._graph_failed:
            try:
                graph = self._graph.to_dict()
            except Exception as e:  # noqa: BLE001
                log.warning("could not serialise the scene graph: %s: %s", type(e).__name__, e)
        if graph is None:
            graph = {"version": 1, "nodes": self._label_nodes(), "edges": []}
        return graph

    def _label_nodes(self) -> list[dict]:
        """Graph nodes straight from the map's labels (used when no scene graph was built)."""
        gm = self.map
        lab = gm.labels
        if not bool((lab >= 0).any()):
            return []
        ids, inv, cnt = torch.unique(lab[lab >= 0], return_inverse=True, return_counts=True)
        pts = gm.means[lab >= 0]
        conf = gm.confidences[lab >= 0]
        n = ids.numel()
        center = torch.zeros(n, 3, device=gm.device).index_add_(0, inv, pts) / cnt[:, None]
        mean_conf = torch.zeros(n, device=gm.device).index_add_(0, inv, conf) / cnt
        lo = torch.full((n, 3), float("inf"), device=gm.device).scatter_reduce(
            0, inv[:, None].expand(-1, 3), pts, reduce="amin"
        )
        hi = torch.full((n, 3), float("-inf"), device=gm.device).scatter_reduce(
            0, inv[:, None].expand(-1, 3), pts, reduce="amax"
        )
        first = torch.full((n,), 2**30, dtype=torch.int64, device=gm.device).scatter_reduce(
            0, inv, gm.origin_kf[lab >= 0].long(), reduce="amin"
        )
        return [
            {
                "id": int(ids[i]),
                "label": int(ids[i]),
                "caption": "",
                "tag": "",
                "confidence": float(mean_conf[i]),
                "center": center[i].tolist(),
                "bbox_min": lo[i].tolist(),
                "bbox_max": hi[i].tolist(),
                "num_gaussians": int(cnt[i]),
                "first_seen": int(first[i]),
                "last_updated": self.keyframe_count - 1,
            }
            for i in range(n)
        ]


def _default_segmenter(config: Config, K: np.ndarray):
    """The live segmenter for frames that carry no precomputed segments (None: map geometry only)."""
    from ..segmentation import make_segmenter

    backend = config.segmentation.backend
    if backend == "none":
        return None
    if backend == "precomputed":
        log.warning("frames carry no precomputed segments: falling back to the classical segmenter")
        return make_segmenter(replace(config.segmentation, backend="classical"), K)
    return make_segmenter(config.segmentation, K)
