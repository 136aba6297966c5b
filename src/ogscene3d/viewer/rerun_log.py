"""A mapping session logged to Rerun (``--rerun``, ``--rerun-save FILE.rrd``; the ``rerun`` extra:
``pip install "ogscene3d[rerun]"``).

:class:`RerunLogger` is an observer of :class:`~ogscene3d.mapping.engine.MappingEngine`: after every keyframe
it logs, on the ``keyframe`` timeline (and the ``frame`` one, the dataset position), these entities:

==========================  ==========================================================================
``world``                   the world's up direction (``ViewCoordinates``, where ``graph.up_axis`` is an
                            axis), static
``world/camera``            the keyframe's camera: pose (``Transform3D``, camera-to-world) and intrinsics
                            (``Pinhole``; Rerun, like ogscene3d, puts pixel (0, 0)'s centre at (0.5, 0.5))
``world/camera/image``      its colour image (JPEG-compressed ``EncodedImage``)
``world/trajectory``        the keyframe cameras' centres so far (``LineStrips3D``)
``world/map``               the map's Gaussian centres coloured by scene label (``Points3D``; unlabelled grey;
                            ``class_ids`` label + 1, named by the scene graph's node tags through an
                            ``AnnotationContext`` on ``world``), at most ``max_points`` of them
``world/graph/nodes``       the scene graph's nodes: boxes (``Boxes3D``, axis-aligned), named by their tags
``world/graph/edges``       its edges: a line between the two nodes' centres, named by the relation
``stats/keyframe_seconds``  the seconds the keyframe took to map (``Scalars``)
==========================  ==========================================================================

The recording comes with a layout (a blueprint): the world in 3D above the keyframe's image and its
seconds, the timeline below following the latest keyframe.

After the final pass (pruning, the last refinement and graph update) the map and the graph are logged once
more, at keyframe = the number of keyframes. A viewer scrubs the whole session back on the timeline.
"""

from __future__ import annotations

import logging
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ..colors import label_colors
from ..errors import ConfigError
from ..optional import require
from ..up_axis import is_auto
from .snapshot import snapshot_from_mapper

log = logging.getLogger(__name__)

EXTRA_HELP = "logging to Rerun (--rerun, --rerun-save)"
SPAWN = "spawn"
DEFAULT_PORT = 9876  # the Rerun viewer's own default
MAX_POINTS = 200_000  # Gaussian centres logged per keyframe (a stratified random subset beyond that)
JPEG_QUALITY = 85
BOX_ALPHA = 0.35  # the nodes' boxes, faint: walls' and floors' boxes span the room and would hide the map

# graph.up_axis as a world axis -> Rerun's view coordinates of the world
_VIEW = {
    (0, 1): "RIGHT_HAND_X_UP", (0, -1): "RIGHT_HAND_X_DOWN",
    (1, 1): "RIGHT_HAND_Y_UP", (1, -1): "RIGHT_HAND_Y_DOWN",
    (2, 1): "RIGHT_HAND_Z_UP", (2, -1): "RIGHT_HAND_Z_DOWN",
}  # fmt: skip


def rerun_module() -> Any:
    """``rerun`` (rerun-sdk), or a :class:`~ogscene3d.errors.ConfigError` naming the ``rerun`` extra."""
    return require("rerun", "rerun", EXTRA_HELP)


