"""The live viewer: a viser server, its GUI and a push thread that draws the latest :class:`MapSnapshot`.

Threading: producers (the mapping thread, a run loader, a test) call :meth:`LiveViewer.publish`, which
only stores a reference under a lock and never waits on the network or the browser. One push thread
takes the newest snapshot at most ``max_rate_hz`` times per second and sends what changed. GUI
callbacks (viser's thread pool) only edit settings and wake the push thread, so every scene update
happens on one thread. Scene nodes are server-wide: every browser sees the same scene, and viser replays
the current state to browsers that connect late. While no browser is connected nothing is pushed (the
newest snapshot waits), so an unwatched viewer costs the mapping nothing but the snapshot copies.
"""

from __future__ import annotations

import errno
import logging
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np

from ..errors import ConfigError
from .scene import (
    COLOR_MODES,
    RENDER_MODES,
    SceneLayers,
    ViewerSettings,
    drawable_graph,
    node_matches,
    node_text,
)
from .snapshot import MapSnapshot

log = logging.getLogger(__name__)

_COLOR_LABELS = {"rgb": "RGB", "semantic": "Semantic label", "confidence": "Confidence"}
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


class LiveViewer:
    """A viser server showing the map, the camera and the scene graph, with a control GUI.

    ``host``/``port``: where to bind (viser moves to the next free port when ``port`` is busy; port 0
    picks any free port); :attr:`url` has the port actually bound. ConfigError when ``host``/``port``
    cannot be served (see :func:`check_bindable`). ``up``: the world up direction
    ("+z", "-y", ... or a vector). ``max_rate_hz`` bounds the push rate. ``control``: the mapping
    session behind the pause and save buttons (None when browsing a saved run).
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
        self.layers = SceneLayers(self.server, on_node_click=self.select_node)

        self._lock = threading.Lock()
        self._latest: MapSnapshot | None = None
        self._dirty: set[str] = set()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._last_publish = -np.inf
        self._last_push = -np.inf
        # the published snapshot whose map is shown, held: without a map_rev it is recognised by identity
        self._shown_map_snap: MapSnapshot | None = None
        self._shown_graph: dict | None = None
        self._shown_texts: dict[str, str] = {}
        self._camera_placed = False
        self._framed: tuple[np.ndarray, float] | None = None
        self._selected: int | None = None
        self._query = ""
        self.stats = {"pushes": 0, "map_pushes": 0, "graph_pushes": 0, "errors": 0}
        self.pushed = threading.Condition()  # notified after every push (tests and tools wait on it)

        self._build_gui()
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
        """What the scene holds now (for tests and status): gaussians, render kind, nodes, edges."""
        return {
            "gaussians": self.layers.shown_gaussians,
            "render": self.layers.shown_kind,
            "nodes": self.layers.shown_nodes,
            "edges": self.layers.shown_edges,
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
        """Show a node's caption, confidence and relations in the GUI (the click handler of a node)."""
        self._selected = node_id
        self._request("details")

    def set_control(self, control: MappingControl | None) -> None:
        """Attach (or detach) the mapping session behind the pause and save buttons."""
        self.control = control
        live = control is not None
        self._btn_pause.disabled = not live
        self._btn_pause.label = "Resume mapping" if live and control.paused else "Pause mapping"
        self._btn_save.disabled = not live
        self._txt_out.disabled = not live
        if live:
            self._txt_out.value = str(control.default_out_dir)
        self._md_save.content = "" if live else "*Browsing a saved run.*"
        self._request("texts")

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

    # ------------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        gui = self.server.gui
        st = self.settings
        with gui.add_folder("Mapping"):
            self._md_status = gui.add_markdown("**Status:** waiting for data")
            self._btn_pause = gui.add_button("Pause mapping", icon=None, disabled=self.control is None)
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
            for key, label in (
                ("show_gaussians", "Gaussians"),
                ("show_trajectory", "Trajectory"),
                ("show_camera", "Current camera"),
                ("show_nodes", "Graph nodes"),
                ("show_edges", "Graph edges"),
                ("show_edge_labels", "Relation labels"),
            ):
                cb = gui.add_checkbox(label, initial_value=getattr(st, key))
                cb.on_update(lambda _, key=key: self._on_toggle(key))
                self._cb[key] = cb
        with gui.add_folder("Scene graph"):
            self._txt_query = gui.add_text(
                "Find", initial_value="", hint="substring of a node's tag or caption"
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
            default = str(self.control.default_out_dir) if self.control is not None else ""
            self._txt_out = gui.add_text("Run dir", initial_value=default, disabled=self.control is None)
            self._btn_save = gui.add_button(
                "Save run",
                disabled=self.control is None,
                hint="write gaussians.ply, map.npz, graph.json, ... to Run dir",
            )
            self._btn_save.on_click(lambda _: self._on_save())
            self._md_save = gui.add_markdown("" if self.control is not None else "*Browsing a saved run.*")

    def _request(self, *what: str) -> None:
        with self._lock:
            self._dirty.update(what)
        self._wake.set()

    def _on_display_change(self) -> None:
        inv_c = {v: k for k, v in _COLOR_LABELS.items()}
        inv_r = {v: k for k, v in _RENDER_LABELS.items()}
        self.settings.color_mode = inv_c[self._dd_color.value]
        self.settings.render = inv_r[self._dd_render.value]
        self.settings.point_size = float(self._sl_point.value) / 100.0
        self._request("map")

    def _on_toggle(self, key: str) -> None:
        setattr(self.settings, key, bool(self._cb[key].value))
        self._request("visibility")

    def _on_query(self) -> None:
        self._query = str(self._txt_query.value)
        self._request("map", "graph", "details")

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
        if self.control is None:
            return
        self.control.set_paused(not self.control.paused)
        self._btn_pause.label = "Resume mapping" if self.control.paused else "Pause mapping"
        self._request("texts")

    def _on_save(self) -> None:
        if self.control is None:
            return
        out = self._txt_out.value.strip() or str(self.control.default_out_dir)
        self._btn_save.disabled = True
        self._md_save.content = f"Saving to `{out}` ..."
        try:
            path = self.control.save(out)
            self._md_save.content = f"Saved to `{path}`"
        except Exception as e:  # noqa: BLE001 - report in the GUI, keep serving
            log.exception("saving the run to %s failed", out)
            self._md_save.content = f"**Save failed:** {type(e).__name__}: {e}"
        finally:
            self._btn_save.disabled = False

    def _on_connect(self, client) -> None:
        log.info("viewer: browser %d connected (%d now)", client.client_id, self.num_clients)
        self._request("connect")

    def _on_disconnect(self, client) -> None:
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
                snap, dirty = self._latest, self._dirty
                self._dirty = set()
            if snap is None:
                continue
            if self.num_clients == 0:
                # Nobody watches: keep the newest snapshot for the first browser (and late GUI changes).
                with self._lock:
                    self._dirty |= dirty
                continue
            try:
                self._push(snap, dirty)
            except Exception:  # noqa: BLE001 - a drawing failure must never stop the viewer or the mapping
                self.stats["errors"] += 1
                log.exception("viewer: update failed")
            self._last_push = time.monotonic()
            with self.pushed:
                self.stats["pushes"] += 1
                self.pushed.notify_all()

    def _matches(self, graph: dict | None) -> set[int]:
        if not self._query.strip() or not graph:
            return set()
        return {int(n["id"]) for n in graph.get("nodes", []) if node_matches(n, self._query)}

    def _shows_map_of(self, snap: MapSnapshot) -> bool:
        """Whether the map shown is ``snap``'s: the same map revision and size, or without a revision the
        very snapshot object."""
        shown = self._shown_map_snap
        if shown is None:
            return False
        if snap.map_rev is None:
            return snap is shown
        return snap.map_rev == shown.map_rev and len(snap) == len(shown)

    def _push(self, snap: MapSnapshot, dirty: set[str]) -> None:
        # compared as published, not as finite()'s copy (a new object at every push)
        same_map = self._shows_map_of(snap)
        published = snap
        snap = snap.finite()
        st = self.settings
        graph = drawable_graph(snap.graph)
        matches = self._matches(graph)
        with self.server.atomic():
            if not same_map or "map" in dirty:
                self.layers.update_bounds(snap)
                self.layers.update_map(snap, st, matches or None)
                self._shown_map_snap = published
                self.stats["map_pushes"] += 1
                if len(snap):
                    self._place_camera(snap.trajectory)
            self.layers.update_camera(snap, st)
            if graph != self._shown_graph or "graph" in dirty:
                self.layers.update_graph(graph, st, matches)
                self._shown_graph = graph
                self.stats["graph_pushes"] += 1
            if "visibility" in dirty:
                self.layers.apply_visibility(st)
            self._update_texts(snap, graph, matches)

    def _place_camera(self, traj: np.ndarray | None = None) -> None:
        """Frame the map: the start and "Reset View" pose follow the map's bounds as they grow; browsers
        already open are moved only once, when the map first has Gaussians (later the user drives)."""
        c, ext = self.layers.center, self.layers.extent
        if self._camera_placed and self._framed is not None:
            c0, ext0 = self._framed
            if np.linalg.norm(c - c0) < 0.1 * ext0 and abs(ext - ext0) < 0.2 * ext0:
                return
        up = self._up if self._up is not None else np.array([0.0, 0.0, 1.0])
        if traj is not None and len(traj):
            # Start behind and above the first camera of the run: scans are mostly seen from the inside
            # (rooms), where a view from outside would look at the backs of the walls.
            first = traj[0]
            eye = first[:3, 3] - 0.15 * ext * first[:3, 2] + 0.1 * ext * up
        else:
            side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
            side /= np.linalg.norm(side)
            fwd = np.cross(side, up)
            eye = c + 0.75 * ext * (0.7 * side + 0.7 * fwd + 0.6 * up)
        self.server.initial_camera.look_at = tuple(c)
        self.server.initial_camera.position = tuple(eye)
        if not self._camera_placed:
            for client in self.server.get_clients().values():
                client.camera.look_at = tuple(c)
                client.camera.position = tuple(eye)
        self._camera_placed = True
        self._framed = (c, ext)

    def _set_text(self, handle, key: str, text: str) -> None:
        if self._shown_texts.get(key) != text:
            handle.content = text
            self._shown_texts[key] = text

    def _update_texts(self, snap: MapSnapshot, graph: dict | None, matches: set[int]) -> None:
        status = snap.status or "running"
        if self.control is not None:
            paused = self.control.paused
            status += " (paused)" if paused else ""
            label = "Resume mapping" if paused else "Pause mapping"
            if self._btn_pause.label != label:
                self._btn_pause.label = label
        self._set_text(self._md_status, "status", f"**Status:** {status}")
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
        if self._query.strip():
            hits = [n for n in nodes if int(n["id"]) in matches]
            lines = [
                f"- **{node_text(n)}** (#{n['id']}, conf {float(n.get('confidence', 0)):.2f})"
                for n in hits[:20]
            ]
            more = f"\n- ... {len(hits) - 20} more" if len(hits) > 20 else ""
            self._set_text(self._md_matches, "matches", f"{len(hits)} match(es)\n" + "\n".join(lines) + more)
        else:
            self._set_text(self._md_matches, "matches", "")
        self._set_text(self._md_selected, "selected", self._details(graph))
        listed = [n for n in nodes if int(n["id"]) in matches] if self._query.strip() else nodes
        options = (_NO_NODE, *(f"#{n['id']} {node_text(n)}" for n in listed[:_MAX_NODE_OPTIONS]))
        if tuple(self._dd_node.options) != options:
            self._dd_node.options = options
        want = next((o for o in options if o.startswith(f"#{self._selected} ")), _NO_NODE)
        if self._dd_node.value != want:
            self._dd_node.value = want

    def _details(self, graph: dict | None) -> str:
        if self._selected is None:
            return "*Pick a node above or click its marker.*"
        nodes = {int(n["id"]): n for n in (graph or {}).get("nodes", [])}
        node = nodes.get(self._selected)
        if node is None:
            return f"*Node #{self._selected} is no longer in the graph.*"
        lines = [
            f"**{node_text(node)}** (node #{node['id']})",
            f"confidence: {float(node.get('confidence', 0.0)):.3f}",
        ]
        if node.get("caption"):
            lines.append(caption_line(node))
        if "num_gaussians" in node:
            lines.append(f"Gaussians: {node['num_gaussians']}")
        if "bbox_min" in node and "bbox_max" in node:
            size = np.asarray(node["bbox_max"], float) - np.asarray(node["bbox_min"], float)
            lines.append("size: " + " x ".join(f"{v:.2f}" for v in size) + " m")
        for e in (graph or {}).get("edges", []):
            s, t = int(e["source"]), int(e["target"])
            if self._selected in (s, t) and s in nodes and t in nodes:
                lines.append(f"- {node_text(nodes[s])} *{e.get('relation', '')}* {node_text(nodes[t])}")
        return "\n\n".join(lines)


__all__ = ["LiveViewer", "MappingControl"]
