r"""Fault matrix (issue #31): re-run every fault case through the CLI on small generated data and print a
table (case, expected, observed, pass/fail), so that the next regression shows.

Groups (``--only`` takes a group or case name, or a substring of one; repeatable):

- ``frame``: bad frames in a synthetic (Replica-layout) scene, each under ``data.on_bad_frame`` error
  and skip: missing/empty/truncated/undecodable/wrong-format colour and depth images, wrong sizes, bad
  poses and bad ``traj.txt`` lines, bad segments, camera-file faults, zero depth, a wrong depth scale;
- ``signal``: SIGINT/SIGTERM during ``run`` and during ``ogscene3d-live --data D --out DIR`` (the map
  must be saved), then ``eval`` and the viewer's loader on the stopped run;
- ``lock``: two concurrent writers to one ``--out`` (the second refused, naming the holder), a stale lock
  left by ``kill -9`` (must not block);
- ``server``: a model server on 127.0.0.1 that answers 401 echoing the Authorization header (the key must
  not appear in any output) and one that answers HTTP 500 (the captioner's circuit breaker must open);
- ``config``: a config file that is not UTF-8 (exit 2, one line);
- ``depth``: every depth image zeroed (the run must fail, saying so);
- ``disk``: a full disk (a tmpfs just large enough for the resumable state; needs root to mount, else
  the row says so) and a read-only one;
- ``count``: skipped frames counted in the summary and in timings.json; the label count of
  timings.json against the saved map;
- ``resume``: ``--resume --max-frames N`` with N at or below the frames already mapped.

The frame group calls ``ogscene3d.cli.main`` in this process (one import of torch/Warp for ~50 runs);
every other case runs the installed CLI in a subprocess (signals, locks, exit codes). On a 2-core CPU
machine the whole matrix takes a few minutes; ``--jobs`` runs subprocess cases side by side.

    python benchmarks/fault_matrix.py                 # everything
    python benchmarks/fault_matrix.py --only frame    # one group
    python benchmarks/fault_matrix.py --only sigint --keep /tmp/fm   # keep the folders to look at
"""

from __future__ import annotations

import argparse
import contextlib
import http.server
import io
import json
import logging
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

PY = sys.executable
# mapping kept cheap: the faults are in the data and the run's life, not in the optimisation
FAST = ["--device", "cpu", "--set", "mapping.optimize.iters=1"]
SECRET = "sk-faultmatrix-0123456789abcdefSECRET"


@dataclass
class Row:
    case: str
    expected: str
    observed: str
    ok: bool | None  # None: could not be run here (says why)


@dataclass
class Case:
    name: str
    group: str
    expected: str
    check: Callable[[Path], tuple[str, bool | None]]


# ------------------------------------------------------------------------------------------ helpers


def cli(args: list[str], env: dict | None = None, timeout: float = 300, live: bool = False):
    exe = [PY, "-c", "from ogscene3d.commands.live import main; raise SystemExit(main())"] if live else [
        PY, "-m", "ogscene3d.cli"]  # fmt: skip
    return subprocess.run(
        exe + args, capture_output=True, text=True, timeout=timeout, env={**os.environ, **(env or {})}
    )


def popen(args: list[str], live: bool = False, env: dict | None = None) -> subprocess.Popen:
    exe = [PY, "-c", "from ogscene3d.commands.live import main; raise SystemExit(main())"] if live else [
        PY, "-m", "ogscene3d.cli"]  # fmt: skip
    return subprocess.Popen(
        exe + args,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
    )


