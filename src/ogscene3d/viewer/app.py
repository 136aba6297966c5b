"""The live viewer: a viser server, a GUI per browser and a push thread that draws the latest
:class:`MapSnapshot`.

Threading: producers (the mapping thread, a run loader, a test) call :meth:`LiveViewer.publish`, which
only stores a reference under a lock and never waits on the network or the browser. One push thread
takes the newest snapshot at most ``max_rate_hz`` times per second and sends each browser what changed
for it. GUI callbacks (viser's thread pool) only edit that browser's settings and wake the push thread,
so every scene update happens on one thread.

Each browser is a :class:`BrowserView`: its own GUI (viser's ``client.gui``) and its own scene
(``client.scene``), built when it connects. Colour mode, Find text, the selected node and the layer
switches of one browser therefore never change what another one shows. While no browser is connected
nothing is pushed (the newest snapshot waits), so an unwatched viewer costs the mapping nothing but the
snapshot copies.
"""

from __future__ import annotations

import dataclasses
import errno
import json
import logging
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np

from ..errors import ConfigError, OGSceneError
from ..graph.scenegraph import SceneGraph
from .scene import (
    COLOR_MODES,
    RENDER_MODES,
    SceneLayers,
    ViewerSettings,
    drawable_graph,
    legend_html,
    node_text,
    scene_bounds,
)
from .snapshot import MapSnapshot

log = logging.getLogger(__name__)

_COLOR_LABELS = {"rgb": "RGB", "semantic": "Semantic label", "confidence": "Confidence", "room": "Room"}
_RENDER_LABELS = {"auto": "Auto", "splats": "Splats", "points": "Points"}
_NO_NODE = "(none)"
# graph.json caption_source values as the node details panel names them
_CAPTION_SOURCES = {
    "vlm": "VLM",
    "vlm-text": "VLM, prose reply instead of JSON",
    "heuristic": "geometric heuristic",
    "detector": "detector class + geometric heuristic",
    "groundtruth": "ground truth",
}
_MAX_NODE_OPTIONS = 500


class _DropAbortedHandshakes(logging.Filter):
    """Browsers open speculative connections and close some before sending a request; the websockets
    server logs each as an ERROR with three chained tracebacks ("opening handshake failed"). Those are
    harmless and dropped; a handshake that failed on a request that did arrive is still logged."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage() != "opening handshake failed" or not record.exc_info:
            return True
        exc = record.exc_info[1]
        while exc is not None:
            if isinstance(exc, EOFError):
                return False
            exc = exc.__cause__
        return True


def _quiet_websockets(verbose: bool) -> None:
    """The websockets server's connection chatter stays out of the console unless ``verbose``."""
    logging.getLogger("websockets").setLevel(logging.DEBUG if verbose else logging.WARNING)
    server_log = logging.getLogger("websockets.server")
    if not any(isinstance(f, _DropAbortedHandshakes) for f in server_log.filters):
        server_log.addFilter(_DropAbortedHandshakes())


class MappingControl(Protocol):
    """What the GUI can ask of a running mapping session (see :class:`ogscene3d.viewer.live.LiveSession`)."""

    @property
    def paused(self) -> bool: ...

    def set_paused(self, paused: bool) -> None: ...

    def save(self, out_dir: str | Path) -> Path: ...

    @property
    def default_out_dir(self) -> Path: ...

    @property
    def done(self) -> bool:
        """Whether mapping has ended (the stream is over, stopped or failed): nothing left to pause."""
        ...


def _up_vector(up: str | np.ndarray | tuple | None) -> np.ndarray | None:
    if up is None:
        return None
    if isinstance(up, str):
        table = {
            "+x": (1, 0, 0),
            "-x": (-1, 0, 0),
            "+y": (0, 1, 0),
            "-y": (0, -1, 0),
            "+z": (0, 0, 1),
            "-z": (0, 0, -1),
        }
        if up not in table:
            raise ValueError(f"up direction must be one of {sorted(table)}, got {up!r}")
        up = table[up]
    v = np.asarray(up, dtype=np.float64)
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) == 0:
        raise ValueError(f"up direction must be a non-zero 3-vector, got {up!r}")
    return v / np.linalg.norm(v)


# viser tries the requested port and then the next ones, this many in all, before giving up
_VISER_PORT_TRIES = 1000


