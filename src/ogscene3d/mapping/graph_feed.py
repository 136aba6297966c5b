"""Feeding the scene graph from the mapping: each keyframe's label map and detector names, the scheduled
updates, the graph's part of a checkpoint and of ``graph.json``. The graph is optional: any failure in it
disables it for the run, and the mapping goes on."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import torch

from ..config import Config
from ..frame import Frame
from ..gaussians import GaussianMap
from ..graph import SceneGraph
from ..rendering import render_semantics
from ..up_axis import AGREE_DEG, CameraUp, angle_deg, axis_name, is_auto
from .timings import Timings

log = logging.getLogger(__name__)


def name_votes(segments: np.ndarray, lut: np.ndarray, names: dict[int, str]) -> dict[int, dict[str, int]]:
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


class GraphFeed:
    """The run's scene graph (``ogscene3d.graph.SceneGraph``, when ``config.graph.enabled``) and what feeds
    it: the mapped cameras' up direction (``graph.up_axis`` auto, or a check of a given one)."""

    def __init__(self, config: Config, device: torch.device, timings: Timings) -> None:
        self.config = config
        self.device = device
        self.timings = timings
        # built now, so that a mistake in the graph's settings (captioner, relations, confidence model)
        # stops the run before its first frame instead of disabling the graph hours into it
        self.graph = self._new_graph() if config.graph.enabled else None
        self.failed = False
        self.camera_up = CameraUp()
        self._up_checked = False

    @property
    def active(self):
        """The graph, None when it is off or an error disabled it for the run."""
        return None if self.failed else self.graph

    def _new_graph(self):
        return SceneGraph(self.config.graph)

    def check_up_axis(self, frames_seen: int) -> None:
        """At the first graph update (the cameras over the frames mapped until then): choose graph.up_axis
        when it is still auto (nothing told it when the run opened: a recording tracked by odometry, a live
        camera), logged; else warn (once) when the given one is far from where the cameras' up points:
        relations (on, under) and floor / wall / ceiling tags would then use a wrong vertical (worlds differ:
        Replica's and ScanNet's are z-up, an OpenCV camera's first frame is -y up).
        :data:`~ogscene3d.up_axis.AGREE_DEG` leaves room for cameras pitched down at a table."""
        if self._up_checked:
            return
        self._up_checked = True
        cam_up = self.camera_up.estimate()
        if is_auto(self.config.graph.up_axis):
            if cam_up is None:
                return  # no camera mapped yet: the provisional up stays
            self.config.graph.up_axis = [float(v) for v in cam_up]
            if self.graph is not None:
                self.graph.set_up_axis(cam_up)
            log.info(
                "graph.up_axis auto: %s (the cameras' up direction over the %d frames mapped)",
                axis_name(cam_up),
                self.camera_up.count,
            )
            return
        up = np.asarray(self.config.graph.up_axis, dtype=np.float64)
        if cam_up is None or up.shape != (3,) or not np.linalg.norm(up) > 0:
            return
        angle = angle_deg(up, cam_up)
        if angle > AGREE_DEG:
            _warn_up_axis(up, cam_up, angle, frames_seen)

    def step(
        self,
        gm: GaussianMap,
        kf: int,
        frame: Frame,
        segments: np.ndarray | None,
        seg_to_label: tuple[np.ndarray, np.ndarray] | None,
        names: dict[int, str] | None,
        frames_seen: int,
    ) -> None:
        """Feed the graph one keyframe; any failure there disables it for the run, mapping goes on.

        The keyframe's label map is its segmentation with each segment replaced by the scene label it was
        given (exact SAM boundaries); without segments, the map's rendered labels. A detector's class
        ``names`` of segments vote, by area, for the name of the scene label each segment was given."""
        try:
            votes: dict[int, dict[str, int]] = {}
            if segments is not None and seg_to_label is not None:
                ids, labs = seg_to_label
                lut = np.full(int(max(ids.max(initial=0), segments.max(initial=0))) + 1, -1, dtype=np.int32)
                lut[ids] = labs
                label_map = lut[np.asarray(segments)]
                if names:
                    votes = name_votes(np.asarray(segments), lut, names)
            else:
                label_map = render_labels(gm, frame, self.device)
            self.graph.observe(kf, frame, label_map, name_votes=votes)
            if self.graph.is_due(kf):
                self.check_up_axis(frames_seen)
                self.graph.update(kf, gm.means, gm.labels, gm.confidences, gm.colors)
        except Exception as e:  # noqa: BLE001 - the graph is optional; mapping must go on
            log.warning("scene graph disabled for this run after an error: %s: %s", type(e).__name__, e)
            self.failed = True
            self.timings.add("graph_errors")

    def finalize(self, gm: GaussianMap, last_keyframe: int, frames_seen: int) -> None:
        """The end of stream's graph update (in a run of fewer than graph.init_keyframes keyframes the only
        one there is)."""
        if self.active is None:
            return
        with self.timings.section("graph"):
            try:
                self.check_up_axis(frames_seen)
                self.graph.finalize(last_keyframe, gm.means, gm.labels, gm.confidences, gm.colors)
            except Exception as e:  # noqa: BLE001
                log.warning("final scene-graph update failed: %s: %s", type(e).__name__, e)
                self.failed = True

    def state(self) -> dict[str, np.ndarray]:
        """The graph's checkpoint array: captions (possibly paid VLM calls), first_seen and the update
        schedule go on after a resume."""
        if self.active is None:
            return {}
        return {"graph_state": np.array(json.dumps(self.graph.state()))}

    def load_state(self, graph_state: np.ndarray | None, path: Path) -> None:
        """Restore :meth:`state` read from the checkpoint ``path`` (None: the checkpoint holds none)."""
        self.failed = False
        if not self.config.graph.enabled:
            return
        # the graph built with the Mapper takes the checkpoint's state (its models are loaded once)
        if self.graph is None or self.graph.num_updates or self.graph.nodes:
            self.graph = self._new_graph()
        if graph_state is None:
            return
        try:
            self.graph.load_state(json.loads(str(graph_state)), source=f"{path} (graph_state)")
        except Exception as e:  # noqa: BLE001 - the graph is optional: the map resumes without it
            log.warning(
                "scene graph not restored (%s: %s): the next update builds it anew", type(e).__name__, e
            )
            self.graph = self._new_graph()

    def document(self, gm: GaussianMap, keyframe_count: int) -> dict:
        """``graph.json``: the graph's, or nodes straight from the map's labels when none was built."""
        graph = None
        if self.active is not None:
            try:
                graph = self.graph.to_dict()
            except Exception as e:  # noqa: BLE001
                log.warning("could not serialise the scene graph: %s: %s", type(e).__name__, e)
        if graph is None:
            graph = {"version": 1, "nodes": label_nodes(gm, keyframe_count), "edges": []}
        return graph


def _warn_up_axis(up: np.ndarray, cam_up: np.ndarray, angle: float, frames_seen: int) -> None:
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
        frames_seen,
        "xyz"[axis] if guess[axis] > 0 else "-" + "xyz"[axis],
        "[" + ",".join(f"{v:g}" for v in guess) + "]",
    )


def render_labels(gm: GaussianMap, frame: Frame, device: torch.device) -> np.ndarray:
    """The map's label per pixel [H,W] int32 (-1 where nothing labelled renders) at the frame's pose."""
    viewmat = torch.as_tensor(np.linalg.inv(frame.pose), dtype=torch.float32, device=device)[None]
    K = torch.as_tensor(frame.K, dtype=torch.float32, device=device)[None]
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


def label_nodes(gm: GaussianMap, keyframe_count: int) -> list[dict]:
    """Graph nodes straight from the map's labels (used when no scene graph was built)."""
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
            "last_updated": keyframe_count - 1,
        }
        for i in range(n)
    ]