class Watch:
    """Reads a process's stdout and stderr in threads, so that a case can wait for a line."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.proc, self.text, self._lock = proc, "", threading.Lock()
        for stream in (proc.stdout, proc.stderr):
            threading.Thread(target=self._pump, args=(stream,), daemon=True).start()

    def _pump(self, stream) -> None:
        while True:
            chunk = stream.read(1) if stream else ""
            if not chunk:
                return
            with self._lock:
                self.text += chunk

    def wait_for(self, needle: str, timeout: float) -> bool:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if needle in self.text:
                return True
            if self.proc.poll() is not None:
                time.sleep(0.2)
                return needle in self.text
            time.sleep(0.1)
        return False

    def finish(self, timeout: float) -> int | None:
        try:
            rc = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            return None
        time.sleep(0.3)  # let the readers drain
        return rc


def last_line(text: str, n: int = 150) -> str:
    lines = [ln.strip() for ln in text.replace("\r", "\n").splitlines() if ln.strip() and "%|" not in ln]
    s = lines[-1] if lines else "(no output)"
    return s if len(s) <= n else s[: n - 3] + "..."


def traceback_in(text: str) -> bool:
    return "Traceback (most recent call last)" in text


@contextlib.contextmanager
def tmpfs(path: Path, size_kib: int, readonly: bool = False):
    """Mount a tmpfs of ``size_kib`` at ``path`` (root only); yields False where it cannot be mounted."""
    path.mkdir(parents=True, exist_ok=True)
    opts = f"size={size_kib}k" + (",ro" if readonly else "")
    ok = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(path)], capture_output=True
    ).returncode
    try:
        yield ok == 0
    finally:
        if ok == 0:
            subprocess.run(["umount", str(path)], capture_output=True)


def make_scene(folder: Path, frames: int, size: tuple[int, int] = (48, 36), seed: int = 0) -> Path:
    from ogscene3d.datasets.synthetic import make_synthetic_scene

    return make_synthetic_scene(folder, seed, frames, size[0], size[1])


# ------------------------------------------------------------------------------------ the frame matrix

BAD = 2  # the damaged frame
STEM = f"{BAD:06d}"


def _write(rel: str, data: bytes) -> Callable[[Path], None]:
    return lambda s: (s / rel).write_bytes(data)


def _rm(rel: str) -> Callable[[Path], None]:
    return lambda s: (s / rel).unlink()


def _cut(rel: str, keep: slice) -> Callable[[Path], None]:
    return lambda s: (s / rel).write_bytes((s / rel).read_bytes()[keep])


def _img(rel: str, make: Callable[[Path], np.ndarray]) -> Callable[[Path], None]:
    def damage(s: Path) -> None:
        img = make(s)
        ok, buf = cv2.imencode(Path(rel).suffix, img)
        assert ok
        (s / rel).write_bytes(buf.tobytes())

    return damage


def _traj_line(row: str) -> Callable[[Path], None]:
    def damage(s: Path) -> None:
        lines = (s / "traj.txt").read_text().splitlines()
        lines[BAD] = row
        (s / "traj.txt").write_text("\n".join(lines) + "\n")

    return damage


def _cam(edit: Callable[[dict], object]) -> Callable[[Path], None]:
    def damage(s: Path) -> None:
        cam = json.loads((s / "cam_params.json").read_text())
        edit(cam["camera"])
        (s / "cam_params.json").write_text(json.dumps(cam))

    return damage


def _depth(s: Path) -> np.ndarray:
    return cv2.imread(str(s / "results" / f"depth{STEM}.png"), cv2.IMREAD_UNCHANGED)


def _seg_nan_score(s: Path) -> None:
    p = s / "segments" / f"frame{STEM}.json"
    meta = json.loads(p.read_text())
    key = next(iter(meta["scores"]))
    meta["scores"][key] = float("nan")
    p.write_text(json.dumps(meta))  # json writes NaN, as a buggy segmenter would


RGB, DEPTH = f"results/frame{STEM}.jpg", f"results/depth{STEM}.png"
SEG = f"segments/frame{STEM}.png"
# (name, damage, what the error must name, kind): kind "frame" = one bad frame (error: exit 2 naming it;
# skip: exit 0, that frame left out with a warning naming it), "data" = the data set as a whole (exit 2
# naming the file in both modes), "ok" = not an error (exit 0), "warn" = exit 0 with a warning naming it
FRAME_FAULTS: list[tuple[str, Callable[[Path], None], str, str]] = [
    ("rgb missing", _rm(RGB), f"frame{STEM}.jpg", "frame"),
    ("depth missing", _rm(DEPTH), f"depth{STEM}.png", "frame"),
    ("rgb empty", _write(RGB, b""), f"frame{STEM}.jpg", "frame"),
    ("depth empty", _write(DEPTH, b""), f"depth{STEM}.png", "frame"),
    ("rgb truncated", _cut(RGB, slice(0, -200)), f"frame{STEM}.jpg", "frame"),
    ("depth truncated", _cut(DEPTH, slice(0, 60)), f"depth{STEM}.png", "frame"),
    ("rgb garbage", _write(RGB, b"\xff\xd8 not a jpeg \xff\xd9"), f"frame{STEM}.jpg", "frame"),
    ("depth garbage", _write(DEPTH, b"not a png"), f"depth{STEM}.png", "frame"),
    ("depth 8-bit", _img(DEPTH, lambda s: (_depth(s) >> 8).astype(np.uint8)), f"depth{STEM}.png", "frame"),
    ("depth 3-channel", _img(DEPTH, lambda s: np.dstack([_depth(s)] * 3)), f"depth{STEM}.png", "frame"),
    (
        "rgb 16-bit",
        _write(RGB, cv2.imencode(".png", np.zeros((36, 48, 3), np.uint16))[1].tobytes()),
        f"frame{STEM}.jpg",
        "frame",
    ),
    ("rgb wrong size", _img(RGB, lambda s: np.zeros((18, 24, 3), np.uint8)), f"frame{STEM}.jpg", "frame"),
    ("depth wrong size", _img(DEPTH, lambda s: _depth(s)[:18, :24].copy()), f"frame{STEM}.jpg", "frame"),
    ("rgb grey (1 channel)", _img(RGB, lambda s: np.full((36, 48), 128, np.uint8)), "", "ok"),
    ("pose NaN", _traj_line("nan " * 16), f"traj.txt:{BAD + 1}", "frame"),
    ("pose non-rigid", _traj_line("2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"), f"traj.txt:{BAD + 1}", "frame"),
    ("pose bad last row", _traj_line("1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1"), f"traj.txt:{BAD + 1}", "frame"),
    ("traj line non-numeric", _traj_line("1 0 0 x " * 4), f"traj.txt:{BAD + 1}", "frame"),
    ("traj line short", _traj_line("1 0 0 0"), f"traj.txt:{BAD + 1}", "frame"),
    (  # the last frame beyond the trajectory: named when the data set opens, an error or a skip
        "traj shorter than frames",
        lambda s: (s / "traj.txt").write_text("".join((s / "traj.txt").read_text().splitlines(True)[:-1])),
        "traj.txt",
        "frame",
    ),
    ("segments corrupt", _write(SEG, b"not a png"), f"frame{STEM}.png", "frame"),
    ("segments wrong size", _img(SEG, lambda s: np.ones((18, 24), np.uint16)), f"frame{STEM}.png", "frame"),
    ("segment score NaN", _seg_nan_score, f"frame{STEM}.json", "frame"),
    ("cam_params malformed", _write("cam_params.json", b"{not json"), "cam_params.json", "data"),
    ("cam_params wrong width", _cam(lambda c: c.update(w=c["w"] * 2)), "cam_params.json", "data"),
    ("cam_params missing", _rm("cam_params.json"), "cam_params.json", "data"),
    ("depth zero (one frame)", _img(DEPTH, lambda s: np.zeros_like(_depth(s))), f"frame{STEM}", "warn"),
    # every depth 1000x too far: nothing can be mapped, and the run fails naming the setting
    ("depth scale wrong", _cam(lambda c: c.update(scale=6.5535)), "depth_scale", "data"),
]


def run_in_process(args: list[str]) -> tuple[int, str]:
    """``ogscene3d.cli.main(args)`` here, with stdout, stderr and logging captured."""
    from ogscene3d.cli import main

    buf = io.StringIO()
    handler = logging.StreamHandler(buf)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    saved = root.handlers[:]
    root.handlers = [handler]
    root.setLevel(logging.INFO)
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            try:
                rc = main(args)
            except SystemExit as e:
                rc = int(e.code or 0)
            except Exception as e:  # a traceback is a finding, not the end of the matrix
                import traceback

                buf.write("Traceback (most recent call last):\n" + traceback.format_exc())
                rc = 1
                del e
    finally:
        root.handlers = saved
    return rc, buf.getvalue()


def frame_case(name: str, damage, needle: str, kind: str, mode: str) -> Case:
    if kind == "frame":
        expected = (
            f"exit 2 naming {needle}"
            if mode == "error"
            else f"exit 0, frame {BAD} skipped, warning naming it"
        )
    elif kind == "data":
        expected = f"exit 2 naming {needle}"
    elif kind == "warn":
        expected = f"exit 0, a warning naming {needle}"
    else:
        expected = "exit 0"

    def check(tmp: Path) -> tuple[str, bool | None]:
        scene = tmp / "scene"
        shutil.copytree(SCENES["base"], scene)
        damage(scene)
        args = ["run", "--data", str(scene), "--out", str(tmp / "run"), "--no-progress", *FAST]
        args += ["--set", f"data.on_bad_frame={mode}"]
        rc, out = run_in_process(args)
        if traceback_in(out):
            return f"exit {rc}, traceback: {last_line(out)}", False
        if kind == "frame" and mode == "skip":
            mapped = _frames_mapped(tmp / "run")
            named = needle in out or f"frame{STEM}" in out
            ok = rc == 0 and named and mapped == FRAMES - 1
            return f"exit {rc}, {mapped} of {FRAMES} frames mapped, named: {named}", ok
        if kind in ("frame", "data"):
            ok = rc == 2 and needle in out
            return f"exit {rc}: {last_line(_error_line(out))}", ok
        if kind == "warn":
            warned = any("WARNING" in ln and needle in ln for ln in out.splitlines())
            return f"exit {rc}, warning naming {needle}: {warned}", rc == 0 and warned
        return f"exit {rc}: {last_line(out)}", rc == 0

    return Case(f"frame: {name} [{mode}]", "frame", expected, check)


def _error_line(out: str) -> str:
    errs = [ln for ln in out.splitlines() if ": error:" in ln]
    return errs[-1] if errs else out


def _frames_mapped(run: Path) -> int | None:
    try:
        return int(json.loads((run / "timings.json").read_text())["counts"]["frames"])
    except (OSError, KeyError, ValueError):
        return None


# ------------------------------------------------------------------------------------ the other cases


def _run_args(scene: Path, out: Path, *extra: str, progress: bool = False) -> list[str]:
    args = ["run", "--data", str(scene), "--out", str(out), *FAST, *extra]
    return args if progress else [*args, "--no-progress"]


def _signal_mid_run(out: Path, sig: int) -> tuple[Watch, int | None, str | None]:
    """Start a slow ``run`` into ``out``, send ``sig`` once keyframe 2 is reported and wait for the exit:
    (the watch, its exit code, a failure message when keyframe 2 never came)."""
    # a slower run so that the signal lands mid-way: more optimisation steps per keyframe
    w = Watch(popen(_run_args(SCENES["long"], out, "--set", "mapping.optimize.iters=6", progress=True)))
    if not w.wait_for("kf=2", 240):
        w.finish(5)
        return w, None, f"never reached keyframe 2: {last_line(w.text)}"
    w.proc.send_signal(sig)
    return w, w.finish(120), None


def interrupt_run(sig: int) -> Callable[[Path], tuple[str, bool | None]]:
    def check(tmp: Path) -> tuple[str, bool | None]:
        out = tmp / "run"
        w, rc, failed = _signal_mid_run(out, sig)
        if failed:
            return failed, False
        saved = (out / "map.npz").is_file()
        ok = saved and not traceback_in(w.text) and "--resume" in w.text
        return f"exit {rc}, map.npz saved: {saved}: {last_line(w.text)}", ok

    return check


def interrupt_live(sig: int) -> Callable[[Path], tuple[str, bool | None]]:
    def check(tmp: Path) -> tuple[str, bool | None]:
        out = tmp / "live"
        args = ["--data", str(SCENES["long"]), "--out", str(out), "--port", "0", *FAST]
        args += ["--set", "mapping.optimize.iters=6"]
        w = Watch(popen(args, live=True))
        if not w.wait_for("open http", 240):
            w.finish(5)
            return f"viewer never served: {last_line(w.text)}", False
        time.sleep(4.0)  # some keyframes in
        if w.proc.poll() is not None:
            return f"exited before the signal: {last_line(w.text)}", None
        w.proc.send_signal(sig)
        rc = w.finish(120)
        saved = (out / "map.npz").is_file()
        return f"exit {rc}, {out.name}/map.npz saved: {saved}: {last_line(w.text)}", saved and rc is not None

    return check


def stop_then_eval(tmp: Path) -> tuple[str, bool | None]:
    out = tmp / "run"
    _, _, failed = _signal_mid_run(out, signal.SIGINT)
    if failed:
        return failed, False
    ev = cli(["eval", str(out), "--gt", str(SCENES["long"]), "--no-plots"])
    view = subprocess.run(
        [PY, "-c", f"from ogscene3d.viewer.runs import load_run; load_run({str(out)!r})"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    ok = ev.returncode == 0 and view.returncode == 0
    return (
        f"eval exit {ev.returncode} ({last_line(ev.stderr or ev.stdout, 70)}); viewer load exit "
        f"{view.returncode} ({last_line(view.stderr or view.stdout, 70)})",
        ok,
    )


def concurrent_writers(tmp: Path) -> tuple[str, bool | None]:
    out = tmp / "run"
    a = Watch(popen(_run_args(SCENES["long"], out, "--set", "mapping.optimize.iters=4", progress=True)))
    a.wait_for("mapping", 120)
    b = Watch(popen(_run_args(SCENES["long"], out, "--set", "mapping.optimize.iters=4")))
    rb = b.finish(600)
    ra = a.finish(600)
    refused = (ra == 0) != (rb == 0)
    loser = b if rb != 0 else a
    named = refused and any(w in loser.text.lower() for w in ("pid", "lock", "another run", "in use"))
    return (
        f"exits {ra} and {rb}; refusal names the holder: {named}: {last_line(loser.text)}",
        refused and named,
    )


def stale_lock(tmp: Path) -> tuple[str, bool | None]:
    out = tmp / "run"
    w = Watch(popen(_run_args(SCENES["long"], out, "--set", "mapping.optimize.iters=6", progress=True)))
    if not w.wait_for("kf=1", 240):
        w.finish(5)
        return f"never reached keyframe 1: {last_line(w.text)}", False
    w.proc.kill()
    w.finish(30)
    again = cli(_run_args(SCENES["base"], out))
    return f"rerun exit {again.returncode}: {last_line(again.stdout + again.stderr)}", again.returncode == 0


class _Server(http.server.ThreadingHTTPServer):
    status = 500
    hits = 0


class _Handler(http.server.BaseHTTPRequestHandler):
    def do_POST(self) -> None:  # noqa: N802 - http.server's naming
        srv: _Server = self.server  # type: ignore[assignment]
        srv.hits += 1
        self.rfile.read(int(self.headers.get("Content-Length") or 0))
        if srv.status == 401:  # as some proxies do: the request's headers echoed in the error
            body = {"error": {"message": f"invalid key: {self.headers.get('Authorization')}", "type": "auth"}}
        else:
            body = {"error": {"message": "internal error", "type": "server_error"}}
        data = json.dumps(body).encode()
        self.send_response(srv.status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    do_GET = do_POST  # noqa: N815

    def log_message(self, *args) -> None:
        pass


def model_server(status: int) -> Callable[[Path], tuple[str, bool | None]]:
    def check(tmp: Path) -> tuple[str, bool | None]:
        srv = _Server(("127.0.0.1", 0), _Handler)
        srv.status = status
        threading.Thread(target=srv.serve_forever, daemon=True).start()
        try:
            url = f"http://127.0.0.1:{srv.server_address[1]}/v1"
            sets = ["graph.captioner.kind=openai", f"graph.endpoint.base_url={url}"]
            sets += ["graph.endpoint.model=fault-matrix", "graph.endpoint.api_key_env=OGS_FAULT_MATRIX_KEY"]
            # one graph update (the final one), one request at a time: the breaker opens after 3 failed
            # nodes, each asked 1 + max_retries times, so at most 9 requests (with N requests in parallel,
            # up to N - 1 more nodes are already under way when it opens)
            sets += ["graph.endpoint.max_retries=2", "graph.endpoint.timeout_s=5"]
            sets += ["graph.init_keyframes=1000", "graph.captioner.concurrency=1"]
            args = _run_args(SCENES["base"], tmp / "run")
            for s in sets:
                args += ["--set", s]
            p = cli(args, env={"OGS_FAULT_MATRIX_KEY": SECRET}, timeout=600)
        finally:
            srv.shutdown()
        text = p.stdout + p.stderr
        if status == 401:
            files = "".join(
                f.read_text(errors="replace")
                for f in (tmp / "run").glob("*")
                if f.suffix in (".json", ".yaml")
            )
            leaks = text.count(SECRET) + files.count(SECRET)
            return f"exit {p.returncode}, key in output/files {leaks} times", leaks == 0
        nodes = _nodes(tmp / "run")
        ok = srv.hits <= 9 and not traceback_in(text)
        return f"exit {p.returncode}, {srv.hits} requests for {nodes} nodes: {last_line(text, 80)}", ok

    return check


def _nodes(run: Path) -> int | None:
    try:
        return len(json.loads((run / "graph.json").read_text())["nodes"])
    except (OSError, KeyError, ValueError):
        return None


def non_utf8_config(tmp: Path) -> tuple[str, bool | None]:
    cfg = tmp / "bad.yaml"
    cfg.write_bytes(b"mapping:\n  opt_iters: 1  # caf\xe9 latin-1\n")
    p = cli([*_run_args(SCENES["base"], tmp / "run"), "--config", str(cfg)])
    text = p.stdout + p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    ok = p.returncode == 2 and not traceback_in(text) and len(lines) == 1 and "bad.yaml" in lines[0]
    return f"exit {p.returncode}, {len(lines)} stderr lines: {last_line(p.stderr)}", ok


def all_zero_depth(tmp: Path) -> tuple[str, bool | None]:
    scene = tmp / "scene"
    shutil.copytree(SCENES["base"], scene)
    for p in (scene / "results").glob("depth*.png"):
        d = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(p), np.zeros_like(d))
    p = cli(_run_args(scene, tmp / "run"))
    text = p.stdout + p.stderr
    ok = p.returncode != 0 and "depth" in text.lower() and not traceback_in(text)
    return f"exit {p.returncode}: {last_line(text)}", ok


def full_disk(tmp: Path) -> tuple[str, bool | None]:
    ref = SCENES["base_run"]
    # room for the resumable state (config, run id, memory views, map.npz: what a run of this scene wrote,
    # in 4 KiB pages) but not for the exports as well
    state = [ref / "config.yaml", ref / "run_id", ref / "map.npz", *(ref / "map_memory").glob("*")]
    size = sum(-(-f.stat().st_size // 4096) * 4 for f in state)
    with tmpfs(tmp / "disk", size + 8) as mounted:
        if not mounted:
            return "tmpfs could not be mounted (needs root): not run", None
        out = tmp / "disk" / "run"
        p = cli(_run_args(SCENES["base"], out))
        text = p.stdout + p.stderr
        saved = (out / "map.npz").is_file()
        names = "map.npz" in text and ("--resume" in text or "resume" in text)
        ok = p.returncode != 0 and not traceback_in(text) and saved and names
        return (
            f"exit {p.returncode}, map.npz saved: {saved}, message says how to go on: {names}: "
            + last_line(text, 90),
            ok,
        )


def read_only_disk(tmp: Path) -> tuple[str, bool | None]:
    with tmpfs(tmp / "ro", 1024, readonly=True) as mounted:
        if not mounted:
            return "tmpfs could not be mounted (needs root): not run", None
        p = cli(_run_args(SCENES["base"], tmp / "ro" / "run"))
        text = p.stdout + p.stderr
        ok = p.returncode == 2 and not traceback_in(text) and str(tmp / "ro") in text
        return f"exit {p.returncode}: {last_line(text)}", ok


def skip_counting(tmp: Path) -> tuple[str, bool | None]:
    scene = tmp / "scene"
    shutil.copytree(SCENES["base"], scene)
    (scene / DEPTH).write_bytes(b"not a png")
    p = cli(_run_args(scene, tmp / "run", "--set", "data.on_bad_frame=skip"))
    summary = next((ln for ln in p.stdout.splitlines() if ln.startswith("read ")), last_line(p.stdout))
    try:
        counts = json.loads((tmp / "run" / "timings.json").read_text())["counts"]
    except (OSError, KeyError, ValueError):
        counts = {}
    counted = {k: v for k, v in counts.items() if "skip" in k}
    ok = p.returncode == 0 and "1 skipped" in summary and 1 in counted.values()
    return f"exit {p.returncode}: {summary!r}; timings.json skip counters {counted}", ok


def label_count(tmp: Path) -> tuple[str, bool | None]:
    """timings.json's label count (what the viewer shows) against the labels the saved map holds."""
    ref = SCENES["base_run"]
    counts = json.loads((ref / "timings.json").read_text())["counts"]
    with np.load(ref / "map.npz") as z:
        labels = z["labels"]
        saved = len(set(labels[labels >= 0].tolist()))
    return f"timings.json {counts.get('labels')}, map.npz {saved}", counts.get("labels") == saved


