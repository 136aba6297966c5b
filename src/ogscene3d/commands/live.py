"""``ogscene3d-live`` (also ``ogscene3d live``): watch mapping live in a browser, or browse a saved run.

    ogscene3d-live RUN_DIR                          browse gaussians.ply + graph.json of a run
    ogscene3d-live --data SCENE [--segments S]      map SCENE live
    ogscene3d-live --synthetic                      generate the synthetic scene and map it live

The server binds 127.0.0.1 unless ``--host`` says otherwise and prints the URL with the port it got.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import threading
import time
from pathlib import Path

from ..atomic import atomic_write_bytes
from ..cli_types import add_rerun_arguments, add_size_argument, port, positive_float, positive_int
from ..config import load_config
from ..errors import ConfigError, DataError, OGSceneError
from ..runs import RunFolder, run_directory
from ..viewer.headless import HeadlessBrowser, find_chromium
from .options import add_override_argument, add_shared_arguments
from .run import run_observers

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Every option of ``ogscene3d live`` / ``ogscene3d-live``, in the order ``--help`` lists them."""
    _add_session_arguments(p)
    _add_viewer_arguments(p)
    add_rerun_arguments(p)


def _add_session_arguments(p: argparse.ArgumentParser) -> None:
    """What to show: a saved run, or what to map live (data, the synthetic scene, a camera) and how."""
    p.add_argument(
        "run_dir", nargs="?", default=None, metavar="RUN_DIR", help="saved run directory to browse"
    )
    src = p.add_mutually_exclusive_group()
    add_shared_arguments(src, "--data", data="dataset folder to map live (Replica, ScanNet, TUM, ...)")
    src.add_argument("--synthetic", action="store_true", help="generate the synthetic scene and map it live")
    src.add_argument(  # robot input (#27): ogscene3d.streams
        "--source",
        default=None,
        help="live camera to map: realsense[:SERIAL], realsense:RECORDING.db3, record3d[:DEVICE_INDEX]",
    )
    add_shared_arguments(
        p,
        "--config",
        "--segments",
        "--device",
        "--max-frames",
        "--out",
        config="YAML config (e.g. configs/replica.yaml)",
        device="mapping device: cpu, cuda or cuda:N",
        max_frames={
            "type": positive_int,
            "help": "map at most this many frames (--synthetic: the scene is generated with at most this "
            "many)",
        },
        out={
            "required": False,
            "help": "run directory written at the end of live mapping (and the default of the GUI's save "
            "box)",
        },
    )
    p.add_argument(
        "--synthetic-dir",
        default=None,
        help="where --synthetic writes its scene (default: OUT/scene, else outputs/live-synthetic)",
    )
    add_override_argument(p, "mapping.optimize.iters=5")


def _add_viewer_arguments(p: argparse.ArgumentParser) -> None:
    """Where the viewer serves, how it draws the map, when it stops, and the headless screenshot."""
    p.add_argument(
        "--host", default="127.0.0.1", help="address to bind (0.0.0.0 exposes the viewer to the network)"
    )
    p.add_argument(
        "--port",
        type=port,
        default=8080,
        help="port to try first (the next free one is used if busy; 0: any free port)",
    )
    p.add_argument("--rate", type=positive_float, default=4.0, help="maximum viewer updates per second")

    p.add_argument("--max-splats", type=positive_int, default=200_000, help="most Gaussians drawn as splats")
    p.add_argument(
        "--max-points", type=positive_int, default=1_000_000, help="most Gaussians drawn as points"
    )
    p.add_argument(
        "--render",
        choices=["auto", "splats", "points"],
        default="auto",
        help="auto: splats up to --max-splats, points beyond",
    )
    p.add_argument(
        "--color", choices=["rgb", "semantic", "confidence", "room"], default="rgb", help="initial colouring"
    )
    p.add_argument(
        "--up",
        default=None,
        choices=["+x", "-x", "+y", "-y", "+z", "-z"],
        help="world up direction (default: the config's graph.up_axis)",
    )

    p.add_argument(
        "--exit-when-done", action="store_true", help="stop serving once live mapping has finished"
    )
    p.add_argument(
        "--screenshot",
        default=None,
        metavar="PNG",
        help="render the view in headless chromium into PNG and exit (after mapping, in live mode)",
    )
    add_size_argument(p, "--screenshot-size", "screenshot size", minimum=64, default=(1280, 800))
    p.add_argument(
        "--screenshot-wait", type=positive_float, default=8.0, help="seconds to let the browser draw first"
    )


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "live",
        help="live web viewer of the map and the scene graph (viser)",
        description=(__doc__ or "").split("\n\n")[0],
    )
    add_arguments(p)
    p.set_defaults(func=run)


def _up_from_config(cfg) -> tuple[float, float, float]:
    from ..up_axis import up_vector

    # load_config's check_config has made sure it is auto or a finite non-zero 3-vector; auto not chosen when
    # the dataset opened (a live camera): an upright first camera's up, as odometry's world has it
    return up_vector(cfg.graph.up_axis)