def _binds(host: str, port: int) -> OSError | None:
    """Whether a listening TCP socket can be bound on ``host``:``port`` as asyncio's ``create_server``
    (viser's) binds it: every address ``host`` resolves to, skipping families the machine lacks
    (EADDRNOTAVAIL) as long as one address binds. None when it can, else the error."""
    infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    bound, skipped = 0, None
    for family, kind, proto, _, addr in infos:
        with socket.socket(family, kind, proto) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio does on POSIX
            try:
                s.bind(addr)
                bound += 1
            except OSError as e:
                if e.errno != errno.EADDRNOTAVAIL:
                    return e
                skipped = e
    return None if bound else skipped


def check_bindable(host: str, port: int) -> int:
    """The port viser will serve on for ``host``/``port`` (the first free one from ``port`` on; port 0
    lets the OS choose), or ConfigError when there is none: an invalid port, a host name that does not
    resolve, or an address that is not this machine's.

    viser binds on its own thread and, when that fails, leaves the caller waiting forever (deaf to
    Ctrl-C and SIGTERM), so what it cannot bind is found out here first."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ConfigError(f"viewer port must be an integer from 0 to 65535, got {port!r}")
    last: OSError | None = None
    candidates = range(port, min(port + _VISER_PORT_TRIES, 65536)) if port else [0]
    for p in candidates:
        try:
            last = _binds(host, p)
        except socket.gaierror as e:
            raise ConfigError(f"viewer host {host!r} does not resolve to an address ({e})") from None
        if last is None:
            return p
        if last.errno not in (errno.EADDRINUSE, errno.EACCES):
            break  # the host itself cannot be bound: another port will not help
    where = f"{host}:{port}" if port else f"{host} (any port)"
    if last is not None and last.errno in (errno.EADDRINUSE, errno.EACCES):
        raise ConfigError(f"cannot serve the viewer on {where} or the next ports: {last.strerror}")
    raise ConfigError(
        f"cannot serve the viewer on {where}: {last.strerror if last else 'no address'} "
        "(is the host an address of this machine? 127.0.0.1 or 0.0.0.0 always are)"
    )


def caption_line(node: dict) -> str:
    """The node panel's caption line, saying where the caption came from (``caption_source``) when the
    graph records it: a prose VLM reply or a heuristic fallback reads differently from a VLM caption."""
    source = node.get("caption_source")
    label = _CAPTION_SOURCES.get(source, str(source)) if source else ""
    return f"caption ({label}): {node['caption']}" if label else f"caption: {node['caption']}"


# Width (CSS pixels) of viser's control panel, which floats over the right of the canvas on wide screens
_PANEL_PX = 340
# the first view's distance over the one where the map's robust sphere just fits (see fit_camera)
_FIT_MARGIN = 1.15
# a browser is moved to the first whole-map view at most this many times (see BrowserView._on_camera)
_CAMERA_TRIES = 5


def fit_camera(
    center: np.ndarray,
    extent: float,
    up: np.ndarray,
    fov: float,
    view_dir: np.ndarray | None = None,
    *,
    aspect: float = 1.0,
    covered: float = 0.0,
    elevation_deg: float = 40.0,
) -> tuple[np.ndarray, np.ndarray]:
    """A camera ``(position, look_at)`` that shows the whole map from outside.

    The map is the sphere of diameter ``extent`` (the diagonal of its robust box) around ``center``; the
    camera is put where that sphere fits the view with a margin for the Gaussians beyond the robust box
    (walls reach past it), seen from ``elevation_deg`` above the horizon.
    ``fov``: vertical field of view (radians); ``aspect``: width / height of the canvas; ``covered``: the
    fraction of its width on the right that the GUI panel hides (the map is fitted into the rest and
    centred there). ``view_dir`` (e.g. the run's first viewing direction) sets the horizontal direction
    the camera looks in, so the first view faces what the run saw first."""
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    d = None if view_dir is None else np.asarray(view_dir, dtype=np.float64)
    if d is not None:
        d = d - (d @ up) * up  # horizontal part
    if d is None or np.linalg.norm(d) < 1e-6:
        d = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    d = d / np.linalg.norm(d)
    el = np.deg2rad(elevation_deg)
    forward = np.cos(el) * d - np.sin(el) * up
    tan_v = np.tan(0.5 * float(fov))
    tan_h = tan_v * float(aspect)
    half = min(np.arctan(tan_v), np.arctan(tan_h * (1.0 - float(covered))))
    dist = 0.5 * float(extent) / np.sin(half) * _FIT_MARGIN
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    # slide camera and target sideways so that the map's centre sits in the middle of the visible part
    shift = float(covered) * dist * tan_h * right
    look_at = np.asarray(center, dtype=np.float64) + shift
    return look_at - dist * forward, look_at


class LiveViewer:
    """A viser server showing the map, the camera and the scene graph, with a control GUI per browser.

    ``host``/``port``: where to bind (viser moves to the next free port when ``port`` is busy; port 0
    picks any free port); :attr:`url` has the port actually bound. ConfigError when ``host``/``port``
    cannot be served (see :func:`check_bindable`). ``settings``: what each browser starts with. ``up``:
    the world up direction ("+z", "-y", ... or a vector). ``max_rate_hz`` bounds the push rate.
    ``control``: the mapping session behind the pause and save buttons (None when browsing a saved run).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8080,
        *,
        settings: ViewerSettings | None = None,
        up: str | np.ndarray | tuple | None = None,
        max_rate_hz: float = 4.0,
        control: MappingControl | None = None,
        title: str = "ogscene3d",
        verbose: bool = False,
    ) -> None:
        import viser

        if not max_rate_hz > 0:
            raise ValueError(f"max_rate_hz must be > 0, got {max_rate_hz}")
        self.settings = (settings or ViewerSettings()).validate()
        self.max_rate_hz = float(max_rate_hz)
        self.control = control
        self._up = _up_vector(up)  # checked before a server is started
        check_bindable(host, port)
        _quiet_websockets(verbose)
        self.server = viser.ViserServer(host=host, port=port, label=title, verbose=verbose)
        if self._up is not None:
            self.server.scene.set_up_direction(tuple(self._up))

        self._lock = threading.Lock()
        self._latest: MapSnapshot | None = None
        self._views: dict[int, BrowserView] = {}
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._last_publish = -np.inf
        self._last_push = -np.inf
        self._framed: tuple[np.ndarray, float] | None = None
        self._query_doc: dict | None = None  # the graph document _query_graph was built from
        self._query_graph = None
        self._query_error = ""
        self.stats = {"pushes": 0, "map_pushes": 0, "graph_pushes": 0, "errors": 0}
        self.pushed = threading.Condition()  # notified after every push (tests and tools wait on it)

        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._on_disconnect)
        self._thread = threading.Thread(target=self._loop, name="ogscene3d-viewer", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ public
    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        host = self.server.get_host()
        shown = "127.0.0.1" if host in ("0.0.0.0", "") else ("::1" if host == "::" else host)
        if ":" in shown and not shown.startswith("["):
            shown = f"[{shown}]"  # an IPv6 address in a URL
        return f"http://{shown}:{self.port}"

    @property
    def num_clients(self) -> int:
        return len(self.server.get_clients())

    @property
    def views(self) -> list[BrowserView]:
        """The connected browsers' views, oldest first."""
        with self._lock:
            return [self._views[k] for k in sorted(self._views)]

    def publish(self, snapshot: MapSnapshot) -> None:
        """Hand the viewer a new state. Never blocks on drawing: only the newest snapshot is kept."""
        with self._lock:
            self._latest = snapshot
            self._last_publish = time.monotonic()
        self._wake.set()

    def wants_snapshot(self) -> bool:
        """Whether a producer should build a new snapshot now: at most ``max_rate_hz`` per second, and
        only while a browser watches (or none has been published yet)."""
        with self._lock:
            if self._latest is None:
                return True
            due = time.monotonic() - self._last_publish >= 1.0 / self.max_rate_hz
        return due and self.num_clients > 0

    def shown(self) -> dict:
        """What the newest browser's scene holds (for tests and status): gaussians, render kind, nodes,
        edges; with the number of browsers and the push counters."""
        views = self.views
        layers = views[-1].layers if views else None
        return {
            "gaussians": layers.shown_gaussians if layers else 0,
            "render": layers.shown_kind if layers else "",
            "nodes": layers.shown_nodes if layers else 0,
            "edges": layers.shown_edges if layers else 0,
            "clients": self.num_clients,
            **self.stats,
        }

    def wait_until(self, predicate: Callable[[dict], bool], timeout: float) -> bool:
        """Block until ``predicate(self.shown())`` holds after a push, or ``timeout`` seconds pass."""
        deadline = time.monotonic() + timeout
        with self.pushed:
            while not predicate(self.shown()):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.pushed.wait(min(left, 0.25))
        return True

    def select_node(self, node_id: int | None) -> None:
        """Show a node's caption, confidence and relations in every browser's panel."""
        for view in self.views:
            view.select_node(node_id)

    def set_control(self, control: MappingControl | None) -> None:
        """Attach (or detach) the mapping session behind the pause and save buttons."""
        self.control = control
        for view in self.views:
            view.show_control()
            view.request("texts")

    def find(self, graph: dict | None, text: str) -> tuple[list[int], str]:
        """Ids of the nodes of ``graph`` (a graph.json document) that answer ``text``, best first, as
        ``ogscene3d graph -q`` answers it (:meth:`SceneGraph.ask`; a room found stands for the nodes in
        it), and the answer's message or an error text ("" when none)."""
        answer, error = self.answer(graph, text)
        if answer is None:
            return [], error
        return answer_ids(answer), answer.message

    def answer(self, graph: dict | None, text: str):
        """(the :class:`~ogscene3d.graph.query.QueryAnswer` to ``text`` over ``graph``, or None, and an error
        text). Runs on the push thread; the graph is rebuilt only when its document changes."""
        if not text.strip() or not graph:
            return None, ""
        if graph != self._query_doc:
            self._query_doc = graph
            try:
                self._query_graph = SceneGraph.from_json(graph, source="the shown graph")
                self._query_error = ""
            except OGSceneError as e:
                self._query_graph, self._query_error = None, f"Find is unavailable: {e}"
        if self._query_graph is None:
            return None, self._query_error
        return self._query_graph.ask(text), ""

    def close(self) -> None:
        """Stop the push thread and the server."""
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=10)
        self.server.stop()

    def __enter__(self) -> LiveViewer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ browsers
    def _on_connect(self, client) -> None:
        view = BrowserView(self, client)
        with self._lock:
            self._views[client.client_id] = view
        log.info("viewer: browser %d connected (%d now)", client.client_id, self.num_clients)
        self._wake.set()

    def _on_disconnect(self, client) -> None:
        with self._lock:
            self._views.pop(client.client_id, None)
        log.info("viewer: browser %d disconnected", client.client_id)

    # ------------------------------------------------------------------ push thread
    def _loop(self) -> None:
        while not self._stop.is_set():
            if not self._wake.wait(timeout=1.0) or self._stop.is_set():
                continue
            # Bound the update rate (GUI changes are drawn at the same bounded rate).
            wait = self._last_push + 1.0 / self.max_rate_hz - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                break
            self._wake.clear()
            with self._lock:
                snap = self._latest
                views = [self._views[k] for k in sorted(self._views)]
                work = [(v, v.take_dirty()) for v in views]
            if snap is None or not work:
                # Nobody watches: the newest snapshot waits for the first browser (which draws it all).
                if snap is not None:
                    with self._lock:
                        for v, dirty in work:
                            v.dirty |= dirty
                continue
            self._place_initial_camera(snap)
            for view, dirty in work:
                if view.pushed_snap is snap and not dirty:
                    continue
                try:
                    view.push(snap, dirty)
                except Exception:  # noqa: BLE001 - a drawing failure must never stop the viewer or the mapping
                    self.stats["errors"] += 1
                    log.exception("viewer: update of browser %d failed", view.client_id)
            self._last_push = time.monotonic()
            with self.pushed:
                self.stats["pushes"] += 1
                self.pushed.notify_all()

    def _place_initial_camera(self, snap: MapSnapshot) -> None:
        """The camera a browser opens with (and "Reset View" returns to): fitted to the map's bounds,
        following them as the map grows."""
        if not len(snap):
            return

        c, ext = scene_bounds(snap.means)
        if self._framed is not None:
            c0, ext0 = self._framed
            if np.linalg.norm(c - c0) < 0.1 * ext0 and abs(ext - ext0) < 0.2 * ext0:
                return
        eye, target = fit_camera(c, ext, self.up, self.server.initial_camera.fov, first_view_dir(snap))
        self.server.initial_camera.look_at = tuple(target)
        self.server.initial_camera.position = tuple(eye)
        self._framed = (c, ext)

    @property
    def up(self) -> np.ndarray:
        """The world up direction the cameras keep (``up``, else +z as viser's default)."""
        return self._up if self._up is not None else np.array([0.0, 0.0, 1.0])