def resume_max_frames(tmp: Path) -> tuple[str, bool | None]:
    out = tmp / "run"
    first = cli([*_run_args(SCENES["base"], out), "--max-frames", "4"])
    if first.returncode != 0:
        return f"first run failed: {last_line(first.stderr)}", False
    obs, ok = [], True
    for n in (4, 3):
        p = cli([*_run_args(SCENES["base"], out), "--resume", "--max-frames", str(n)])
        text = p.stdout + p.stderr
        said = "--max-frames" in text
        obs.append(f"N={n}: exit {p.returncode}, says so: {said}")
        ok &= said and not traceback_in(text)
    return "; ".join(obs), ok


OTHER_CASES = [
    Case("signal: SIGINT during run", "signal", "map.npz saved, message says --resume", interrupt_run(2)),
    Case("signal: SIGTERM during run", "signal", "map.npz saved, message says --resume", interrupt_run(15)),
    Case("signal: SIGINT during live --out", "signal", "DIR/map.npz saved", interrupt_live(signal.SIGINT)),
    Case("signal: SIGTERM during live --out", "signal", "DIR/map.npz saved", interrupt_live(signal.SIGTERM)),
    Case(
        "signal: stop then eval/viewer", "signal", "eval and the viewer read the stopped run", stop_then_eval
    ),
    Case(
        "lock: two writers to one --out",
        "lock",
        "one exits 0, the other refused naming the holder",
        concurrent_writers,
    ),  # fmt: skip
    Case("lock: stale lock after kill -9", "lock", "a new run on that --out exits 0", stale_lock),
    Case("server: 401 echoing Authorization", "server", "the key appears nowhere", model_server(401)),
    Case("server: HTTP 500", "server", "breaker opens: <= 9 requests, run goes on", model_server(500)),
    Case("config: not UTF-8", "config", "exit 2, one line naming the file", non_utf8_config),
    Case("depth: all zero", "depth", "the run fails, saying depth", all_zero_depth),
    Case("disk: full (tmpfs)", "disk", "exit != 0, map.npz saved, message names it and --resume", full_disk),
    Case("disk: read-only (tmpfs ro)", "disk", "exit 2 naming the folder, no traceback", read_only_disk),
    Case(
        "count: skipped frames",
        "count",
        "'1 skipped' in the summary and a timings.json counter",
        skip_counting,
    ),  # fmt: skip
    Case("count: labels", "count", "timings.json labels == labels in map.npz", label_count),
    Case(
        "resume: --max-frames <= mapped",
        "resume",
        "says --max-frames N is at or below the frames mapped (N=4, N=3)",
        resume_max_frames,
    ),  # fmt: skip
]

