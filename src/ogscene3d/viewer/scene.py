"""The viewer's 3D layers: Gaussians (splats or points), camera trajectory + frustum, scene graph.

Each layer keeps what it last sent and re-sends only what changed. All methods run on the viewer's
push thread (never on the mapping thread), so they may take their time.
"""

from __future__ import annotations

import html
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..colors import (
    UNLABELED_RGB,
    confidence_colors,
    dim,
    label_color_uint8,
    label_colors,
    room_colors,
    turbo,
)
from ..errors import OGSceneError
from ..graph.rooms import assign_rooms, read_rooms
from .snapshot import MapSnapshot, covariances, decimate_indices, rotmat_to_wxyz

log = logging.getLogger(__name__)

COLOR_MODES = ("rgb", "semantic", "confidence", "room")
RENDER_MODES = ("auto", "splats", "points")
HIGHLIGHT_RGB = (255, 196, 0)
EDGE_RGB = (70, 70, 70)
# the camera's trajectory and its frustum are drawn alike
CAMERA_RGB = (230, 60, 30)
CAMERA_LINE_WIDTH = 2.0


@dataclass
class ViewerSettings:
    """Display settings (the GUI edits them; the CLI sets their start values).

    ``max_splats``: at most this many Gaussians are sent as splats; ``max_points``: as points. In
    ``render="auto"`` a map up to ``max_splats`` is drawn as splats, a larger one as points.
    ``point_size`` is in metres (0 = from the median Gaussian scale). ``show_edge_labels``: every
    relation's label (otherwise only those of the selected node's relations). ``show_rooms``: the rooms'
    outlines at floor height with their type. Colour mode "room": every Gaussian in its room's colour (the
    room whose outline holds it, as ``ogscene3d eval`` counts it), grey outside all. ``label_spacing``: a node
    label is left out where a larger node's label is nearer than this fraction of the map's size (the
    selected node and Find matches are always labelled; 0 labels every node).
    """

    color_mode: str = "rgb"
    render: str = "auto"
    max_splats: int = 200_000
    max_points: int = 1_000_000
    point_size: float = 0.0
    show_gaussians: bool = True
    show_trajectory: bool = True
    show_camera: bool = True
    show_nodes: bool = True
    show_edges: bool = True
    show_edge_labels: bool = False
    show_rooms: bool = True
    max_edge_labels: int = 300
    label_spacing: float = 0.08

    def validate(self) -> ViewerSettings:
        if self.color_mode not in COLOR_MODES:
            raise ValueError(f"color mode must be one of {COLOR_MODES}, got {self.color_mode!r}")
        if self.render not in RENDER_MODES:
            raise ValueError(f"render mode must be one of {RENDER_MODES}, got {self.render!r}")
        if self.max_splats < 1 or self.max_points < 1:
            raise ValueError(
                f"max_splats and max_points must be >= 1, got {self.max_splats}, {self.max_points}"
            )
        if not np.isfinite(self.point_size) or self.point_size < 0:
            raise ValueError(f"point_size must be a finite number >= 0, got {self.point_size}")
        if not 0 <= self.label_spacing <= 1:
            raise ValueError(f"label_spacing must be in [0, 1], got {self.label_spacing}")
        return self


def scene_bounds(means: np.ndarray) -> tuple[np.ndarray, float]:
    """Robust centre and size (m) of a point set: 2nd-98th percentile box of at most 20k points."""
    if len(means) == 0:
        return np.zeros(3), 1.0
    idx = decimate_indices(len(means), 20_000)
    pts = means if idx is None else means[idx]
    lo, hi = np.percentile(pts, 2, axis=0), np.percentile(pts, 98, axis=0)
    return 0.5 * (lo + hi), float(max(np.linalg.norm(hi - lo), 0.1))


def node_text(node: dict) -> str:
    """The short text drawn at a node: its tag, else the first words of its caption, else its id."""
    tag = str(node.get("tag") or "").strip()
    if tag:
        return tag
    caption = str(node.get("caption") or "").strip()
    if caption:
        words = caption.split()
        return " ".join(words[:4]) + ("..." if len(words) > 4 else "")
    return f"#{node.get('id')}"