class RerunLogger:
    """Logs a mapping session to Rerun: to a viewer it spawns (``viewer="spawn"``) or connects to (``viewer``
    a ``rerun+http://HOST:PORT/proxy`` URL), and/or to an ``.rrd`` file (``save``).

    Args:
        viewer: None, ``"spawn"`` or a viewer's URL.
        save: an ``.rrd`` file to write (its folder is created).
        name: the recording's name (the dataset's, shown in the viewer).
        max_points: most Gaussian centres logged per keyframe.
    """

    def __init__(
        self,
        viewer: str | None = None,
        save: str | Path | None = None,
        name: str = "ogscene3d",
        max_points: int = MAX_POINTS,
    ) -> None:
        if viewer is None and save is None:
            raise ValueError("RerunLogger needs a viewer to spawn or connect to, or a file to save to")
        rr = rerun_module()
        self.rr = rr
        self.max_points = int(max_points)
        self.rec = rr.RecordingStream("ogscene3d")
        self.rec.send_recording_name(name)
        sinks = []
        if save is not None:
            self.save = Path(save)
            self.save.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(self.save)))
        if viewer is not None:
            url = viewer
            if viewer == SPAWN:
                _spawn_viewer(rr, self.rec)
                url = f"rerun+http://127.0.0.1:{DEFAULT_PORT}/proxy"
            sinks.append(rr.GrpcSink(url))
        self.rec.set_sinks(*sinks, default_blueprint=_layout())
        self._trajectory: list[np.ndarray] = []
        self._up: Any = None
        self._keyframe = 0

    # -- the engine's observer interface

    def keyframe(self, mapper: Any, frame: Any, seconds: float) -> None:
        """Log the keyframe ``frame`` that ``mapper`` has just mapped (``seconds``: how long that took)."""
        self._keyframe = int(mapper.keyframe_count) - 1
        self.rec.set_time("keyframe", sequence=self._keyframe)
        self.rec.set_time("frame", sequence=int(frame.index))
        snap = snapshot_from_mapper(mapper, self.max_points, frame=frame, seed=self._keyframe)
        self._log_up(mapper)
        self._log_camera(snap)
        self._log_map(snap)
        self.rec.log("stats/keyframe_seconds", self.rr.Scalars(float(seconds)))

    def finished(self, mapper: Any) -> None:
        """Log the final map and graph, one step after the last keyframe."""
        self.rec.set_time("keyframe", sequence=int(mapper.keyframe_count))
        self.rec.disable_timeline("frame")
        self._log_up(mapper)
        self._log_map(snapshot_from_mapper(mapper, self.max_points, seed=int(mapper.keyframe_count)))

    def close(self) -> None:
        """Write out everything logged (the ``.rrd`` file is complete after this). A viewer that could not be
        reached (one that failed to start, or went away) is warned about: the run has its map already."""
        try:
            self.rec.flush()
        except Exception as e:  # noqa: BLE001 - rerun-sdk raises RuntimeError for a sink it cannot reach
            log.warning("Rerun: %s; the viewer may have missed some of the session", e)
        try:
            self.rec.disconnect()
        except Exception as e:  # noqa: BLE001
            log.warning("Rerun: %s", e)

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- what is logged

    def _log_up(self, mapper: Any) -> None:
        up = getattr(getattr(getattr(mapper, "config", None), "graph", None), "up_axis", None)
        if up is None or is_auto(up) or up == self._up:
            return
        self._up = list(up)
        u = np.asarray(up, dtype=np.float64)
        k = int(np.argmax(np.abs(u)))
        if abs(u[k]) >= 0.999 * np.linalg.norm(u):  # Rerun's view coordinates name axes only
            view = getattr(self.rr.ViewCoordinates, _VIEW[(k, 1 if u[k] > 0 else -1)])
            self.rec.log("world", view, static=True)

    def _log_camera(self, snap: Any) -> None:
        rr = self.rr
        pose = snap.pose
        if pose is not None:
            self.rec.log("world/camera", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
            self._trajectory.append(np.asarray(pose[:3, 3], dtype=np.float32))
            self.rec.log("world/trajectory", rr.LineStrips3D([np.stack(self._trajectory)]))
        if snap.K is not None and snap.image_size is not None:
            self.rec.log(
                "world/camera",
                rr.Pinhole(
                    image_from_camera=snap.K,
                    resolution=list(snap.image_size),
                    camera_xyz=rr.ViewCoordinates.RDF,
                ),
            )
        if snap.image is not None:
            self.rec.log("world/camera/image", rr.Image(snap.image).compress(jpeg_quality=JPEG_QUALITY))

    def _log_map(self, snap: Any) -> None:
        rr = self.rr
        labels = np.asarray(snap.labels, dtype=np.int64)
        colours = (label_colors(labels) * 255).round().astype(np.uint8)
        class_ids = np.clip(labels + 1, 0, 65535).astype(np.uint16)
        self.rec.log("world/map", rr.Points3D(snap.means, colors=colours, class_ids=class_ids))
        graph = snap.graph or {}
        nodes = graph.get("nodes") or []
        if not nodes:
            return
        names = {int(n["id"]): _node_name(n) for n in nodes}
        ids = np.array(sorted(names), dtype=np.int64)
        node_colours = (label_colors(ids) * 255).round().astype(np.uint8)
        self.rec.log(
            "world",
            rr.AnnotationContext(
                [(0, "unlabelled", (158, 158, 158))]
                + [(int(i) + 1, names[int(i)], tuple(int(v) for v in c)) for i, c in zip(ids, node_colours)]
            ),
        )
        lo = np.array([n["bbox_min"] for n in nodes], dtype=np.float32)
        hi = np.array([n["bbox_max"] for n in nodes], dtype=np.float32)
        self.rec.log(
            "world/graph/nodes",
            rr.Boxes3D(
                mins=lo,
                sizes=hi - lo,
                labels=[names[int(n["id"])] for n in nodes],
                colors=_with_alpha(label_colors(np.array([n["id"] for n in nodes])), BOX_ALPHA),
                class_ids=[int(n["id"]) + 1 for n in nodes],
            ),
        )
        centres = {int(n["id"]): n["center"] for n in nodes}
        edges = [e for e in graph.get("edges") or [] if e["source"] in centres and e["target"] in centres]
        self.rec.log(
            "world/graph/edges",
            rr.LineStrips3D(
                [[centres[e["source"]], centres[e["target"]]] for e in edges],
                labels=[e["relation"] for e in edges],
            ),
        )


def _spawn_viewer(rr: Any, rec: Any) -> None:
    """Start Rerun's viewer (listening on :data:`DEFAULT_PORT`; one already there is reused): the ``rerun``
    on PATH, else the one installed beside this Python (a virtual environment not activated)."""
    exe = shutil.which("rerun")
    beside = Path(sys.executable).parent / "rerun"
    if exe is None and beside.is_file():
        exe = str(beside)
    try:
        rr.spawn(port=DEFAULT_PORT, connect=False, recording=rec, executable_path=exe)
    except RuntimeError as e:
        raise ConfigError(
            f"--rerun could not start Rerun's viewer ({str(e).splitlines()[0]}); give the URL of a viewer "
            "that runs elsewhere (--rerun rerun+http://HOST:9876/proxy), or log to a file (--rerun-save "
            "FILE.rrd)"
        ) from e


def _layout() -> Any:
    """The viewer's first layout: the world in 3D (map, graph, camera, path) above the keyframe's image and
    the seconds per keyframe, the timeline below following the latest keyframe (scrub it to go back), the
    side panels folded."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Spatial3DView(origin="/world", name="map and scene graph"),
            rrb.Horizontal(
                rrb.Spatial2DView(origin="/world/camera", name="keyframe"),
                rrb.TimeSeriesView(origin="/stats", name="seconds per keyframe"),
            ),
            row_shares=[2, 1],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline="keyframe", play_state="following"),
    )


def _with_alpha(rgb: np.ndarray, alpha: float) -> np.ndarray:
    """[N, 3] RGB in [0, 1] -> [N, 4] uint8 RGBA."""
    rgba = np.concatenate([rgb, np.full((len(rgb), 1), alpha, dtype=rgb.dtype)], axis=1)
    return (rgba * 255).round().astype(np.uint8)


def _node_name(node: dict) -> str:
    """What a node is called in the viewer: its tag, else the start of its caption, else its label."""
    name = node.get("tag") or (node.get("caption") or "").split(".")[0][:40]
    return f"{name} ({node['id']})" if name else f"label {node['id']}"


def rerun_logger(viewer: str | None, save: str | Path | None, name: str) -> RerunLogger | None:
    """The logger that ``--rerun [URL]`` (``viewer``: ``"spawn"`` or a URL) and ``--rerun-save FILE`` ask for,
    or None when neither was given."""
    if viewer is None and save is None:
        return None
    logger = RerunLogger(viewer, save, name)
    where = [str(save)] if save is not None else []
    where += ["a Rerun viewer it started" if viewer == SPAWN else viewer] if viewer is not None else []
    log.info("logging the session to Rerun: %s", " and ".join(where))
    return logger