FRAMES = 5
SCENES: dict[str, Path] = {}


def all_cases() -> list[Case]:
    cases = []
    for name, damage, needle, kind in FRAME_FAULTS:
        modes = ("error", "skip") if kind == "frame" else ("error",)
        cases += [frame_case(name, damage, needle, kind, m) for m in modes]
    return cases + OTHER_CASES


def select(cases: list[Case], only: list[str] | None) -> list[Case]:
    if not only:
        return cases
    return [c for c in cases if any(o.lower() in c.group or o.lower() in c.name.lower() for o in only)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", action="append", help="a group or case (substring); repeatable")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    ap.add_argument("--jobs", type=int, default=1, help="subprocess cases run side by side")
    ap.add_argument("--keep", help="work in this folder and keep it (default: a temporary one)")
    args = ap.parse_args()
    cases = select(all_cases(), args.only)
    if args.list or not cases:
        for c in cases or all_cases():
            print(f"{c.group:7s} {c.name}")
        return 0 if cases or args.list else 2
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="fault_matrix_"))
    root.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        SCENES["base"] = make_scene(root / "scene_base", FRAMES)
        if any(c.group in ("signal", "lock") for c in cases):
            SCENES["long"] = make_scene(root / "scene_long", 24)
        if any(c.name in ("disk: full (tmpfs)", "count: labels") for c in cases):
            ref = root / "base_run"
            if not (ref / "map.npz").is_file():
                p = cli(_run_args(SCENES["base"], ref))
                if p.returncode != 0:
                    print(f"the reference run failed:\n{p.stderr[-2000:]}", file=sys.stderr)
                    return 1
            SCENES["base_run"] = ref
        rows = _run_cases(cases, root, args.jobs)
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    _print(rows)
    passed = sum(r.ok is True for r in rows)
    failed = sum(r.ok is False for r in rows)
    print(f"\n{passed} passed, {failed} failed, {len(rows) - passed - failed} not run, "
          f"in {time.perf_counter() - t0:.0f} s")  # fmt: skip
    return 1 if failed else 0