def labelled_nodes(nodes: dict[int, dict], spacing: float, always: set[int] = frozenset()) -> set[int]:
    """The ids of the nodes whose labels are drawn: a greedy pass from the largest node (most Gaussians)
    down, keeping a label unless a kept one is within ``spacing`` metres (3D centre distance), so that a
    cluster of small objects shows its largest one instead of a pile of overlapping texts. ``always``
    (the selected node, Find matches) are labelled whatever their neighbours."""
    keep = {i for i in always if i in nodes}
    if spacing <= 0:
        return set(nodes)
    centers = [np.asarray(nodes[i]["center"], dtype=np.float64) for i in keep]
    order = sorted(nodes, key=lambda i: (-int(nodes[i].get("num_gaussians") or 0), i))
    for i in order:
        if i in keep:
            continue
        c = np.asarray(nodes[i]["center"], dtype=np.float64)
        if all(np.linalg.norm(c - k) >= spacing for k in centers):
            keep.add(i)
            centers.append(c)
    return keep


def _swatch(rgb: tuple[int, int, int] | np.ndarray, text: str) -> str:
    r, g, b = (int(v) for v in rgb)
    return (
        f'<div style="display:flex;align-items:center;gap:6px;line-height:1.5">'
        f'<span style="display:inline-block;width:12px;height:12px;border-radius:2px;'
        f'background:rgb({r},{g},{b})"></span><span>{html.escape(text)}</span></div>'
    )


def shown_rooms(graph: dict | None):
    """(up, floors, rooms) of a graph document for drawing (:func:`~ogscene3d.graph.rooms.read_rooms`);
    no rooms when it has none or they are malformed (a live graph half-way through an update must not
    break the viewer)."""
    if not isinstance(graph, dict) or not graph.get("rooms"):
        return None, [], []
    try:
        return read_rooms(graph, "the shown graph")
    except OGSceneError as e:
        log.debug("rooms not drawn: %s", e)
        return None, [], []


def gaussian_rooms(means: np.ndarray, graph: dict | None, up: np.ndarray) -> np.ndarray:
    """The room id of every Gaussian (-1: none), by the rooms' outlines."""
    doc_up, floors, rooms = shown_rooms(graph)
    if not rooms:
        return np.full(len(means), -1, dtype=np.int64)
    return assign_rooms(means, doc_up if doc_up is not None else up, floors, rooms)


def legend_html(color_mode: str, graph: dict | None, max_rows: int = 40) -> str:
    """The colour legend of ``color_mode`` as HTML: per scene-graph node its label colour and text
    (largest nodes first) in "semantic" mode, per room its colour and type in "room" mode, the colour ramp
    in "confidence" mode, "" in "rgb"."""
    grey = tuple(int(round(float(v) * 255)) for v in UNLABELED_RGB)
    if color_mode == "room":
        _, _, rooms = shown_rooms(graph)
        rows = [
            _swatch(tuple(int(round(float(v) * 255)) for v in room_colors(np.array([r.id]))[0]),
                    f"{r.type} (room #{r.id}, {len(r.objects)} objects)")
            for r in rooms[:max_rows]
        ]  # fmt: skip
        if not rooms:
            rows.append("<div><i>no rooms yet</i></div>")
        return "".join(rows) + _swatch(grey, "in no room")
    if color_mode == "confidence":
        ts = np.linspace(0.0, 1.0, 6)
        ramp = np.round(turbo(ts) * 255).astype(int)
        stops = ", ".join(f"rgb({r},{g},{b}) {t * 100:.0f}%" for (r, g, b), t in zip(ramp, ts))
        return (
            f'<div style="height:12px;border-radius:2px;background:linear-gradient(to right, {stops})"></div>'
            '<div style="display:flex;justify-content:space-between"><span>0</span>'
            "<span>label confidence</span><span>1</span></div>" + _swatch(grey, "unlabelled")
        )
    if color_mode != "semantic":
        return ""
    nodes = sorted(
        (graph or {}).get("nodes", []), key=lambda n: (-int(n.get("num_gaussians") or 0), int(n["id"]))
    )
    rows = [_swatch(label_color_uint8(int(n["id"])), f"{node_text(n)} (#{n['id']})") for n in nodes]
    rows = rows[:max_rows]
    if len(nodes) > max_rows:
        rows.append(f"<div>... {len(nodes) - max_rows} more nodes</div>")
    if not nodes:
        rows.append("<div><i>no scene-graph nodes yet</i></div>")
    rows.append(_swatch(grey, "unlabelled"))
    rows.append("<div><small>labels without a graph node keep their own colour</small></div>")
    return "".join(rows)


