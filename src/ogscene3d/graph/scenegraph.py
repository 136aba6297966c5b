"""The progressive 3D scene graph of paper Sec. III-D.

Interface for the mapper (it needs nothing else from this package)::

    graph = SceneGraph(config.graph, out_path=run_dir / "graph.json")
    for every keyframe k (0-based keyframe counter):
        graph.observe(k, frame, label_map)            # label_map: int32 [H, W] scene labels, -1 = none
        if graph.is_due(k):                            # cheap; lets the mapper skip the GPU->CPU copy
            graph.update(k, means, labels, confidences, colors)
    graph.finalize(k_last, means, labels, confidences, colors)   # last update of pending nodes, save
    graph.save(run_dir / "graph.json")

``update`` follows the paper's schedule: the graph is initialised once ``init_keyframes`` keyframes have
been seen (every node captioned, scored and connected); after that, every ``update_every`` keyframes,
only the nodes with C_i < ``tau_update`` and the new nodes are re-captioned and re-scored, and only
their edges are re-evaluated (Eqs. 20-21 against all nodes). With a captioner other than the heuristic
one, nodes that still carry a heuristic caption (its request failed, was skipped, or it had nothing to go
on) are asked for again at every update and at ``finalize``. Node geometry (centre, bounds, thinned
point set) is refreshed for all nodes at every update; nodes whose label vanished from the map (merged by
global refinement) are removed with their edges.

Edge candidates are the pairs with R_ij > tau_e (Eqs. 20-21, computed on each node's points thinned to one
per theta_e/2 voxel) and, unless ``graph.support_edges`` is false, pairs where one node's bottom or top
band rests against the other (an extension: R_ij misses a sofa on a floor because it normalises by the
whole node). Relations come from the configured :class:`RelationPredictor`.

Robustness: exceptions raised by the captioner, the relation predictor, the confidence model or the
writing of graph.json are logged and never propagate to the mapper; with ``graph.background: true`` the
update runs on a worker thread (a due update is deferred while the previous one still runs).
"""

from __future__ import annotations

import json
import logging
import math
import re
import threading
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_path
from ..config import GraphConfig
from ..errors import ConfigError, DataError, OGSceneError
from ..frame import Frame
from ..runs import RunFolder
from ..runs.graph_json import read_graph_json, write_graph_json
from ..up_axis import unit_up, up_vector
from .captioner import Captioner, GroundTruthCaptioner, HeuristicCaptioner, build_captioner
from .confidence import MeanConfidence, NodeConfidence, build_confidence
from .geometry import directed_ratios, proximate_points
from .query import LLMQuery, QueryAnswer, QueryContext, QueryHit, answer_offline
from .relations import GeometricRelations, RelationPredictor, build_relations
from .rooms import Floor, RoomMap, RoomNode, build_room_typer
from .terms import SYNONYM_GROUPS, text_score

__all__ = ["SYNONYM_GROUPS", "SceneGraph"]  # SYNONYM_GROUPS: the offline synonyms, from .terms
from .confidence import ClipConfidence
from .openai_client import ChatClient
from .types import (
    OFFLINE_SOURCES,
    VLM_CAPTION_SOURCES,
    CaptionRequest,
    ObservationSet,
    SceneContext,
    SceneEdge,
    SceneNode,
    node_geometry,
)

log = logging.getLogger(__name__)

GRAPH_JSON_VERSION = 1


def _to_numpy(x: Any, name: str) -> np.ndarray:
    if hasattr(x, "detach"):  # torch tensor, on any device
        x = x.detach().cpu().numpy()
    return np.array(x, copy=True)