def _run_one(case: Case, root: Path) -> Row:
    # a folder name without the words a check looks for in the output ("--max-frames")
    tmp = root / (
        "case_" + re.sub(r"[^a-z0-9]+", "_", case.name.lower().replace("max-frames", "n")).strip("_")
    )
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        observed, ok = case.check(tmp)
    except Exception as e:  # the matrix goes on; the row says what broke
        observed, ok = f"the check itself failed: {type(e).__name__}: {e}", False
    return Row(case.name, case.expected, observed, ok)


def _run_cases(cases: list[Case], root: Path, jobs: int) -> list[Row]:
    rows: dict[str, Row] = {}
    # in-process cases one after the other (they share this process's logging and stdout)
    for c in cases:
        if c.group == "frame":
            rows[c.name] = _run_one(c, root)
            print(_fmt(rows[c.name]), file=sys.stderr, flush=True)
    rest = [c for c in cases if c.group != "frame"]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max(1, jobs)) as pool:
        for c, row in zip(rest, pool.map(lambda c: _run_one(c, root), rest)):
            rows[c.name] = row
            print(_fmt(row), file=sys.stderr, flush=True)
    return [rows[c.name] for c in cases]


def _fmt(r: Row) -> str:
    return f"[{'pass' if r.ok else 'FAIL' if r.ok is False else 'n/a '}] {r.case}: {r.observed}"


def _print(rows: list[Row]) -> None:
    w = [max(len(h), *(len(x) for x in col)) for h, col in (
        ("case", [r.case for r in rows]), ("expected", [r.expected for r in rows]))]  # fmt: skip
    print(f"{'case':{w[0]}}  {'expected':{w[1]}}  result  observed")
    for r in rows:
        res = "pass" if r.ok else "FAIL" if r.ok is False else "n/a"
        print(f"{r.case:{w[0]}}  {r.expected:{w[1]}}  {res:6s}  {r.observed}")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import run_main

    run_main(main)