def _valid_node(node: dict) -> bool:
    """A node can be drawn when it has an id and a finite 3D centre (others are skipped, not fatal)."""
    try:
        int(node["id"])
        c = np.asarray(node["center"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        return False
    return c.shape == (3,) and bool(np.isfinite(c).all())


def drawable_graph(graph: dict | None) -> dict | None:
    """The part of a graph document the viewer can draw: nodes with an int id and a finite centre,
    edges whose integer source and target are such nodes. Malformed entries are dropped (a live graph
    half-way through an update must not break the viewer); None stays None."""
    if not isinstance(graph, dict):
        return None
    nodes = [n for n in graph.get("nodes", []) if isinstance(n, dict) and _valid_node(n)]
    ids = {int(n["id"]) for n in nodes}
    edges = []
    for e in graph.get("edges", []):
        try:
            if int(e["source"]) in ids and int(e["target"]) in ids:
                edges.append(e)
        except (KeyError, TypeError, ValueError):
            continue
    return {**graph, "nodes": nodes, "edges": edges}


def _remove(*handles) -> None:
    """Take scene handles off the scene (None: nothing drawn there)."""
    for h in handles:
        if h is not None:
            h.remove()


def _box_segments(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The 12 edges of the axis-aligned box [lo, hi] as [12, 2, 3]."""
    c = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    corners = lo + c * (hi - lo)
    pairs = [(i, j) for i in range(8) for j in range(i + 1, 8) if np.abs(c[i] - c[j]).sum() == 1]
    return np.stack([corners[[i, j]] for i, j in pairs])


class SceneLayers:
    """Owns the viser scene nodes of one view: ``target`` is a viser ``ClientHandle`` (one browser's
    scene, as the viewer uses it) or a ``ViserServer`` (a scene every browser shares)."""

    def __init__(self, target, on_node_click: Callable[[int], None] | None = None) -> None:
        self.target = target
        self.scene = target.scene
        self.on_node_click = on_node_click
        self.center = np.zeros(3)
        self.extent = 1.0
        # What was last sent, for diffing.
        self._gauss_handle = None
        self._gauss_kind: str | None = None
        self.shown_gaussians = 0
        self.shown_kind = ""
        self._traj_key: tuple | None = None
        self._traj_handle = None
        self._frustum = None
        self._frustum_key: tuple | None = None
        self._image: np.ndarray | None = None  # the image shown (held: an id() can be reused once freed)
        self._pose_key: tuple | None = None
        self._nodes: dict[int, tuple] = {}  # id -> (text, center, highlighted, radius)
        self._node_handles: dict[int, tuple] = {}  # id -> (label handle, sphere handle)
        # id -> the frame /graph/nodes/<id> holding them (removing it removes both; viser would otherwise
        # keep an implicit frame per node id ever shown and replay it to every browser that connects)
        self._node_frames: dict[int, object] = {}
        self._labelled: set[int] = set()  # nodes whose label is drawn
        self._edges_key: tuple | None = None
        self._edge_segments = None
        self._edge_labels: list = []
        self._edge_labels_key: tuple | None = None
        self._highlight_handle = None
        self._highlight_key: tuple | None = None
        self._rooms_key: tuple | None = None
        self._room_handles: list = []

    # ------------------------------------------------------------------ Gaussians
    def update_bounds(self, snap: MapSnapshot) -> None:
        self.center, self.extent = scene_bounds(snap.means)

    def update_map(
        self,
        snap: MapSnapshot,
        st: ViewerSettings,
        highlight_labels: set[int] | None,
        graph: dict | None = None,
        up: np.ndarray | None = None,
    ) -> None:
        """(Re)send the Gaussians with the current colour mode, render mode and budgets (``graph`` and the
        world ``up``: the rooms of colour mode "room")."""
        n = len(snap)
        kind = st.render
        if kind == "auto":
            kind = "splats" if (snap.total_gaussians or n) <= st.max_splats else "points"
        budget = st.max_splats if kind == "splats" else st.max_points
        idx = decimate_indices(n, budget)
        s = snap if idx is None else snap.subset(idx)
        if st.color_mode == "semantic":
            rgb = label_colors(s.labels)
        elif st.color_mode == "confidence":
            rgb = confidence_colors(s.confidences, s.labels)
        elif st.color_mode == "room":
            default_up = np.array([0.0, -1.0, 0.0]) if up is None else up
            rgb = room_colors(gaussian_rooms(s.means, graph, default_up))
        else:
            rgb = np.clip(s.colors, 0.0, 1.0)
        if highlight_labels:
            rgb = np.where(np.isin(s.labels, list(highlight_labels))[:, None], rgb, dim(rgb))
        if len(s) == 0:
            self._remove_gaussians()
            return
        if kind != self._gauss_kind:
            self._remove_gaussians()
        if kind == "splats":
            cov = covariances(s.quats, s.scales)
            op = s.opacities[:, None]
            if self._gauss_handle is None:
                self._gauss_handle = self.scene.add_gaussian_splats(
                    "/map/gaussians",
                    centers=s.means,
                    covariances=cov,
                    rgbs=rgb,
                    opacities=op,
                    visible=st.show_gaussians,
                )
            else:
                self._gauss_handle.set_gaussians(s.means, cov, rgb, op)
        else:
            size = st.point_size or float(np.clip(2.0 * np.median(s.scales.max(axis=1)), 0.002, 0.05))
            if self._gauss_handle is None:
                self._gauss_handle = self.scene.add_point_cloud(
                    "/map/gaussians",
                    points=s.means,
                    colors=rgb,
                    point_size=size,
                    precision="float32",
                    point_shape="circle",
                    point_shading="flat",
                    visible=st.show_gaussians,
                )
            else:
                self._gauss_handle.points = s.means
                self._gauss_handle.colors = (np.clip(rgb, 0, 1) * 255).astype(np.uint8)
                self._gauss_handle.point_size = size
        self._gauss_kind = kind
        self.shown_gaussians = len(s)
        self.shown_kind = kind

    def _remove_gaussians(self) -> None:
        _remove(self._gauss_handle)
        self._gauss_handle = None
        self._gauss_kind = None
        self.shown_gaussians = 0
        self.shown_kind = ""

    def _lines(self, name: str, points: np.ndarray, rgb: tuple[int, ...], width: float, visible: bool = True):
        """Add line segments ``points`` [M, 2, 3] of one colour, ``width`` screen pixels wide (the look of
        every line layer: trajectory, edges, highlight boxes, room outlines)."""
        return self.scene.add_line_segments(
            name, points=points, colors=rgb, thickness=width, thickness_units="screen", visible=visible
        )

    # ------------------------------------------------------------------ camera
    def update_camera(self, snap: MapSnapshot, st: ViewerSettings) -> None:
        """Trajectory polyline and the current frustum (with the current image when there is one)."""
        traj = snap.trajectory
        key = (len(traj), tuple(np.round(traj[-1, :3, 3], 6)) if len(traj) else ())
        if key != self._traj_key:
            _remove(self._traj_handle)
            self._traj_handle = None
            if len(traj) >= 2:
                pos = traj[:, :3, 3]
                seg = np.stack([pos[:-1], pos[1:]], axis=1).astype(np.float32)
                self._traj_handle = self._lines(
                    "/camera/trajectory", seg, CAMERA_RGB, CAMERA_LINE_WIDTH, st.show_trajectory
                )
            self._traj_key = key
        if snap.pose is None:
            return
        w, h = snap.image_size or (640, 480)
        fy = float(snap.K[1, 1]) if snap.K is not None else 0.5 * h / np.tan(np.deg2rad(30))
        fov, aspect = 2.0 * float(np.arctan(0.5 * h / fy)), w / h
        scale = float(np.clip(0.06 * self.extent, 0.05, 0.5))
        fkey = (round(fov, 5), round(aspect, 5), round(scale, 3))
        if self._frustum is None or fkey != self._frustum_key:
            _remove(self._frustum)
            self._frustum = self.scene.add_camera_frustum(
                "/camera/current",
                fov=fov,
                aspect=aspect,
                scale=scale,
                color=CAMERA_RGB,
                thickness=CAMERA_LINE_WIDTH,
                thickness_units="screen",
                visible=st.show_camera,
            )
            self._frustum_key = fkey
            self._image = None
            self._pose_key = None
        pose_key = tuple(np.round(snap.pose[:3].ravel(), 6))
        if pose_key != self._pose_key:
            self._frustum.wxyz = rotmat_to_wxyz(snap.pose[:3, :3])
            self._frustum.position = snap.pose[:3, 3]
            self._pose_key = pose_key
        if snap.image is not None and snap.image is not self._image:
            step = max(1, int(np.ceil(snap.image.shape[1] / 240)))
            self._frustum.image = np.ascontiguousarray(snap.image[::step, ::step])
            self._image = snap.image

    # ------------------------------------------------------------------ graph
    def update_graph(
        self, graph: dict | None, st: ViewerSettings, matches: set[int], selected: int | None = None
    ) -> None:
        """Clickable spheres at node centres with the labels :func:`labelled_nodes` keeps, edges, the
        relation labels (all, or the ``selected`` node's), boxes around the Find ``matches``."""
        nodes = {int(n["id"]): n for n in (graph or {}).get("nodes", []) if _valid_node(n)}
        radius = float(np.clip(0.012 * self.extent, 0.015, 0.08))
        always = set(matches) | ({selected} if selected is not None else set())
        labelled = labelled_nodes(nodes, st.label_spacing * self.extent, always)
        for nid in [i for i in self._node_handles if i not in nodes]:
            self._node_handles.pop(nid)
            self._node_frames.pop(nid).remove()  # and the label and marker in it
            self._nodes.pop(nid, None)
        for nid, node in nodes.items():
            center = np.asarray(node["center"], dtype=np.float64)
            hl, sel = nid in matches, nid == selected
            state = (node_text(node), tuple(np.round(center, 5)), hl, sel, nid in labelled, radius)
            if self._nodes.get(nid) == state:
                continue
            text = ("★ " if hl else "") + state[0]
            color = HIGHLIGHT_RGB if hl else label_color_uint8(nid)
            r = radius * (1.6 if hl or sel else 1.0)
            font = 1.2 if hl or sel else 0.9
            label_visible = st.show_nodes and nid in labelled
            if nid in self._node_handles:
                label, sphere = self._node_handles[nid]
                label.text = text
                label.position = center
                label.font_screen_scale = font
                label.visible = label_visible
                sphere.position = center
                sphere.color = color
                sphere.scale = (r / radius,) * 3
            else:
                self._node_frames[nid] = self.scene.add_frame(f"/graph/nodes/{nid}", show_axes=False)
                label = self.scene.add_label(
                    f"/graph/nodes/{nid}/label",
                    text,
                    position=center,
                    anchor="bottom-center",
                    font_screen_scale=font,
                    visible=label_visible,
                )
                sphere = self.scene.add_icosphere(
                    f"/graph/nodes/{nid}/marker",
                    radius=radius,
                    color=color,
                    subdivisions=2,
                    position=center,
                    scale=(r / radius,) * 3,
                    visible=st.show_nodes,
                )
                if self.on_node_click is not None:
                    cb = self.on_node_click
                    sphere.on_click(lambda _event, nid=nid, cb=cb: cb(nid))
                self._node_handles[nid] = (label, sphere)
            self._nodes[nid] = state
        self._labelled = labelled
        self._update_edges(graph, nodes, st, selected)
        self._update_highlight(nodes, matches)

    def _update_edges(
        self, graph: dict | None, nodes: dict[int, dict], st: ViewerSettings, selected: int | None
    ) -> None:
        edges = [
            e
            for e in (graph or {}).get("edges", [])
            if int(e.get("source", -1)) in nodes and int(e.get("target", -1)) in nodes
        ]
        key = tuple(
            (
                int(e["source"]),
                int(e["target"]),
                str(e.get("relation", "")),
                tuple(nodes[int(e["source"])]["center"]),
                tuple(nodes[int(e["target"])]["center"]),
            )
            for e in edges
        )
        if key != self._edges_key:
            _remove(self._edge_segments)
            self._edge_segments = None
            self._edges_key = key
            if edges:
                src = np.array([k[3] for k in key], dtype=np.float32)
                dst = np.array([k[4] for k in key], dtype=np.float32)
                self._edge_segments = self._lines(
                    "/graph/edges", np.stack([src, dst], axis=1), EDGE_RGB, 1.5, st.show_edges
                )
        # Relation labels: on a room-sized graph (a hundred edges) all of them at once are a pile of
        # overlapping text, so by default only the selected node's relations are labelled.
        shown = [
            i for i, k in enumerate(key) if k[2].strip() and (st.show_edge_labels or selected in (k[0], k[1]))
        ][: st.max_edge_labels]
        label_key = (key, tuple(shown))
        if label_key == self._edge_labels_key:
            return
        _remove(*self._edge_labels)
        self._edge_labels = []
        self._edge_labels_key = label_key
        for i in shown:
            mid = 0.5 * (np.asarray(key[i][3]) + np.asarray(key[i][4]))
            self._edge_labels.append(
                self.scene.add_label(
                    f"/graph/edge_labels/{i}",
                    key[i][2].strip(),
                    position=mid,
                    anchor="center-center",
                    font_screen_scale=0.75,
                    visible=st.show_edges,
                )
            )

    def _update_highlight(self, nodes: dict[int, dict], matches: set[int]) -> None:
        boxes = [
            (np.asarray(nodes[i]["bbox_min"], float), np.asarray(nodes[i]["bbox_max"], float))
            for i in sorted(matches)
            if i in nodes and "bbox_min" in nodes[i] and "bbox_max" in nodes[i]
        ]
        key = tuple((tuple(lo), tuple(hi)) for lo, hi in boxes)
        if key == self._highlight_key:
            return
        _remove(self._highlight_handle)
        self._highlight_handle = None
        self._highlight_key = key
        good = [
            (lo, hi)
            for lo, hi in boxes
            if lo.shape == (3,) and hi.shape == (3,) and np.isfinite([lo, hi]).all()
        ]
        if good:
            seg = np.concatenate([_box_segments(lo, hi) for lo, hi in good]).astype(np.float32)
            self._highlight_handle = self._lines("/graph/highlight", seg, HIGHLIGHT_RGB, 3.0)

    # ------------------------------------------------------------------ rooms
    def update_rooms(self, graph: dict | None, st: ViewerSettings) -> None:
        """Each room's outline at its floor's height, in its colour, with its type at its centre."""
        _, _, rooms = shown_rooms(graph)
        key = tuple((r.id, r.type, tuple(np.round(np.concatenate(r.outline), 4).ravel())) for r in rooms
                    if r.outline)  # fmt: skip
        if key == self._rooms_key:
            return
        _remove(*self._room_handles)
        self._room_handles = []
        self._rooms_key = key
        for r in rooms:
            if not r.outline:
                continue
            seg = np.concatenate([np.stack([p, np.roll(p, -1, axis=0)], axis=1) for p in r.outline])
            color = tuple(int(round(float(v) * 255)) for v in room_colors(np.array([r.id]))[0])
            self._room_handles.append(
                self._lines(f"/rooms/{r.id}/outline", seg.astype(np.float32), color, 3.0, st.show_rooms)
            )
            self._room_handles.append(
                self.scene.add_label(
                    f"/rooms/{r.id}/label",
                    f"{r.type} #{r.id}",
                    position=np.concatenate(r.outline).mean(axis=0),
                    anchor="center-center",
                    font_screen_scale=1.1,
                    visible=st.show_rooms,
                )
            )

    @property
    def shown_rooms(self) -> int:
        return len(self._rooms_key or ())

    @property
    def shown_nodes(self) -> int:
        return len(self._node_handles)

    @property
    def shown_edges(self) -> int:
        return len(self._edges_key or ())

    # ------------------------------------------------------------------ visibility
    def apply_visibility(self, st: ViewerSettings) -> None:
        """Show/hide layers without re-sending their data."""
        if self._gauss_handle is not None:
            self._gauss_handle.visible = st.show_gaussians
        if self._traj_handle is not None:
            self._traj_handle.visible = st.show_trajectory
        if self._frustum is not None:
            self._frustum.visible = st.show_camera
        for nid, (label, sphere) in self._node_handles.items():
            label.visible = st.show_nodes and nid in self._labelled
            sphere.visible = st.show_nodes
        if self._edge_segments is not None:
            self._edge_segments.visible = st.show_edges
        for h in self._edge_labels:
            h.visible = st.show_edges
        for h in self._room_handles:
            h.visible = st.show_rooms


__all__ = [
    "COLOR_MODES",
    "RENDER_MODES",
    "SceneLayers",
    "ViewerSettings",
    "drawable_graph",
    "labelled_nodes",
    "legend_html",
    "node_text",
    "scene_bounds",
]