def first_view_dir(snap: MapSnapshot) -> np.ndarray | None:
    """The viewing direction (camera +z, OpenCV axes) of the run's first pose, if the snapshot has one."""
    if len(snap.trajectory):
        return snap.trajectory[0][:3, 2]
    if snap.pose is not None:
        return snap.pose[:3, 2]
    return None


class BrowserView:
    """One browser: its GUI, its scene layers and its display state (colour mode, Find text, selected
    node, layer switches). Built when the browser connects, from the viewer's start settings."""

    def __init__(self, viewer: LiveViewer, client) -> None:
        self.viewer = viewer
        self.client = client
        self.client_id = int(client.client_id)
        self.settings = dataclasses.replace(viewer.settings)
        self.layers = SceneLayers(client, on_node_click=self.select_node)
        self.query = ""
        self.selected: int | None = None
        self.dirty: set[str] = {"map", "graph", "visibility"}
        self.pushed_snap: MapSnapshot | None = None  # the published snapshot last drawn
        # the published snapshot whose map is shown, held: without a map_rev it is recognised by identity
        self._shown_map_snap: MapSnapshot | None = None
        self._shown_graph_key: tuple | None = None
        self._shown_rooms_key: str | None = None  # the rooms the map's room colours show
        self._shown_texts: dict[str, str] = {}
        self._camera_goal: np.ndarray | None = None  # where _place_camera put the camera
        self._camera_again = False
        self._camera_tries = 0
        client.camera.on_update(self._on_camera)
        self._build_gui()

    # ------------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        gui = self.client.gui
        st = self.settings
        control = self.viewer.control
        with gui.add_folder("Mapping"):
            self._md_status = gui.add_markdown("**Status:** waiting for data")
            self._btn_pause = gui.add_button("Pause mapping", icon=None, disabled=control is None)
            self._btn_pause.on_click(lambda _: self._toggle_pause())
            self._md_counts = gui.add_markdown("")
            self._md_timings = gui.add_markdown("")
        with gui.add_folder("Display"):
            self._dd_color = gui.add_dropdown(
                "Color", [_COLOR_LABELS[m] for m in COLOR_MODES], initial_value=_COLOR_LABELS[st.color_mode]
            )
            self._dd_render = gui.add_dropdown(
                "Render",
                [_RENDER_LABELS[m] for m in RENDER_MODES],
                initial_value=_RENDER_LABELS[st.render],
                hint="Auto: splats up to the splat budget, points beyond it",
            )
            self._sl_point = gui.add_slider(
                "Point size (cm)", 0.0, 5.0, 0.1, round(st.point_size * 100, 1), hint="points mode; 0 = auto"
            )
            self._dd_color.on_update(lambda _: self._on_display_change())
            self._dd_render.on_update(lambda _: self._on_display_change())
            self._sl_point.on_update(lambda _: self._on_display_change())
            self._cb = {}
            for key, label, hint in (
                ("show_gaussians", "Gaussians", None),
                ("show_trajectory", "Trajectory", None),
                ("show_camera", "Current camera", None),
                ("show_nodes", "Graph nodes", None),
                ("show_edges", "Graph edges", None),
                ("show_edge_labels", "All relation labels", "otherwise only the selected node's"),
                ("show_rooms", "Rooms", "each room's outline at floor height with its type"),
            ):
                cb = gui.add_checkbox(label, initial_value=getattr(st, key), hint=hint)
                cb.on_update(lambda _, key=key: self._on_toggle(key))
                self._cb[key] = cb
        with gui.add_folder("Legend"):
            self._html_legend = gui.add_html("")
        with gui.add_folder("Scene graph"):
            self._txt_query = gui.add_text(
                "Find",
                initial_value="",
                hint='an object, a relation, a room: "pillow on the bed", "chair in the kitchen", "kitchen", '
                "#id (as ogscene3d graph -q)",
            )
            self._txt_query.on_update(lambda _: self._on_query())
            self._md_matches = gui.add_markdown("")
            self._dd_node = gui.add_dropdown("Node", (_NO_NODE,), hint="show a node's caption and relations")
            # Programmatic changes (event.client is None) come from the push thread itself: ignore them.
            self._dd_node.on_update(
                lambda e: None if e.client is None else self._on_node_pick(self._dd_node.value)
            )
            self._md_selected = gui.add_markdown("*Pick a node above or click its marker.*")
        with gui.add_folder("Save"):
            self._txt_out = gui.add_text("Run dir", initial_value="", disabled=True)
            self._btn_save = gui.add_button(
                "Save run", disabled=True, hint="write gaussians.ply, map.npz, graph.json, ... to Run dir"
            )
            self._btn_save.on_click(lambda _: self._on_save())
            self._md_save = gui.add_markdown("")
        self.show_control()

    def show_control(self) -> None:
        """Enable the pause and save controls while a mapping session is attached and running."""
        control = self.viewer.control
        live = control is not None
        done = live and bool(getattr(control, "done", False))
        self._btn_pause.disabled = not live or done
        self._btn_pause.label = _pause_label(control)
        self._btn_save.disabled = not live
        self._txt_out.disabled = not live
        if live and not self._txt_out.value:
            self._txt_out.value = str(control.default_out_dir)
        self._md_save.content = "" if live else "*Browsing a saved run.*"

    def request(self, *what: str) -> None:
        with self.viewer._lock:
            self.dirty.update(what)
        self.viewer._wake.set()

    def take_dirty(self) -> set[str]:
        """The changes asked for since the last push (call with the viewer's lock held)."""
        dirty, self.dirty = self.dirty, set()
        return dirty

    def select_node(self, node_id: int | None) -> None:
        """Show a node's caption, confidence and relations (the click handler of a node marker)."""
        self.selected = node_id
        self.request("graph", "details")

    def _on_display_change(self) -> None:
        inv_c = {v: k for k, v in _COLOR_LABELS.items()}
        inv_r = {v: k for k, v in _RENDER_LABELS.items()}
        self.settings.color_mode = inv_c[self._dd_color.value]
        self.settings.render = inv_r[self._dd_render.value]
        self.settings.point_size = float(self._sl_point.value) / 100.0
        self.request("map")

    def _on_toggle(self, key: str) -> None:
        setattr(self.settings, key, bool(self._cb[key].value))
        self.request("visibility", *(("graph",) if key == "show_edge_labels" else ()))

    def _on_query(self) -> None:
        self.query = str(self._txt_query.value)
        self.request("map", "graph", "details")

    def _on_node_pick(self, option: str) -> None:
        """A node picked in the GUI list: options read "#<id> <text>"."""
        if option == _NO_NODE or not option.startswith("#"):
            self.select_node(None)
            return
        try:
            self.select_node(int(option[1:].split(" ", 1)[0]))
        except ValueError:
            self.select_node(None)

    def _toggle_pause(self) -> None:
        control = self.viewer.control
        if control is None or getattr(control, "done", False):
            return
        control.set_paused(not control.paused)
        for view in self.viewer.views:  # every browser shows the one session's state
            view.request("texts")

    def _on_save(self) -> None:
        control = self.viewer.control
        if control is None:
            return
        out = self._txt_out.value.strip() or str(control.default_out_dir)
        self._btn_save.disabled = True
        self._md_save.content = f"Saving to `{out}` ..."
        try:
            path = control.save(out)
            self._md_save.content = f"Saved to `{path}`"
        except Exception as e:  # noqa: BLE001 - report in the GUI, keep serving
            log.exception("saving the run to %s failed", out)
            self._md_save.content = f"**Save failed:** {type(e).__name__}: {e}"
        finally:
            self._btn_save.disabled = False

    # ------------------------------------------------------------------ drawing (push thread)
    def _shows_map_of(self, snap: MapSnapshot) -> bool:
        """Whether the map shown is ``snap``'s: the same map revision and size, or without a revision the
        very snapshot object."""
        shown = self._shown_map_snap
        if shown is None:
            return False
        if snap.map_rev is None:
            return snap is shown
        return snap.map_rev == shown.map_rev and len(snap) == len(shown)

    def push(self, published: MapSnapshot, dirty: set[str]) -> None:
        """Send this browser what changed since its last push."""
        # compared as published, not as finite()'s copy (a new object at every push)
        same_map = self._shows_map_of(published)
        snap = published.finite()
        st = self.settings
        graph = drawable_graph(snap.graph)
        answer, error = self.viewer.answer(graph, self.query)
        found = answer_ids(answer) if answer is not None else []
        matches = set(found)
        stats = self.viewer.stats
        with self.client.atomic():
            rooms_key = json.dumps((graph or {}).get("rooms")) if st.color_mode == "room" else None
            if not same_map or "map" in dirty or rooms_key != self._shown_rooms_key:
                self.layers.update_bounds(snap)
                self.layers.update_map(snap, st, matches or None, graph, self.viewer.up)
                self._shown_rooms_key = rooms_key
                self._shown_map_snap = published
                stats["map_pushes"] += 1
            if len(snap) and (self._camera_goal is None or self._camera_again):
                self._place_camera(snap)
            self.layers.update_camera(snap, st)
            graph_key = (graph, frozenset(matches), self.selected, st.show_edge_labels)
            if graph_key != self._shown_graph_key or "graph" in dirty:
                self.layers.update_graph(graph, st, matches, self.selected)
                self._shown_graph_key = graph_key
                stats["graph_pushes"] += 1
            self.layers.update_rooms(graph, st)
            if "visibility" in dirty:
                self.layers.apply_visibility(st)
            self._update_texts(snap, graph, found, error, answer)
        self.pushed_snap = published

    def _place_camera(self, snap: MapSnapshot) -> None:
        """Move this browser's camera to the whole-map view fitted to its canvas (left of the GUI panel)
        when it first gets Gaussians; later the user drives ("Reset View" returns to the viewer's initial
        camera, which follows the map's bounds)."""
        camera = self.client.camera
        if camera.update_timestamp == 0.0:
            # the browser has not reported its camera yet (viser cannot move it before): next push
            self.request("camera")
            return
        w, h = max(int(camera.image_width), 1), max(int(camera.image_height), 1)
        eye, target = fit_camera(
            self.layers.center,
            self.layers.extent,
            self.viewer.up,
            camera.fov,
            first_view_dir(snap),
            aspect=w / h,
            covered=min(_PANEL_PX / w, 0.5) if w >= 2 * _PANEL_PX else 0.0,
        )
        self._camera_goal = np.asarray(eye, dtype=np.float64)
        self._camera_again = False
        self._camera_tries += 1
        camera.up_direction = tuple(self.viewer.up)
        camera.position = tuple(eye)  # moves look_at along: set it after
        camera.look_at = tuple(target)

    def _on_camera(self, camera) -> None:
        """A camera report from the browser. It resets its camera to the initial camera when that first
        arrives, which can overtake the move of :meth:`_place_camera` (they travel apart): a browser seen
        back at the initial camera is moved again (a few times at most)."""
        goal = self._camera_goal
        if goal is None or self._camera_tries >= _CAMERA_TRIES:
            return
        initial = np.asarray(self.viewer.server.initial_camera.position, dtype=np.float64)
        tol = 1e-3 * max(self.layers.extent, 1e-3)
        if np.linalg.norm(camera.position - initial) < tol < np.linalg.norm(goal - initial):
            self._camera_again = True
            self.request("camera")

    @property
    def camera_placed(self) -> bool:
        """Whether this browser's camera is (as last reported) at the whole-map view it was given."""
        goal = self._camera_goal
        tol = 1e-3 * max(self.layers.extent, 1e-3)
        return goal is not None and bool(np.linalg.norm(self.client.camera.position - goal) < tol)

    def _set_text(self, handle, key: str, text: str) -> None:
        if self._shown_texts.get(key) != text:
            handle.content = text
            self._shown_texts[key] = text

    def _update_texts(
        self, snap: MapSnapshot, graph: dict | None, found: list[int], error: str, answer=None
    ) -> None:
        control = self.viewer.control
        status = snap.status or "running"
        if control is not None and control.paused and not getattr(control, "done", False):
            status += " (paused)"
        self._set_text(self._md_status, "status", f"**Status:** {status}")
        label, disabled = _pause_label(control), control is None or bool(getattr(control, "done", False))
        if self._btn_pause.label != label:
            self._btn_pause.label = label
        if self._btn_pause.disabled != disabled:
            self._btn_pause.disabled = disabled
        counts = dict(snap.counts)
        counts.setdefault("gaussians", snap.total_gaussians)
        nodes = (graph or {}).get("nodes", [])
        rows = [
            f"| {k} | {int(v) if float(v).is_integer() else round(float(v), 3)} |" for k, v in counts.items()
        ]
        rows += [
            f"| graph nodes | {len(nodes)} |",
            f"| graph edges | {len((graph or {}).get('edges', []))} |",
        ]
        shown = (
            f"{self.layers.shown_gaussians} as {self.layers.shown_kind}" if self.layers.shown_kind else "0"
        )
        rows.append(f"| shown | {shown} |")
        self._set_text(self._md_counts, "counts", "| | |\n|---|---:|\n" + "\n".join(rows))
        if snap.timings:
            t_rows = [f"| {k} | {v:.1f} |" for k, v in sorted(snap.timings.items(), key=lambda kv: -kv[1])]
            self._set_text(
                self._md_timings, "timings", "| module | ms/keyframe |\n|---|---:|\n" + "\n".join(t_rows)
            )
        legend = legend_html(self.settings.color_mode, graph)
        if self._shown_texts.get("legend") != legend:
            self._html_legend.content = legend or "<small>RGB: the Gaussians' own colours</small>"
            self._shown_texts["legend"] = legend
        by_id = {int(n["id"]): n for n in nodes}
        if error:
            self._set_text(self._md_matches, "matches", f"*{error}*")
        elif self.query.strip() and answer is not None:
            lines = [
                f"- **{node_text(by_id[h.id]) if h.kind == 'object' and h.id in by_id else h.node.type}** "
                f"({'#' if h.kind == 'object' else 'room #'}{h.id}, score {h.score:.2f}): {h.reason}"
                for h in answer.hits[:20]
            ]
            more = f"\n- ... {len(answer.hits) - 20} more" if len(answer.hits) > 20 else ""
            note = f"\n\n*{answer.message}*" if answer.message else ""
            text = f"{len(answer.hits)} match(es)\n" + "\n".join(lines) + more + note
            self._set_text(self._md_matches, "matches", text)
        else:
            self._set_text(self._md_matches, "matches", "")
        self._set_text(self._md_selected, "selected", node_details(graph, self.selected))
        listed = [by_id[i] for i in found if i in by_id] if self.query.strip() else nodes
        options = (_NO_NODE, *(f"#{n['id']} {node_text(n)}" for n in listed[:_MAX_NODE_OPTIONS]))
        if tuple(self._dd_node.options) != options:
            self._dd_node.options = options
        want = next((o for o in options if o.startswith(f"#{self.selected} ")), _NO_NODE)
        if self._dd_node.value != want:
            self._dd_node.value = want