def _settings(args):
    from ..viewer.scene import ViewerSettings

    try:
        return ViewerSettings(
            color_mode=args.color, render=args.render, max_splats=args.max_splats, max_points=args.max_points
        ).validate()
    except ValueError as e:
        raise ConfigError(f"viewer settings: {e}") from e


def _serve_forever(viewer, stop: threading.Event, session=None, exit_when_done: bool = False) -> None:
    while not stop.wait(0.5):
        if session is not None and session.done and exit_when_done:
            break


_CLOSE_NOTIFICATIONS = (
    "document.querySelectorAll('.mantine-Notification-root button, .mantine-Notification-closeButton')"
    ".forEach(b => b.click())"
)


def take_screenshot(
    viewer, out: str | Path, size: tuple[int, int] = (1280, 800), wait: float = 8.0, timeout: float = 180.0
) -> Path:
    """Open the viewer in headless chromium and write a PNG once the picture has settled.

    After ``wait`` seconds, screenshots are taken until two in a row are identical (the splats are
    sorted and faded in; software WebGL can take tens of seconds for the first full frame) or
    ``timeout`` seconds have passed.
    """
    if find_chromium() is None:
        raise ConfigError("--screenshot needs chromium (e.g. apt-get install chromium)")
    before = viewer.stats["pushes"]
    deadline = time.monotonic() + timeout
    with HeadlessBrowser(viewer.url, *size) as browser:
        if not viewer.wait_until(lambda s: s["clients"] > 0 and s["pushes"] > before, timeout=60):
            raise OGSceneError(f"the headless browser did not connect: {browser.log_tail()}")
        time.sleep(wait)
        # headless chromium draws with software WebGL, and viser says so in a notification over the view:
        # close it, the picture is of the map
        browser.call("Runtime.evaluate", {"expression": _CLOSE_NOTIFICATIONS})
        png, previous = browser.screenshot(), b""
        while png != previous and time.monotonic() < deadline:
            time.sleep(1.0)
            png, previous = browser.screenshot(), png
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, png)
    return out


def run(args: argparse.Namespace) -> int:
    """Entry point shared by ``ogscene3d-live`` and ``ogscene3d live``; returns the exit code."""
    from ..viewer.app import check_bindable

    if args.run_dir is not None and (args.data or args.synthetic or args.source):
        raise ConfigError(
            "give either RUN_DIR (browse a saved run) or --data/--synthetic (map live), not both"
        )
    if args.run_dir is None and not args.data and not args.synthetic and not args.source:
        raise ConfigError("nothing to show: give RUN_DIR, --data DATASET, --synthetic or --source CAMERA")
    if args.rerun or args.rerun_save:
        if args.run_dir is not None:
            raise ConfigError(
                "--rerun and --rerun-save log a mapping session: give --data, --synthetic or --source"
            )
        from ..viewer.rerun_log import rerun_module

        rerun_module()  # a missing rerun-sdk fails now, before a server starts
    # before reading a run or building a mapper: a host/port the server cannot bind is an error now
    check_bindable(args.host, args.port)
    if args.run_dir is not None or args.out is None:
        return _serve(args)

    with run_directory(args.out, "live"):  # one writer per run directory, as for `ogscene3d run`
        return _serve(args)


def _serve(args: argparse.Namespace) -> int:
    from ..mapping.engine import stopped_message

    stop = threading.Event()
    watchers = contextlib.ExitStack()  # the session's observers that need closing (a Rerun recording)
    prev = signal.getsignal(signal.SIGTERM)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    session = None
    viewer = None
    try:
        if args.run_dir is not None:
            from ..viewer.runs import load_run

            snap, info = load_run(args.run_dir)
            up = args.up or (tuple(info.up) if info.up is not None else None)
            viewer = _viewer(args, up, info.path.name)
            viewer.publish(snap)
            print(
                f"ogscene3d-live: browsing {info.path} ({snap.total_gaussians} Gaussians, "
                f"{len((snap.graph or {}).get('nodes', []))} graph nodes)"
            )
        else:
            session, viewer = _start_live(args, watchers)
        if args.screenshot:
            if session is not None:
                while not session.join(0.5) and not stop.is_set():
                    pass
            out = take_screenshot(viewer, args.screenshot, args.screenshot_size, args.screenshot_wait)
            print(f"ogscene3d-live: screenshot written to {out}")
        else:
            print(f"ogscene3d-live: open {viewer.url} in a browser (Ctrl-C to stop)", flush=True)
            _serve_forever(viewer, stop, session, args.exit_when_done)
    except KeyboardInterrupt:
        pass
    finally:
        if session is not None:
            from ..streams import close_stream

            if close_stream(session.frames):
                # a camera's stream ends here: the session maps what it has, finalizes and saves (a camera
                # has no frames to resume from, so this is its normal end, not a stop)
                session.join()
            # no timeout: a stop saves the map so far (--out), which must not be cut short at exit
            session.stop(timeout=None)
        watchers.close()
        if viewer is not None:
            viewer.close()
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, prev)
    if session is not None and session.error is not None:
        print(f"ogscene3d-live: mapping failed: {session.status}", file=sys.stderr)
        return 2 if isinstance(session.error, OGSceneError) else 1
    if session is not None and session.summary is not None and session.summary.status == "stopped":
        print(f"ogscene3d-live: {stopped_message(session.summary)}")
        return 130
    return 0