def _label_regions(
    lm: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The labelled regions of a label map ``lm`` [H, W] (-1: none): the labelled pixels (flat indices),
    the labels present (sorted), each labelled pixel's index into them, each label's area in pixels and its
    bounding box [L, 4] (y0, y1, x0, x1; ends exclusive). None when no pixel is labelled."""
    H, W = lm.shape
    flat = lm.reshape(-1)
    pix = np.nonzero(flat >= 0)[0]
    if len(pix) == 0:
        return None
    vals = flat[pix].astype(np.int64)
    top = int(vals.max())
    if top < 4 * len(flat) + 1024:  # labels small enough for counting (the usual case): no sort
        counts = np.bincount(vals, minlength=top + 1)
        labs = np.nonzero(counts)[0]
        area = counts[labs]
        lut = np.zeros(top + 1, np.int64)
        lut[labs] = np.arange(len(labs))
        inv = lut[vals]
    else:
        labs, inv, area = np.unique(vals, return_inverse=True, return_counts=True)
    ys, xs = np.divmod(pix, W)
    # Bounding boxes from per-(label, row) and per-(label, column) occupancy: two bincounts.
    L = len(labs)
    rows = np.bincount(inv * H + ys, minlength=L * H).reshape(L, H) > 0
    cols = np.bincount(inv * W + xs, minlength=L * W).reshape(L, W) > 0
    r0, r1 = rows.argmax(axis=1), H - rows[:, ::-1].argmax(axis=1)
    c0, c1 = cols.argmax(axis=1), W - cols[:, ::-1].argmax(axis=1)
    return pix, labs, inv, area, np.stack([r0, r1, c0, c1], axis=1)


class SceneGraph:
    """Nodes (one per scene label with at least ``min_gaussians`` Gaussians) and directed relation edges.

    Thread-safe: ``observe`` may run while a background update is in flight.

    Args:
        config: the ``graph`` section (its defaults when None).
        captioner: node captions; None: what ``graph.captioner.kind`` selects.
        relations: edge relations; None: what ``graph.relations.kind`` selects.
        node_confidence: node confidence; None: what ``graph.confidence.kind`` selects.
        out_path: graph.json, rewritten (atomically) after every update; None: not written.
        label_names: scene label -> name, for the ground-truth captioner.
        class_names: class id -> name, for the ground-truth captioner.

    Raises:
        ConfigError: settings of ``config`` out of their rules.
    """

    def __init__(
        self,
        config: GraphConfig | None = None,
        captioner: Captioner | None = None,
        relations: RelationPredictor | None = None,
        node_confidence: NodeConfidence | None = None,
        out_path: str | Path | None = None,
        label_names: Mapping[int, str] | None = None,
        class_names: Mapping[int, str] | None = None,
    ) -> None:
        self.config = config or GraphConfig()
        c = self.config
        try:
            # graph.up_axis auto: provisional until the mapper chooses it (set_up_axis) from the cameras
            self.up = unit_up(up_vector(c.up_axis))
        except ValueError as e:
            raise ConfigError(str(e)) from None
        for key in (
            "init_keyframes",
            "update_every",
            "min_gaussians",
            "max_points_per_node",
            "max_masked_views",
            "crop_max_side",
        ):
            if getattr(c, key) < 1:
                raise ConfigError(f"graph.{key} must be >= 1, got {getattr(c, key)}")
        if not c.theta_e > 0 or not 0 <= c.tau_e < 1 or c.context_pad < 0 or c.edge_voxel < 0:
            raise ConfigError(
                f"graph: need theta_e > 0, 0 <= tau_e < 1, context_pad >= 0, edge_voxel >= 0 (got "
                f"{c.theta_e}, {c.tau_e}, {c.context_pad}, {c.edge_voxel})"
            )
        if not c.support_band > 0 or not 0 < c.support_ratio <= 1:
            raise ConfigError(
                f"graph: need support_band > 0 and 0 < support_ratio <= 1 "
                f"(got {c.support_band}, {c.support_ratio})"
            )
        self.captioner: Captioner = captioner or build_captioner(
            c.captioner, label_names, class_names, c.endpoint
        )
        self.relations: RelationPredictor = relations or build_relations(c.relations, self.up, c.endpoint)
        self.node_confidence: NodeConfidence = node_confidence or build_confidence(c.confidence)
        self._fallback_captioner = HeuristicCaptioner()
        self._fallback_relations = GeometricRelations(c.relations, self.up)
        self.out_path = Path(out_path) if out_path is not None else None

        self.nodes: dict[int, SceneNode] = {}
        self.edges: dict[tuple[int, int], SceneEdge] = {}  # key: (min id, max id), one relation per pair
        self._obs: dict[int, ObservationSet] = {}
        self._gt_class_votes: dict[int, dict[int, int]] = {}
        self._name_votes: dict[int, dict[str, int]] = {}
        self._label_pixels: dict[
            int, int
        ] = {}  # label -> its pixels in the observed keyframes (all named or not)
        self._gt_instance_votes: dict[int, dict[int, int]] = {}
        self._lock = threading.RLock()
        self._initialized = False
        self._last_update_count = 0  # keyframe count at the last update
        self.num_updates = 0
        self.last_update_keyframe = -1
        self.timings: dict[str, dict[str, float]] = {}
        self._executor: ThreadPoolExecutor | None = None
        self._future: Future | None = None
        self._embed_cache: dict[str, np.ndarray] = {}
        self._query_encoder: Any = None
        # storeys and rooms (graph.rooms), updated with the graph and every rooms.update_every keyframes
        self.room_map: RoomMap | None = (
            RoomMap(c.rooms, build_room_typer(c.rooms, c.endpoint)) if c.rooms.enabled else None
        )
        self._last_rooms_count = 0
        self._keyframe_frames: dict[int, int] = {}  # keyframe index -> its dataset frame index
        self._llm_query: LLMQuery | None = (
            LLMQuery.from_config(c.query, c.endpoint) if c.query.kind == "llm" else None
        )

    def set_up_axis(self, up: Sequence[float]) -> None:
        """Set the world up direction (``graph.up_axis`` auto, chosen by the mapper from the cameras at its
        first update): the graph's, its config's and its relation predictors'."""
        with self._lock:
            self.up = unit_up(up)
            self.config.up_axis = [float(v) for v in self.up]
            for r in (self.relations, getattr(self.relations, "fallback", None), self._fallback_relations):
                if r is not None and hasattr(r, "up"):
                    r.up = self.up

    # ----------------------------------------------------------------------------------------- observe

    def observe(
        self,
        keyframe_index: int,
        frame: Frame,
        label_map: np.ndarray,
        name_votes: Mapping[int, Mapping[str, int]] | None = None,
    ) -> None:
        """Record the keyframe's views of every labelled region into the observation sets O_i.

        ``label_map``: int [H, W] scene labels of the keyframe (e.g. the rendered semantic labels or the
        segments mapped to scene labels), -1 where none; H, W as ``frame.rgb``. Crops (context crop with
        ``context_pad`` margin, masked view with everything but the region blacked out) are made only when
        they enter O_i, downscaled to ``crop_max_side``. With ground-truth maps in ``frame``
        (synthetic scenes), the overlap votes label -> GT class / instance are accumulated too.
        ``name_votes``: {label: {detector class name: pixels}} of this keyframe, accumulated for the offline
        captions (a node then takes its majority name as tag).
        """
        if not self.config.enabled:
            return
        with self._lock:
            self._keyframe_frames[int(keyframe_index)] = int(frame.index)
            for lab, d in (name_votes or {}).items():
                acc = self._name_votes.setdefault(int(lab), {})
                for name, n in d.items():
                    acc[str(name)] = acc.get(str(name), 0) + int(n)
        lm = np.asarray(label_map)
        H, W = frame.rgb.shape[:2]
        if lm.shape != (H, W):
            raise ValueError(
                f"SceneGraph.observe: label_map shape {lm.shape} differs from the frame's {(H, W)}"
            )
        if not np.issubdtype(lm.dtype, np.integer):
            raise ValueError(f"SceneGraph.observe: label_map must be an integer array, got {lm.dtype}")
        t0 = time.perf_counter()
        regions = _label_regions(lm)
        if regions is None:
            return
        pix, labs, inv, area, boxes = regions
        with self._lock:
            for lab, a in zip(labs.tolist(), area.tolist()):
                self._label_pixels[lab] = self._label_pixels.get(lab, 0) + a
            self._add_views(keyframe_index, frame, lm, labs, area, boxes)
            self._add_gt_votes(frame, pix, labs, inv)
        self._time("observe", time.perf_counter() - t0)

    def _add_views(
        self,
        keyframe_index: int,
        frame: Frame,
        lm: np.ndarray,
        labs: np.ndarray,
        area: np.ndarray,
        boxes: np.ndarray,
    ) -> None:
        """Put the keyframe's context crop and masked view of each region large enough into its
        observation set, where the set wants them. Call with the lock held."""
        c = self.config
        H, W = lm.shape
        for k in np.nonzero(area >= c.min_obs_pixels)[0]:
            lab, a = int(labs[k]), int(area[k])
            obs = self._obs.setdefault(lab, ObservationSet())
            want_ctx, want_mask = obs.wants(keyframe_index, a, c.max_masked_views)
            if not (want_ctx or want_mask):
                continue
            y0, y1, x0, x1 = (int(v) for v in boxes[k])
            ctx = masked = None
            if want_ctx:
                py, px = round(c.context_pad * (y1 - y0)), round(c.context_pad * (x1 - x0))
                ctx = self._downscale(
                    frame.rgb[max(0, y0 - py) : min(H, y1 + py), max(0, x0 - px) : min(W, x1 + px)]
                )
            if want_mask:
                sub = frame.rgb[y0:y1, x0:x1].copy()
                sub[lm[y0:y1, x0:x1] != lab] = 0
                masked = self._downscale(sub)
            obs.add(keyframe_index, a, ctx, masked, c.max_masked_views)

    def _add_gt_votes(self, frame: Frame, pix: np.ndarray, labs: np.ndarray, inv: np.ndarray) -> None:
        """Accumulate the overlap votes label -> GT class / instance of a frame with ground-truth maps
        (synthetic scenes). Call with the lock held."""
        H, W = frame.rgb.shape[:2]
        for gt, votes in (
            (frame.gt_classes, self._gt_class_votes),
            (frame.gt_instances, self._gt_instance_votes),
        ):
            if gt is None or gt.shape != (H, W):
                continue
            g = np.asarray(gt).reshape(-1)[pix].astype(np.int64)
            ok = g >= 0
            if not ok.any():
                continue
            gmax = int(g[ok].max()) + 1
            codes, counts = np.unique(inv[ok].astype(np.int64) * gmax + g[ok], return_counts=True)
            for code, n in zip(codes.tolist(), counts.tolist()):
                li, gi = divmod(code, gmax)
                d = votes.setdefault(int(labs[li]), {})
                d[gi] = d.get(gi, 0) + n

    def _downscale(self, img: np.ndarray) -> np.ndarray:
        import cv2

        h, w = img.shape[:2]
        s = self.config.crop_max_side / max(h, w)
        if s >= 1.0:
            return np.ascontiguousarray(img)
        return cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)

    def observations(self, node_id: int) -> ObservationSet:
        """A copy of O_i for ``node_id`` (empty when never observed)."""
        with self._lock:
            obs = self._obs.get(int(node_id))
            return obs.copy() if obs is not None else ObservationSet()

    def majority_gt(self, kind: str = "class") -> dict[int, int]:
        """Scene label -> ground-truth class (``kind="class"``) or instance id with the largest pixel overlap
        seen in :meth:`observe` (synthetic scenes; evaluation only)."""
        votes = {"class": self._gt_class_votes, "instance": self._gt_instance_votes}.get(kind)
        if votes is None:
            raise ValueError(f"majority_gt: kind must be 'class' or 'instance', got {kind!r}")
        with self._lock:
            return {lab: max(v.items(), key=lambda kv: (kv[1], -kv[0]))[0] for lab, v in votes.items() if v}

    # ------------------------------------------------------------------------------------------ update

    def is_due(self, keyframe_index: int) -> bool:
        """Whether :meth:`update` at 0-based keyframe ``keyframe_index`` would run: a graph update (paper
        schedule) or a room update (every ``graph.rooms.update_every`` keyframes)."""
        return self._graph_due(keyframe_index) or self._rooms_due(keyframe_index)

    def _graph_due(self, keyframe_index: int) -> bool:
        if not self.config.enabled:
            return False
        count = keyframe_index + 1
        if not self._initialized:
            return count >= self.config.init_keyframes
        return count - self._last_update_count >= self.config.update_every

    def _rooms_due(self, keyframe_index: int) -> bool:
        if not self.config.enabled or self.room_map is None:
            return False
        return keyframe_index + 1 - self._last_rooms_count >= self.config.rooms.update_every

    def update(
        self,
        keyframe_index: int,
        means: np.ndarray,
        labels: np.ndarray,
        confidences: np.ndarray,
        colors: np.ndarray | None = None,
        force: bool = False,
    ) -> bool:
        """Run a graph update if due (or ``force``): returns whether one ran (or was started in background).

        ``means`` [N,3] float world metres, ``labels`` [N] int scene labels (-1 unlabeled), ``confidences``
        [N] float in [0, 1], ``colors`` [N,3] float RGB in [0, 1] (None: grey). numpy arrays or torch
        tensors (copied). Gaussians with non-finite means are ignored. Shape mismatches raise ValueError
        (a caller bug); failures inside the update are logged and never raised.
        """
        if not self.config.enabled:
            return False
        if not (force or self._graph_due(keyframe_index)):
            return self._rooms_only(keyframe_index, means) if self._rooms_due(keyframe_index) else False
        arrays = self._check_arrays(means, labels, confidences, colors)
        if self.config.background:
            if self._future is not None and not self._future.done():
                log.info(
                    "scene graph: previous update still running; deferring the one due at keyframe %d",
                    keyframe_index,
                )
                return False
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="scenegraph")
            self._last_update_count = keyframe_index + 1
            self._future = self._executor.submit(self._safe_update, keyframe_index, *arrays)
            return True
        self._last_update_count = keyframe_index + 1
        return self._safe_update(keyframe_index, *arrays)

    def _rooms_only(self, kf: int, means) -> bool:
        """A room update between graph updates (on the worker thread with ``background``)."""
        m = _to_numpy(means, "means").astype(np.float64)
        if m.ndim != 2 or m.shape[1] != 3:
            raise ValueError(f"SceneGraph.update: means must be [N, 3], got {m.shape}")
        self._last_rooms_count = kf + 1
        if self.config.background:
            if self._future is not None and not self._future.done():
                return False
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="scenegraph")
            self._future = self._executor.submit(self._safe_rooms, kf, m, True)
            return True
        return self._safe_rooms(kf, m, True)

    def _safe_rooms(self, kf: int, means: np.ndarray, save: bool) -> bool:
        try:
            self._update_rooms(kf, means, ask_model=False)
        except Exception:
            log.exception("room update at keyframe %d failed; mapping continues", kf)
            return False
        if save and self.out_path is not None:
            try:
                self.save(self.out_path)
            except Exception as e:
                log.warning("scene graph: could not write %s (%s)", self.out_path, e)
        return True

    def _update_rooms(self, kf: int, means: np.ndarray, ask_model: bool = True) -> None:
        """Segment the rooms anew from all Gaussian means and put the object nodes in them (``ask_model``:
        an LLM room typer is asked, at graph updates only)."""
        if self.room_map is None:
            return
        t0 = time.perf_counter()
        with self._lock:
            objects = {
                i: (n.points if len(n.points) else n.center[None], n.tag, n.num_gaussians)
                for i, n in self.nodes.items()
            }
        self.room_map.update(kf, means, self.up, objects, self._keyframe_frames.get(kf, -1), ask_model)
        with self._lock:
            for i, n in self.nodes.items():
                n.room = self.room_map.object_room.get(i)
        self._time("graph_rooms", time.perf_counter() - t0)

    @property
    def rooms(self) -> dict[int, RoomNode]:
        """The room nodes by id (empty when ``graph.rooms.enabled`` is false or none was found yet)."""
        return self.room_map.rooms if self.room_map is not None else {}

    @property
    def floors(self) -> list[Floor]:
        """The storeys found so far (lowest first)."""
        return self.room_map.floors if self.room_map is not None else []

    def wait(self, timeout: float | None = None) -> None:
        """Block until a background update (if any) has finished."""
        fut = self._future
        if fut is not None:
            fut.result(timeout=timeout)

    def finalize(
        self,
        keyframe_index: int,
        means: np.ndarray,
        labels: np.ndarray,
        confidences: np.ndarray,
        colors: np.ndarray | None = None,
    ) -> bool:
        """End of the run: wait for a background update, then run one last update (in this thread) for new
        and low-confidence nodes, and write graph.json if ``out_path`` is set."""
        if not self.config.enabled:
            return False
        self.wait()
        arrays = self._check_arrays(means, labels, confidences, colors)
        self._last_update_count = keyframe_index + 1
        ok = self._safe_update(keyframe_index, *arrays)
        self.close()
        self._log_caption_summary()
        return ok

    def _log_caption_summary(self) -> None:
        """How many nodes the VLM captioned in the end (the rest have fallback captions)."""
        if isinstance(self.captioner, HeuristicCaptioner | GroundTruthCaptioner) or not self.nodes:
            return
        st = self.stats()
        n, k = st["nodes"], st["vlm_captioned"]
        prose = st["caption_sources"].get("vlm-text", 0)
        log.log(
            logging.WARNING if k == 0 else logging.INFO,
            "scene graph: %d of %d nodes captioned by the VLM%s; %d keep an offline caption",
            k,
            n,
            f" ({prose} from replies that were not JSON)" if prose else "",
            sum(st["caption_sources"].get(s, 0) for s in OFFLINE_SOURCES),
        )

    def close(self) -> None:
        """Stop the background worker (waits for a running update)."""
        if self._executor is not None:
            self._executor.shutdown(wait=True)
            self._executor = None

    @staticmethod
    def _check_arrays(means, labels, confidences, colors) -> tuple[np.ndarray, ...]:
        m = _to_numpy(means, "means").astype(np.float64)
        lab = _to_numpy(labels, "labels")
        conf = _to_numpy(confidences, "confidences").astype(np.float64)
        if m.ndim != 2 or m.shape[1] != 3:
            raise ValueError(f"SceneGraph.update: means must be [N, 3], got {m.shape}")
        n = len(m)
        if lab.shape != (n,) or not np.issubdtype(lab.dtype, np.integer):
            raise ValueError(f"SceneGraph.update: labels must be integer [{n}], got {lab.dtype} {lab.shape}")
        if conf.shape != (n,):
            raise ValueError(f"SceneGraph.update: confidences must be [{n}], got {conf.shape}")
        if colors is None:
            col = np.full((n, 3), 0.5)
        else:
            col = _to_numpy(colors, "colors").astype(np.float64)
            if col.shape != (n, 3):
                raise ValueError(f"SceneGraph.update: colors must be [{n}, 3], got {col.shape}")
        return m, lab.astype(np.int64), conf, col

    def _safe_update(self, kf: int, means, labels, confs, colors) -> bool:
        try:
            self._update(kf, means, labels, confs, colors)
            return True
        except Exception:
            log.exception("scene graph update at keyframe %d failed; mapping continues", kf)
            return False

    def _time(self, key: str, seconds: float, count: int = 1) -> None:
        t = self.timings.setdefault(key, {"seconds": 0.0, "count": 0})
        t["seconds"] += seconds
        t["count"] += count

    def _geometry(self, kf: int, means, labels, confs, colors) -> dict[int, dict]:
        finite = np.all(np.isfinite(means), axis=1)
        if not finite.all():
            log.warning("scene graph: ignoring %d Gaussians with non-finite means", int((~finite).sum()))
        sel = np.nonzero(finite & (labels >= 0))[0]
        order = sel[np.argsort(labels[sel], kind="stable")]
        ulab, starts, counts = np.unique(labels[order], return_index=True, return_counts=True)
        cap = self.config.max_points_per_node
        voxel = self.config.edge_voxel if self.config.edge_voxel > 0 else self.config.theta_e / 2
        out: dict[int, dict] = {}
        for lab, s, n in zip(ulab.tolist(), starts.tolist(), counts.tolist()):
            if n < self.config.min_gaussians:
                continue
            idx = order[s : s + n]
            out[lab] = node_geometry(lab, means[idx], colors[idx], confs[idx], cap, voxel)
        return out

    def _update(self, kf: int, means, labels, confs, colors) -> None:
        t_start = time.perf_counter()
        geo = self._geometry(kf, means, labels, confs, colors)
        with self._lock:
            new = self._merge_geometry(kf, geo)
            requests, retry, ctx = self._caption_requests(new)
        self._time("graph_geometry", time.perf_counter() - t_start)

        t0 = time.perf_counter()
        self._caption(kf, requests, ctx)
        self._time("graph_caption", time.perf_counter() - t0, len(requests))

        t0 = time.perf_counter()
        self._score_confidence(requests)
        self._time("graph_confidence", time.perf_counter() - t0, len(requests))

        t0 = time.perf_counter()
        self._update_edges([r.node.id for r in requests])
        self._time("graph_edges", time.perf_counter() - t0)
        if self.room_map is not None:
            self._last_rooms_count = kf + 1
            try:
                self._update_rooms(kf, means)
            except Exception:
                log.exception("room update at keyframe %d failed; the graph keeps its previous rooms", kf)

        self._initialized = True
        self.num_updates += 1
        self.last_update_keyframe = kf
        log.info(
            "scene graph update at keyframe %d: %d nodes (%d new, %d re-captioned%s), %d edges, %.2f s",
            kf,
            len(self.nodes),
            len(new),
            len(requests) - len(new),
            f", {len(retry)} of them after a fallback caption" if retry else "",
            len(self.edges),
            time.perf_counter() - t_start,
        )
        if self.out_path is not None:
            try:
                self.save(self.out_path)
            except Exception as e:
                log.warning("scene graph: could not write %s (%s)", self.out_path, e)

    def _merge_geometry(self, kf: int, geo: dict[int, dict]) -> list[int]:
        """Nodes from this update's geometry: those whose label left the map go (with their edges), the
        others are made or updated. -> the new node ids. Call with the lock held."""
        gone = [i for i in self.nodes if i not in geo]
        for i in gone:
            del self.nodes[i]
        if gone:
            self.edges = {k: e for k, e in self.edges.items() if k[0] in self.nodes and k[1] in self.nodes}
            log.info("scene graph: %d node(s) left the map: %s", len(gone), gone[:10])
        new = []
        for lab, g in geo.items():
            node = self.nodes.get(lab)
            if node is None:
                self.nodes[lab] = SceneNode(id=lab, first_seen=kf, last_updated=kf, **g)
                new.append(lab)
            else:
                for k, v in g.items():
                    setattr(node, k, v)
                node._shape = None
        return new

    def _caption_requests(self, new: list[int]) -> tuple[list[CaptionRequest], set[int], SceneContext]:
        """The nodes to describe at this update (all at the first; then the new ones, those under
        tau_update and those awaiting a real caption) as caption requests, the ones awaiting a caption, and
        the scene context. Call with the lock held."""
        retry: set[int] = set()
        if not self._initialized:
            todo = sorted(self.nodes)
        else:
            low = [i for i, n in self.nodes.items() if n.confidence < self.config.tau_update and i not in new]
            retry = self._awaiting_caption() - set(new) - set(low)
            todo = sorted(set(new) | set(low) | retry)
        ctx = self._scene_context()
        requests = [
            CaptionRequest(
                node=self.nodes[i],
                observations=self._obs[i].copy() if i in self._obs else ObservationSet(),
                context=ctx,
                gt_class_votes=dict(self._gt_class_votes.get(i, {})),
                gt_instance_votes=dict(self._gt_instance_votes.get(i, {})),
                detector_name_votes=dict(self._name_votes.get(i, {})),
                label_pixels=self._label_pixels.get(i, 0),
            )
            for i in todo
        ]
        return requests, retry, ctx

    def _caption(self, kf: int, requests: list[CaptionRequest], ctx: SceneContext) -> None:
        """Describe the requested nodes (slow, possibly remote: outside the lock); nodes left without an
        answer get (or refresh) the heuristic caption, and every heuristic caption follows its geometry."""
        try:
            descs = self.captioner.describe(requests) if requests else {}
        except Exception as e:
            log.warning("scene graph: captioner failed (%s); nodes keep their previous captions", e)
            descs = {}
        # Nodes left without an answer get (or refresh) the heuristic caption; a real caption is kept.
        need = [
            r
            for r in requests
            if r.node.id not in descs and (not r.node.caption or r.node.caption_source in OFFLINE_SOURCES)
        ]
        if need:
            descs.update(self._fallback_captioner.describe(need))
        with self._lock:
            for r in requests:
                d = descs.get(r.node.id)
                if d is not None:
                    r.node.caption, r.node.tag, r.node.caption_source = d.caption, d.tag, d.source
                r.node.last_updated = kf
            # Heuristic captions cost nothing and describe geometry that keeps growing, so they follow it
            # at every update (the selective schedule exists to save VLM calls, not to freeze captions).
            done = {r.node.id for r in requests}
            stale = [
                n for i, n in self.nodes.items() if n.caption_source in OFFLINE_SOURCES and i not in done
            ]
            if stale:
                fresh = self._fallback_captioner.describe(
                    [
                        CaptionRequest(
                            n,
                            ObservationSet(),
                            ctx,
                            detector_name_votes=dict(self._name_votes.get(n.id, {})),
                            label_pixels=self._label_pixels.get(n.id, 0),
                        )
                        for n in stale
                    ]
                )
                for n in stale:
                    d = fresh[n.id]
                    n.caption, n.tag, n.caption_source = d.caption, d.tag, d.source

    def _score_confidence(self, requests: list[CaptionRequest]) -> None:
        """The node confidence of the described nodes (the mean Gaussian confidence when the scorer fails)."""
        try:
            scores = self.node_confidence.score(requests) if requests else {}
        except Exception as e:
            log.warning("scene graph: node confidence failed (%s); using mean Gaussian confidence", e)
            scores = MeanConfidence().score(requests)
        with self._lock:
            for r in requests:
                s = scores.get(r.node.id)
                if s is not None and math.isfinite(s):
                    r.node.confidence = float(s)

    def _awaiting_caption(self) -> set[int]:
        """Nodes whose heuristic caption stands in for the configured captioner's: its request failed or
        was skipped, or it had nothing to go on yet. Call with the lock held."""
        if isinstance(self.captioner, HeuristicCaptioner):
            return set()  # heuristic captions are final (and refreshed at every update anyway)
        return {i for i, n in self.nodes.items() if n.caption_source in OFFLINE_SOURCES}

    def _scene_context(self) -> SceneContext:
        if not self.nodes:
            return SceneContext(self.up, 0.0, 0.0)
        shapes = [n.shape(self.up) for n in self.nodes.values()]
        return SceneContext(self.up, min(s.h_lo for s in shapes), max(s.h_hi for s in shapes))

    def _edge_candidates(self, clouds: list[np.ndarray], query: list[int]) -> list[tuple[int, int, float]]:
        """Candidate pairs (a < b, indices into ``clouds``) with R_ab (paper Eq. 21): R_ab > tau_e, plus,
        with ``support_edges``, pairs where one node's bottom or top band (``support_band`` metres along
        up) has at least ``support_ratio`` of its points within theta_e of the other node."""
        c = self.config
        sizes = np.array([len(p) for p in clouds], dtype=np.int64)
        pt, other = proximate_points(clouds, c.theta_e, query=query)
        ratios: dict[tuple[int, int], float] = {}
        for (i, j), r in directed_ratios(pt, other, sizes).items():
            key = (min(i, j), max(i, j))
            ratios[key] = max(ratios.get(key, 0.0), r)
        chosen = {k for k, r in ratios.items() if r > c.tau_e}
        if c.support_edges and len(pt):
            h = np.concatenate(clouds) @ self.up
            owner = np.repeat(np.arange(len(clouds)), sizes)
            lo = np.full(len(clouds), np.inf)
            hi = np.full(len(clouds), -np.inf)
            np.minimum.at(lo, owner, h)
            np.maximum.at(hi, owner, h)
            for band in (h <= lo[owner] + c.support_band, h >= hi[owner] - c.support_band):
                for (i, j), r in directed_ratios(pt, other, sizes, band).items():
                    if r >= c.support_ratio:
                        chosen.add((min(i, j), max(i, j)))
        return sorted((a, b, ratios[(a, b)]) for a, b in chosen)

    def _update_edges(self, updated: Sequence[int]) -> None:
        with self._lock:
            ids = sorted(self.nodes)
            upd = set(updated) & set(ids)
            self.edges = {k: e for k, e in self.edges.items() if k[0] not in upd and k[1] not in upd}
            if not upd:
                return
            pos = {i: k for k, i in enumerate(ids)}
            clouds = [np.asarray(self.nodes[i].points, dtype=np.float64).reshape(-1, 3) for i in ids]
            cands = self._edge_candidates(clouds, [pos[i] for i in sorted(upd)])
            cands = [(ids[a], ids[b], r) for a, b, r in cands]
            pairs = [(self.nodes[a], self.nodes[b]) for a, b, _ in cands]
        if not pairs:
            return
        try:
            rels = self.relations.predict(pairs)
            if len(rels) != len(pairs):
                raise ValueError(f"relation predictor returned {len(rels)} relations for {len(pairs)} pairs")
        except Exception as e:
            log.warning("scene graph: relation predictor failed (%s); using geometric relations", e)
            rels = self._fallback_relations.predict(pairs)
        with self._lock:
            for (a, b, r), rel in zip(cands, rels):
                if a in self.nodes and b in self.nodes and {rel.source, rel.target} == {a, b}:
                    self.edges[(a, b)] = SceneEdge(
                        rel.source, rel.target, rel.relation, float(r), rel.predictor
                    )

    # ------------------------------------------------------------------------------------------ output

    def to_json(self) -> dict:
        """The graph.json document (docs/formats.md): version, nodes sorted by id, edges, :meth:`stats`
        (derived from the nodes; readers may ignore it), the world ``up`` vector and, with rooms on, the
        ``floors`` and ``rooms`` (nodes name their room in ``room``)."""
        with self._lock:
            doc = {
                "version": GRAPH_JSON_VERSION,
                "nodes": [self.nodes[i].to_dict() for i in sorted(self.nodes)],
                "edges": [self.edges[k].to_dict() for k in sorted(self.edges)],
                "stats": self.stats(),
            }
            doc["up"] = [float(v) for v in self.up]  # the vertical that rooms and relations used
            if self.room_map is not None:
                doc.update(self.room_map.to_dict())
            return doc

    def stats(self) -> dict:
        """Counts: ``nodes``, ``edges``, ``rooms``, ``vlm_captioned`` (nodes whose caption came from a VLM,
        prose replies included) and ``caption_sources`` (nodes per ``caption_source``; "" = no caption)."""
        with self._lock:
            sources: dict[str, int] = {}
            for n in self.nodes.values():
                sources[n.caption_source] = sources.get(n.caption_source, 0) + 1
            return {
                "nodes": len(self.nodes),
                "edges": len(self.edges),
                "rooms": len(self.rooms),
                "vlm_captioned": sum(v for k, v in sources.items() if k in VLM_CAPTION_SOURCES),
                "caption_sources": dict(sorted(sources.items())),
            }

    def to_dict(self) -> dict:
        """Alias of :meth:`to_json` (the graph.json document as a dict)."""
        return self.to_json()

    def save(self, path: str | Path) -> None:
        """Write graph.json atomically (never a half-written file)."""
        write_graph_json(path, self.to_json())

    @classmethod
    def load(cls, path: str | Path, config: GraphConfig | None = None) -> SceneGraph:
        """Read a graph.json, or the one in a run directory (for queries and export). Node point subsamples
        and observations are not stored in the file, so geometric predicates on a loaded graph use node
        centres only."""
        p = Path(path)
        if p.is_dir():
            if not RunFolder(p).graph.is_file():
                raise DataError(f"run directory {str(p)!r} has no graph.json (did the run finish?)")
            p = RunFolder(p).graph
        return cls.from_json(read_graph_json(p, centers=True), config, source=str(p))

    @classmethod
    def from_json(cls, doc: Any, config: GraphConfig | None = None, source: str = "graph.json") -> SceneGraph:
        """Build a graph from a graph.json document (see :meth:`load`); DataError naming ``source``."""
        cfg = config or GraphConfig()
        g = cls(
            cfg,
            captioner=HeuristicCaptioner(),
            relations=GeometricRelations(cfg.relations, up_vector(cfg.up_axis)),
            node_confidence=MeanConfidence(),
        )
        g._read_json(doc, source)
        return g

    def state(self) -> dict:
        """The graph, its update schedule and the detector name votes (they name nodes at every update),
        for a mapping checkpoint (``load_state`` resumes from it). Observations and ground-truth votes are
        not kept: after a resume they start from the next keyframe."""
        with self._lock:
            return {
                "graph": self.to_json(),
                "last_update_count": self._last_update_count,
                "last_update_keyframe": self.last_update_keyframe,
                "num_updates": self.num_updates,
                "last_rooms_count": self._last_rooms_count,
                "name_votes": {str(k): dict(v) for k, v in self._name_votes.items()},
                "label_pixels": {str(k): int(v) for k, v in self._label_pixels.items()},
            }

    def load_state(self, state: Any, source: str = "checkpoint") -> None:
        """Go on from ``state()``: its nodes (captions, confidences, first_seen), edges and schedule, with
        this graph's own captioner, relations and confidence; DataError naming ``source``."""
        if not isinstance(state, dict) or not isinstance(state.get("graph"), dict):
            raise DataError(f"{source}: not a scene graph state")
        try:
            schedule = [int(state[k]) for k in ("last_update_count", "last_update_keyframe", "num_updates")]
        except (KeyError, TypeError, ValueError) as e:
            raise DataError(f"{source}: scene graph state has no valid schedule ({e})") from None
        try:  # absent from checkpoints written before detector names reached the graph
            name_votes = {
                int(k): {str(n): int(c) for n, c in v.items()} for k, v in state.get("name_votes", {}).items()
            }
            label_pixels = {int(k): int(v) for k, v in state.get("label_pixels", {}).items()}
        except (AttributeError, TypeError, ValueError) as e:
            raise DataError(f"{source}: scene graph state has invalid name votes ({e})") from None
        with self._lock:
            self._name_votes = name_votes
            self._label_pixels = label_pixels
            self._read_json(state["graph"], source)
            self._last_update_count, self.last_update_keyframe, self.num_updates = schedule
            self._last_rooms_count = int(state.get("last_rooms_count", self._last_update_count))
            self._initialized = bool(self.num_updates)

    def _read_json(self, doc: Any, source: str) -> None:
        """Replace the nodes and edges by those of a graph.json document."""
        if not isinstance(doc, dict) or doc.get("version") != GRAPH_JSON_VERSION:
            raise DataError(f"{source}: not a version-{GRAPH_JSON_VERSION} scene graph document")
        if not isinstance(doc.get("nodes"), list) or not isinstance(doc.get("edges"), list):
            raise DataError(f"{source}: 'nodes' and 'edges' must be lists")

        def vec(d: dict, key: str, shape: tuple[int, ...], k: int, default: Any = None) -> np.ndarray:
            v = d.get(key, default)
            try:
                a = np.asarray(v, dtype=np.float64)
            except (TypeError, ValueError):
                a = np.zeros(0)
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise DataError(
                    f"{source}: node #{k} field {key!r} must be {len(shape)}-D finite numbers {shape}"
                )
            return a

        nodes: dict[int, SceneNode] = {}
        edges: dict[tuple[int, int], SceneEdge] = {}
        for k, d in enumerate(doc["nodes"]):
            if not isinstance(d, dict) or not isinstance(d.get("id"), int):
                raise DataError(f"{source}: node #{k} has no integer 'id'")
            center = vec(d, "center", (3,), k)
            node = SceneNode(
                id=d["id"],
                center=center,
                bbox_min=vec(d, "bbox_min", (3,), k),
                bbox_max=vec(d, "bbox_max", (3,), k),
                obb_center=vec(d, "obb_center", (3,), k, center.tolist()),
                obb_axes=vec(d, "obb_axes", (3, 3), k, np.eye(3).tolist()),
                obb_extent=vec(d, "obb_extent", (3,), k, [0.0, 0.0, 0.0]),
                num_gaussians=int(d.get("num_gaussians", 0)),
                first_seen=int(d.get("first_seen", -1)),
                last_updated=int(d.get("last_updated", -1)),
                caption=str(d.get("caption", "")),
                tag=str(d.get("tag", "")),
                caption_source=str(d.get("caption_source", "")),
                confidence=float(d.get("confidence", 0.0)),
                stored_extent=vec(d, "extent", (3,), k) if "extent" in d else None,
                room=int(d["room"]) if isinstance(d.get("room"), int) else None,
            )
            nodes[node.id] = node
        for k, e in enumerate(doc["edges"]):
            try:
                s, t, rel = int(e["source"]), int(e["target"]), str(e["relation"])
                score = float(e.get("score", 0.0))
            except (KeyError, TypeError, ValueError):
                raise DataError(
                    f"{source}: edge #{k} needs integer 'source'/'target' and a 'relation'"
                ) from None
            if s not in nodes or t not in nodes:
                raise DataError(f"{source}: edge #{k} refers to a node that is not in the graph ({s} -> {t})")
            edges[(min(s, t), max(s, t))] = SceneEdge(s, t, rel, score, str(e.get("predictor", "")))
        if self.room_map is not None:
            self.room_map.load(doc, source, self.up)
            for i, rid in self.room_map.object_room.items():  # the rooms' object lists say it too
                if i in nodes and nodes[i].room is None:
                    nodes[i].room = rid
        self.nodes, self.edges = nodes, edges
        self._initialized = True

    def to_networkx(self):
        """A ``networkx.DiGraph``: object nodes (ids = labels, ``kind`` "object", ``room``: their room id or
        -1) with attributes label, caption, tag, confidence, center_x/y/z, the
        axis-aligned box bbox_min_x/y/z and bbox_max_x/y/z, the oriented box obb_center_x/y/z,
        obb_extent_x/y/z (full side lengths) and obb_axes (its 3x3 rows, 9 numbers, as a JSON list),
        num_gaussians, first_seen, last_updated, caption_source; edge attributes relation, score,
        predictor. The hierarchy: room nodes ``room_<id>`` (``kind`` "room": type as tag and caption, area,
        floor, first_seen, centre and box, ``outline`` as JSON) and storeys ``floor_<id>`` (``kind`` "floor",
        height), with "in" edges object -> room -> floor. GraphML holds scalars only, hence one attribute per
        coordinate. networkx is optional (``pip install networkx``)."""
        try:
            import networkx as nx
        except ImportError:
            raise OGSceneError(
                "exporting the scene graph to networkx/GraphML needs networkx: pip install networkx"
            ) from None
        G = nx.DiGraph()
        with self._lock:
            for i in sorted(self.nodes):
                n = self.nodes[i]
                xyz = {
                    f"{name}_{axis}": float(getattr(n, name)[k])
                    for name in ("center", "bbox_min", "bbox_max", "obb_center", "obb_extent")
                    for k, axis in enumerate("xyz")
                }
                G.add_node(
                    int(i),
                    kind="object",
                    room=int(n.room) if n.room is not None else -1,
                    label=int(n.label),
                    caption=n.caption,
                    tag=n.tag,
                    confidence=float(n.confidence),
                    **xyz,
                    obb_axes=json.dumps([round(float(v), 6) for v in np.ravel(n.obb_axes)]),
                    num_gaussians=int(n.num_gaussians),
                    first_seen=int(n.first_seen),
                    last_updated=int(n.last_updated),
                    caption_source=n.caption_source,
                )
            for k in sorted(self.edges):
                e = self.edges[k]
                G.add_edge(
                    int(e.source),
                    int(e.target),
                    relation=e.relation,
                    score=float(e.score),
                    predictor=e.predictor,
                )
            self._hierarchy_to_networkx(G)
        return G

    def _hierarchy_to_networkx(self, G) -> None:
        """Floors (``floor_<id>``) and rooms (``room_<id>``) as nodes, with "in" edges object -> room ->
        floor (edge attribute ``predictor`` "rooms"); call with the lock held."""
        for f in self.floors:
            if any(r.floor == f.id for r in self.rooms.values()):  # a storey holding no room is left out
                G.add_node(f"floor_{f.id}", kind="floor", label=-1, height=float(f.height))
        for i in sorted(self.rooms):
            r = self.rooms[i]
            G.add_node(
                f"room_{r.id}",
                kind="room",
                label=-1,
                caption=r.type,
                tag=r.type,
                type_source=r.type_source,
                area=float(r.area),
                floor=int(r.floor),
                outline=json.dumps([[[round(float(v), 4) for v in p] for p in poly] for poly in r.outline]),
                first_seen=int(r.first_seen),
                **{f"center_{a}": float(r.center[k]) for k, a in enumerate("xyz")},
                **{f"bbox_min_{a}": float(r.bbox_min[k]) for k, a in enumerate("xyz")},
                **{f"bbox_max_{a}": float(r.bbox_max[k]) for k, a in enumerate("xyz")},
            )
            if any(f.id == r.floor for f in self.floors):
                G.add_edge(f"room_{r.id}", f"floor_{r.floor}", relation="in", score=1.0, predictor="rooms")
            for o in r.objects:
                if o in self.nodes:
                    G.add_edge(int(o), f"room_{r.id}", relation="in", score=1.0, predictor="rooms")

    def save_graphml(self, path: str | Path) -> None:
        """Write the graph as GraphML (atomically; needs networkx)."""
        import networkx as nx

        G = self.to_networkx()
        with atomic_path(path) as tmp:
            nx.write_graphml(G, str(tmp))

    # ------------------------------------------------------------------------------------------- query

    def query(self, text: str, top_k: int | None = None) -> list[SceneNode]:
        """Object nodes answering ``text``, best first (see :meth:`ask`)."""
        return [n for n, _ in self.query_scored(text, top_k)]

    def query_scored(self, text: str, top_k: int | None = None) -> list[tuple[SceneNode, float]]:
        """``[(node, score)]``: the object hits of :meth:`ask`, best first. ConfigError for an empty text."""
        if not " ".join(str(text).split()):
            raise ConfigError("SceneGraph.query: the query text is empty")
        return [(h.node, h.score) for h in self.ask(text, top_k).hits if h.kind == "object"]

    def ask(self, text: str, top_k: int | None = None) -> QueryAnswer:
        """Answer a query such as "chair", "pillow on the bed", "the mug on the desk in the office" or
        "kitchen": ranked object (and room) hits, each with the reason it matched (:mod:`.query`). Never
        raises on a bad query: an empty text or one without a known term gets a message and no hit.

        Offline (``graph.query.kind: offline``): object terms are matched as whole words (plural-tolerant)
        against tags (1.0 for the exact tag, 0.9 inside it) and captions (0.6), synonyms
        (:data:`SYNONYM_GROUPS`) 0.9 times; with ``graph.query_embedding`` "clip" or "openai" the cosine
        similarity of the term and "tag: caption" counts too (from ``graph.query_min_similarity``), and a
        text without any known term is matched as a whole that way. Relations and rooms then weigh each
        candidate (:func:`~ogscene3d.graph.query.rank`). ``#<id>`` names one node. With
        ``graph.query.kind: llm`` the configured endpoint picks the nodes (:class:`~.query.LLMQuery`)."""
        q = " ".join(str(text).lower().split())
        if not q:
            return QueryAnswer(str(text), [], "the query is empty")
        by_id = re.fullmatch(r"#(\d+)", q)
        if by_id:
            with self._lock:
                node = self.nodes.get(int(by_id.group(1)))
            if node is None:
                return QueryAnswer(str(text), [], f"no node {q} in the graph")
            return QueryAnswer(str(text), [QueryHit("object", node.id, 1.0, "node id", node)])
        ctx = self._query_context()
        if self._llm_query is not None:
            return self._llm_query.answer(str(text), ctx, top_k)
        answer = answer_offline(str(text), ctx, top_k)
        if answer.parsed is None and self.config.query_embedding != "none":
            ranked = sorted(self._term_scores(q).items(), key=lambda kv: (-kv[1], kv[0]))[:top_k]
            hits = [QueryHit("object", i, s, "text / embedding similarity", ctx.nodes[i]) for i, s in ranked]
            return QueryAnswer(str(text), hits, "" if hits else answer.message)
        return answer

    def _query_context(self) -> QueryContext:
        with self._lock:
            nodes = dict(self.nodes)
            return QueryContext(
                nodes=nodes,
                edges=dict(self.edges),
                rooms=dict(self.rooms),
                object_room={i: n.room for i, n in nodes.items() if n.room is not None},
                up=self.up,
                term_scores=self._term_scores,
            )

    def _term_scores(self, term: str) -> dict[int, float]:
        """{node id: score} of the nodes an object term names: words (:func:`~.terms.text_score`) and, when
        configured, embedding similarity (the larger of the two)."""
        with self._lock:
            nodes = [self.nodes[i] for i in sorted(self.nodes)]
        # an offline caption repeats the tag and describes geometry ("12 % of it detected as book"): only
        # the words of a model's caption count
        scores = {
            n.id: s
            for n in nodes
            if (s := text_score(term, n.tag, "" if n.caption_source in OFFLINE_SOURCES else n.caption)) > 0
        }
        if self.config.query_embedding != "none" and nodes:
            try:
                sims = self._embedding_scores(" ".join(str(term).lower().split()), nodes)
                for n, s in zip(nodes, sims):
                    if s >= self.config.query_min_similarity:
                        scores[n.id] = max(scores.get(n.id, 0.0), float(s))
            except Exception as e:
                log.warning(
                    "scene graph query: embedding similarity unavailable (%s); using text matching", e
                )
        return scores

    def _embed(self, texts: list[str]) -> np.ndarray:
        kind = self.config.query_embedding
        if self._query_encoder is None:
            if kind == "clip":
                enc = self.node_confidence if isinstance(self.node_confidence, ClipConfidence) else None
                self._query_encoder = enc or ClipConfidence.from_config(self.config.confidence)
            elif kind == "openai":
                model = self.config.embedding_model or self.config.captioner.model
                self._query_encoder = ChatClient.from_config(
                    self.config.endpoint, model, "graph.embedding_model"
                )
            else:
                raise ConfigError(f"graph.query_embedding must be none, clip or openai, got {kind!r}")
        enc = self._query_encoder
        out = enc.embed_texts(texts) if kind == "clip" else enc.embed(texts)
        return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)

    def _embedding_scores(self, q: str, nodes: Sequence[SceneNode]) -> np.ndarray:
        docs = [f"{n.tag}: {n.caption}" for n in nodes]
        missing = [d for d in dict.fromkeys(docs) if d not in self._embed_cache]
        if missing:
            for d, e in zip(missing, self._embed(missing)):
                self._embed_cache[d] = e
        qe = self._embed([q])[0]
        return np.array([float(self._embed_cache[d] @ qe) for d in docs])