def answer_ids(answer) -> list[int]:
    """The node ids a query answer points at, best first: its object hits, and for a room hit the nodes in
    the room."""
    ids: list[int] = []
    for h in answer.hits:
        for i in [h.id] if h.kind == "object" else h.node.objects:
            if i not in ids:
                ids.append(i)
    return ids


def _pause_label(control: MappingControl | None) -> str:
    if control is not None and getattr(control, "done", False):
        return "Mapping finished"
    return "Resume mapping" if control is not None and control.paused else "Pause mapping"


def _fmt_size(v: np.ndarray) -> str:
    return " x ".join(f"{float(x):.2f}" for x in v) + " m"


def node_details(graph: dict | None, selected: int | None) -> str:
    """The node panel (markdown): text, id, confidence, caption and its source, Gaussians, size, relations.

    The size is the one the heuristic caption's "about ..." is: the node's robust extents along its
    principal axes, the axis of largest spread first (graph.json ``extent``); the axis-aligned box of
    all its Gaussians, which outliers and the axes' orientation make larger, is given apart as "box"."""
    if selected is None:
        return "*Pick a node above or click its marker.*"
    nodes = {int(n["id"]): n for n in (graph or {}).get("nodes", [])}
    node = nodes.get(selected)
    if node is None:
        return f"*Node #{selected} is no longer in the graph.*"
    lines = [
        f"**{node_text(node)}** (node #{node['id']})",
        f"confidence: {float(node.get('confidence', 0.0)):.3f}",
    ]
    if node.get("caption"):
        lines.append(caption_line(node))
    if "num_gaussians" in node:
        lines.append(f"Gaussians: {node['num_gaussians']}")
    if "extent" in node:
        lines.append(f"size: {_fmt_size(np.asarray(node['extent'], float))} (principal axes, 2-98 %)")
    if "bbox_min" in node and "bbox_max" in node:
        size = np.asarray(node["bbox_max"], float) - np.asarray(node["bbox_min"], float)
        lines.append(f"box: {_fmt_size(size)} (x, y, z; all Gaussians)")
    for e in (graph or {}).get("edges", []):
        s, t = int(e["source"]), int(e["target"])
        if selected in (s, t) and s in nodes and t in nodes:
            lines.append(f"- {node_text(nodes[s])} *{e.get('relation', '')}* {node_text(nodes[t])}")
    return "\n\n".join(lines)


__all__ = ["BrowserView", "LiveViewer", "MappingControl", "fit_camera", "node_details"]