def _synthetic_config() -> Path | None:
    """The shipped ``synthetic.yaml`` (small images, few Gaussians): what ``--synthetic`` maps with when
    no ``--config`` is given, as the README's demo does."""
    from importlib import resources

    packaged = resources.files("ogscene3d") / "configs" / "synthetic.yaml"
    if packaged.is_file():
        return Path(str(packaged))
    checkout = Path(__file__).resolve().parents[3] / "configs" / "synthetic.yaml"  # an editable install
    return checkout if checkout.is_file() else None


def live_config(args: argparse.Namespace):
    """The config live mapping runs with: ``--config`` (for ``--synthetic`` by default the shipped
    ``synthetic.yaml``), ``--set`` and ``--device``."""
    overrides = list(args.overrides)
    if args.device:
        overrides.append(f"device={args.device}")
    config = args.config
    if args.synthetic and config is None:
        config = _synthetic_config()
        if config is None:
            log.warning("synthetic.yaml not found with the package: mapping with defaults (see --config)")
        else:
            log.info("mapping the synthetic scene with %s (--config to change)", config)
    return load_config(config, overrides)


def live_data(args: argparse.Namespace, cfg) -> str | Path:
    """The dataset to map live: ``--data``, or the synthetic scene generated for ``--synthetic`` (only
    the frames that ``--max-frames`` maps), or the config's ``data.path``."""
    import copy

    from ..datasets import configured_scene

    data = args.data
    if args.synthetic:
        s = copy.copy(cfg.synthetic)
        if args.max_frames is not None:
            s.frames = min(s.frames, args.max_frames)
        cache = args.synthetic_dir is None and args.out is None
        scene_dir = Path(
            args.synthetic_dir or (RunFolder(args.out).scene if args.out else "outputs/live-synthetic")
        )
        print(
            f"ogscene3d-live: synthetic scene (seed {s.seed}, {s.frames} frames, {s.width}x{s.height}) "
            f"in {scene_dir}",
            flush=True,
        )
        remedy = "give another --synthetic-dir, or remove that folder to generate the scene there again"
        try:
            data = configured_scene(scene_dir, s, progress=True, remedy=remedy)
        except DataError:
            if not (cache and (scene_dir / "scene.json").is_file()):
                raise
            # the default folder is this command's cache: a scene made there with other settings (another
            # --max-frames) is made again
            data = configured_scene(scene_dir, s, progress=True, overwrite=True)
    if data is None:
        data = cfg.data.path
    if data is None:
        raise ConfigError("nothing to map: give --data DATASET or --synthetic (the config sets no data.path)")
    return data


def _viewer(args: argparse.Namespace, up, name: str):
    """The browser viewer the options describe, titled after ``name`` (a run, a dataset or a camera)."""
    from ..viewer.app import LiveViewer

    return LiveViewer(
        args.host,
        args.port,
        settings=_settings(args),
        up=up,
        max_rate_hz=args.rate,
        title=f"ogscene3d: {name}",
    )


def _start_live(args: argparse.Namespace, watchers: contextlib.ExitStack):
    from ..mapping.session import open_session
    from ..viewer.live import LiveSession

    cfg = live_config(args)
    stream = data = None
    if args.source:  # a live camera (ogscene3d.streams): no dataset, so no frames to resume by
        from ..streams import stream_for_live

        stream = stream_for_live(args.source, cfg, args.max_frames, list(args.overrides))
    else:
        data = live_data(args, cfg)
    # with --out: config.yaml (with the data, as `run` records it) and run_id, so that `run --resume` goes on
    # from a stop; the caller holds the run folder's lock
    mapping = open_session(
        cfg, args.out, data, segments=args.segments, max_frames=args.max_frames, stream=stream
    )
    # what watches the session: the run-time estimate, Rerun (closed by the caller when the session ends)
    observers = watchers.enter_context(run_observers(args, cfg, mapping.data, mapping.total))
    mapping.engine.observers.extend(observers)

    up = args.up or _up_from_config(cfg)
    viewer = _viewer(args, up, stream.name if stream is not None else Path(str(data)).name)
    session = LiveSession(
        mapping.mapper,
        mapping.frames,
        viewer,
        budget=max(args.max_points, args.max_splats),
        out_dir=args.out,
        engine=mapping.engine,
        total=mapping.total,
    )
    viewer.set_control(session)
    session.start()
    return session, viewer


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ogscene3d-live", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_arguments(p)
    return p


def main(argv: list[str] | None = None) -> int:
    """The ``ogscene3d-live`` console script."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    try:
        return run(args)
    except OGSceneError as e:
        print(f"ogscene3d-live: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
