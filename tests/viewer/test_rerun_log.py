"""Rerun logging (``--rerun``, ``--rerun-save``; the ``rerun`` extra): a run's .rrd, read back with the SDK,
holds per keyframe the camera pose and image, the map's points by label and the scene graph's nodes and
edges; a viewer reached by URL receives the same; without rerun-sdk the options say which extra to install."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import tomllib

from ogscene3d.cli import main

ROOT = Path(__file__).resolve().parents[2]
ENTITIES = (
    "/world/camera", "/world/camera/image", "/world/trajectory", "/world/map", "/world/graph/nodes",
    "/world/graph/edges",
)  # fmt: skip


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from ogscene3d.datasets import make_synthetic_scene

    folder = tmp_path_factory.mktemp("rr") / "scene"
    return make_synthetic_scene(folder, seed=1, frames=6, width=64, height=48)


SMALL = [
    "--set", "mapping.keyframe_every=2", "--set", "mapping.optimize.iters=1",
    "--set", "graph.init_keyframes=1", "--set", "graph.update_every=1", "--set", "graph.min_gaussians=5",
]  # fmt: skip


def _run(scene: Path, out: Path, *rerun: str) -> list[str]:
    args = ["run", "--data", str(scene), "--out", str(out), "--device", "cpu", "--no-progress"]
    return [*args, *rerun, *SMALL]


def _read(rrd: Path) -> dict[str, dict[str, dict[int, object]]]:
    """{entity: {component: {keyframe: value}}} of a recording, read back with rerun-sdk."""
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, dict[int, object]]] = {}
    for chunk in RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        cols = {
            f.name: batch.column(i).to_pylist()
            for i, f in enumerate(batch.schema)
            if ":" in f.name or f.name == "keyframe"
        }
        keys = cols.get("keyframe", [None] * batch.num_rows)
        for name, values in cols.items():
            if ":" in name:
                comp = out.setdefault(chunk.entity_path, {}).setdefault(name, {})
                for k, v in zip(keys, values):
                    comp[-1 if k is None else int(k)] = v
    return out


def test_rerun_save_writes_every_keyframe_and_the_final_state(tmp_path, scene):
    pytest.importorskip("rerun", reason='the rerun extra: pip install "ogscene3d[rerun]"')
    out, rrd = tmp_path / "run", tmp_path / "session.rrd"
    assert main(_run(scene, out, "--rerun-save", str(rrd))) == 0
    got = _read(rrd)
    timings = json.loads((out / "timings.json").read_text())
    kf = int(timings["counts"]["keyframes"])
    assert kf == 3
    per_keyframe = set(range(kf))
    for entity in ENTITIES:
        assert entity in got, sorted(got)
    assert set(got["/world/camera"]["Transform3D:translation"]) == per_keyframe
    assert set(got["/world/camera"]["Pinhole:image_from_camera"]) == per_keyframe
    assert set(got["/world/camera/image"]["EncodedImage:blob"]) == per_keyframe
    # the map and the graph: every keyframe, and once more after the final pass
    for entity, comp in (("/world/map", "Points3D:positions"), ("/world/graph/nodes", "Boxes3D:half_sizes"),
                         ("/world/graph/edges", "LineStrips3D:strips")):  # fmt: skip
        assert set(got[entity][comp]) == per_keyframe | {kf}, entity
    # the camera is each keyframe's pose (keyframe_every 2: frames 0, 2, 4)
    from ogscene3d.datasets import open_dataset

    ds = open_dataset(scene)
    for k in range(kf):
        (t,) = got["/world/camera"]["Transform3D:translation"][k]
        np.testing.assert_allclose(t, ds.pose(2 * k)[:3, 3], atol=1e-6)
    # the final state is the saved one: every Gaussian (under the budget) and graph.json's nodes and edges
    graph = json.loads((out / "graph.json").read_text())
    from plyfile import PlyData

    saved = PlyData.read(out / "gaussians.ply")["vertex"].count
    assert len(got["/world/map"]["Points3D:positions"][kf]) == saved
    names = got["/world/graph/nodes"]["Boxes3D:labels"][kf]
    assert len(names) == len(graph["nodes"])
    assert all(f"({n['id']})" in m for n, m in zip(graph["nodes"], names))
    assert got["/world/graph/edges"]["LineStrips3D:labels"][kf] == [e["relation"] for e in graph["edges"]]
    # the world's up direction: the synthetic scene's, -y
    assert "/world" in got and any("ViewCoordinates" in c for c in got["/world"])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_rerun_streams_to_a_viewer_at_a_url(tmp_path, scene):
    """``--rerun URL`` streams to a running Rerun viewer; here the SDK's own headless server, which writes
    what it receives to a file."""
    pytest.importorskip("rerun", reason='the rerun extra: pip install "ogscene3d[rerun]"')
    port, got = _free_port(), tmp_path / "received.rrd"
    # `rerun --save FILE` listens as a viewer does and writes what it receives (its own process group: the
    # python wrapper starts the viewer binary as a child)
    server = subprocess.Popen(
        [sys.executable, "-m", "rerun", "--port", str(port), "--save", str(got)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        _wait_for(lambda: _listening(port), "the Rerun server to listen")
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        assert main(_run(scene, tmp_path / "run", "--rerun", url)) == 0
        _wait_for(lambda: _keyframe_images(got) == {0, 1, 2}, "the keyframes to arrive")
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=10)


def _keyframe_images(rrd: Path) -> set[int]:
    """The keyframes whose image a recording being written holds so far."""
    try:
        return set(_read(rrd)["/world/camera/image"]["EncodedImage:blob"])
    except Exception:  # noqa: BLE001 - not there yet, or cut mid-message
        return set()


def _listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def _wait_for(ready, what: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not ready():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.2)


def test_without_rerun_sdk_the_options_name_the_extra(tmp_path, scene, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun fails as it does without the package
    assert main(_run(scene, tmp_path / "run", "--rerun-save", str(tmp_path / "x.rrd"))) == 2
    err = capsys.readouterr().err
    assert "logging to Rerun (--rerun, --rerun-save) needs the Python package 'rerun'" in err
    assert 'pip install "ogscene3d[rerun]"' in err and not (tmp_path / "run").exists()


def test_rerun_is_an_extra_that_the_core_install_does_not_pull():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert not any(d.startswith("rerun") for d in project["dependencies"])
    extras = project["optional-dependencies"]
    assert any(d.startswith("rerun-sdk") for d in extras["rerun"])
    assert any(d.startswith("rerun-sdk") for d in extras["test"])  # CI tests it


def test_without_a_viewer_to_start_rerun_says_what_else_to_give(tmp_path, scene, monkeypatch, capsys):
    """--rerun starts the `rerun` on PATH (or beside this Python); with none, the run stops with the two
    other ways."""
    pytest.importorskip("rerun", reason='the rerun extra: pip install "ogscene3d[rerun]"')
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))
    assert main(_run(scene, tmp_path / "run", "--rerun")) == 2
    err = capsys.readouterr().err
    assert "--rerun could not start Rerun's viewer (Failed to find Rerun Viewer executable" in err
    assert "--rerun rerun+http://HOST:9876/proxy" in err and "--rerun-save FILE.rrd" in err


def test_a_bad_viewer_url_is_refused(tmp_path, scene, capsys):
    with pytest.raises(SystemExit):
        main(_run(scene, tmp_path / "run", "--rerun", "http://localhost:9876"))
    assert "expected a Rerun viewer's URL such as rerun+http://" in capsys.readouterr().err


def test_live_logs_its_session_too(tmp_path, scene, capsys):
    pytest.importorskip("rerun", reason='the rerun extra: pip install "ogscene3d[rerun]"')
    from ogscene3d.commands.live import main as live_main

    rrd = tmp_path / "live.rrd"
    args = ["--data", str(scene), "--out", str(tmp_path / "live"), "--exit-when-done", "--port", "0",
            "--device", "cpu", "--rerun-save", str(rrd), *SMALL]  # fmt: skip
    assert live_main(args) == 0
    got = _read(rrd)
    assert set(got["/world/camera/image"]["EncodedImage:blob"]) == {0, 1, 2}
    assert set(got["/world/map"]["Points3D:positions"]) == {0, 1, 2, 3}  # and the final state
    # browsing a saved run maps nothing: there is no session to log
    assert live_main([str(tmp_path / "live"), "--rerun-save", str(tmp_path / "x.rrd"), "--port", "0"]) == 2
    assert "--rerun and --rerun-save log a mapping session" in capsys.readouterr().err
