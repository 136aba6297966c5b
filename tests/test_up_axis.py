"""graph.up_axis auto: the format's world up where it defines one, else the cameras' up direction; scenes
in the ScanNet, Replica and TUM layouts map without up_axis flags and without the warning, their on/under
relations pointing the right way."""

from __future__ import annotations

import dataclasses
import json
import logging

import numpy as np
import pytest
import yaml
from layout_scenes import Y_DOWN_TO_Z_UP, synthetic_frames, tiny_frames, tum_intrinsics, write_layout

from ogscene3d.cli import main
from ogscene3d.config import load_config
from ogscene3d.datasets import make_synthetic_scene, open_dataset
from ogscene3d.errors import ConfigError
from ogscene3d.frame import Frame
from ogscene3d.mapping.mapper import Mapper
from ogscene3d.up_axis import CameraUp, angle_deg, choose_up_axis


def _turn(axis: str, deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler(axis, deg, degrees=True).as_matrix()
    return T


def _upright_camera(yaw_deg: float, pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """An OpenCV camera in a z-up world looking along its heading ``yaw_deg``, pitched down ``pitch_deg``."""
    level = np.eye(4)
    level[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # camera x = world x, y down = -z, z forward = y
    return _turn("z", yaw_deg) @ level @ _turn("x", -pitch_deg) @ _turn("z", roll_deg)


# ------------------------------------------------------------------------------------------ the estimate


def test_cameras_that_turn_give_the_vertical_whatever_their_pitch():
    cams = CameraUp()
    rng = np.random.default_rng(0)
    for yaw in range(0, 120, 10):
        cams.add(_upright_camera(yaw, pitch_deg=35.0, roll_deg=rng.normal(0, 2)))
    assert angle_deg(cams.estimate(), [0, 0, 1]) == 0.0  # the x axes' plane, snapped to z
    # without turning, the mean of the up vectors is all there is: 35 degrees off, not an axis
    still = CameraUp()
    for _ in range(5):
        still.add(_upright_camera(30.0, pitch_deg=35.0))
    assert angle_deg(still.estimate(), [0, 0, 1]) == pytest.approx(35.0, abs=1e-6)
    assert CameraUp().estimate() is None


def test_a_tilted_world_keeps_its_tilt():
    """A world anchored at a pitched first camera (7-Scenes, odometry): its vertical is no axis."""
    tilt = np.linalg.inv(_upright_camera(0.0, pitch_deg=30.0))
    cams = CameraUp()
    for yaw in range(0, 90, 15):
        cams.add(tilt @ _upright_camera(yaw, pitch_deg=10.0))
    truth = tilt[:3, :3] @ [0, 0, 1]
    assert angle_deg(cams.estimate(), truth) < 1e-6 and angle_deg(truth, [0, -1, 0]) == pytest.approx(30.0)


# ------------------------------------------------------------------------------------------ at open


def _chosen(path, caplog, *overrides: str):
    """graph.up_axis after the dataset at ``path`` opened (what `ogscene3d run` does), the log captured."""
    cfg = load_config(None, list(overrides))
    assert cfg.graph.up_axis == "auto" or overrides
    with caplog.at_level(logging.INFO, logger="ogscene3d.up_axis"):
        choose_up_axis(cfg.graph, open_dataset(path, config=cfg.data))
    return cfg.graph.up_axis


@pytest.mark.parametrize("layout", ["scannet", "replica", "semantic_nerf", "tum"])
def test_auto_takes_the_formats_world_up(tmp_path, layout, caplog):
    frames = tiny_frames()
    frames.poses = [Y_DOWN_TO_Z_UP @ p for p in frames.poses]
    root = write_layout(layout, tmp_path / layout, frames)
    given = [f"data.intrinsics={tum_intrinsics(frames)}"] if layout == "tum" else []
    assert _chosen(root, caplog, *given) == [0.0, 0.0, 1.0]
    (line,) = [r.getMessage() for r in caplog.records]
    assert line.startswith("graph.up_axis auto: z (the ") and "layout" in line


def test_a_ros_bags_tf_world_is_z_up_and_a_record3d_capture_minus_y(tmp_path, caplog):
    """REP 103: a tf world frame is z-up; Record3D's ARKit world (y up) read in OpenCV axes is -y up. A bag
    without poses leaves the choice to the tracked cameras."""
    pytest.importorskip("rosbags")
    from robot_recordings import BagSpec, small_scene, write_bag, write_r3d

    from ogscene3d.datasets.record3d import lzfse_module

    _, frames, K = small_scene(tmp_path / "scene")
    z_up = [dataclasses.replace(f, pose=Y_DOWN_TO_Z_UP @ f.pose) for f in frames]
    for spec, want in ((BagSpec(), [0.0, 0.0, 1.0]), (BagSpec(poses=None), "auto")):
        assert _chosen(write_bag(tmp_path / f"rec{spec.poses}.bag", z_up, K, spec), caplog) == want
    assert "ROS's REP 103 (the world frame" in caplog.text
    try:
        lzfse_module()
    except ConfigError:
        pytest.skip("no LZFSE bindings for the Record3D part (pip install lzfse)")
    assert _chosen(write_r3d(tmp_path / "cap.r3d", frames, K), caplog) == [0.0, -1.0, 0.0]
    assert "Record3D (ARKit's" in caplog.text


def test_auto_without_a_convention_takes_the_cameras(tmp_path, caplog):
    # 7-Scenes: the world is its first camera's
    root = write_layout("sevenscenes", tmp_path / "chess", tiny_frames())
    assert _chosen(root, caplog) == [0.0, -1.0, 0.0]
    assert "the cameras' up direction over the first 3 frames" in caplog.text


def test_poses_of_another_world_in_a_formats_layout(tmp_path, caplog):
    """A ScanNet-layout export whose poses start at an upright first camera (-y up): the cameras are 90 deg
    from ScanNet's z, so auto takes theirs, saying why (no warning: the choice agrees with the cameras)."""
    root = write_layout("scannet", tmp_path / "byo", tiny_frames())
    assert _chosen(root, caplog) == [0.0, -1.0, 0.0]
    assert "says the world is z-up, but the cameras' up direction" in caplog.text
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_an_explicit_up_axis_wins(tmp_path, caplog):
    frames = tiny_frames()
    frames.poses = [Y_DOWN_TO_Z_UP @ p for p in frames.poses]
    root = write_layout("scannet", tmp_path / "s", frames)
    assert _chosen(root, caplog, "graph.up_axis=[1,0,0]") == [1.0, 0.0, 0.0]


def test_frames_without_poses_leave_the_choice_to_the_mapper(tmp_path, caplog):
    """No poses when the dataset opens (tracked by odometry; a live camera): the mapper chooses from the
    tracked cameras at its first graph update, and the graph uses it."""
    frames = tiny_frames()
    root = write_layout("scannet", tmp_path / "s", frames)
    for p in (root / "pose").iterdir():
        p.unlink()
    assert _chosen(root, caplog) == "auto"
    cfg = load_config(None, ["graph.init_keyframes=1", "graph.min_gaussians=5", "mapping.optimize.iters=0"])
    m = Mapper(cfg, "cpu")
    turned = _turn("x", -20.0)  # the tracked world: pitched 20 degrees, as a first camera looking down
    depth = np.full((24, 32), 2.0, np.float32)
    rgb = np.random.default_rng(0).integers(0, 255, (24, 32, 3), dtype=np.uint8)
    K = frames.K.astype(np.float32)
    with caplog.at_level(logging.INFO, logger="ogscene3d.mapping.mapper"):
        for i, yaw in enumerate((0.0, 20.0)):
            pose = turned @ _turn("y", yaw)  # turning about the world's vertical
            seg = np.ones((24, 32), np.int32)
            m.process(Frame(index=i, rgb=rgb, depth=depth, K=K, pose=pose, segments=seg))
    up = np.asarray(cfg.graph.up_axis)
    assert angle_deg(up, turned[:3, :3] @ [0, -1, 0]) < 1e-6
    assert np.allclose(m.graph.up, up) and "graph.up_axis auto:" in caplog.text
    assert "far from" not in caplog.text and "deg from the cameras" not in caplog.text


# ------------------------------------------------------------------------------------------ whole runs


@pytest.fixture(scope="module")
def z_up_frames(tmp_path_factory):
    folder = tmp_path_factory.mktemp("up") / "scene"
    scene = make_synthetic_scene(folder, seed=0, frames=16, width=96, height=72)
    return synthetic_frames(scene, Y_DOWN_TO_Z_UP)


@pytest.mark.parametrize("layout", ["scannet", "replica", "tum"])
def test_a_scene_maps_with_the_right_vertical_without_flags(tmp_path, z_up_frames, layout, caplog):
    """The synthetic room (objects on a cabinet, furniture on the floor) written z-up in a format's layout
    maps without up_axis flags and without the warning; its on/under relations point up z (with the wrong
    vertical, most of them do not: measured when this test was written)."""
    root = write_layout(layout, tmp_path / layout, z_up_frames)
    out = tmp_path / "run"
    extra = ["--set", f"data.intrinsics={tum_intrinsics(z_up_frames)}"] if layout == "tum" else []
    budget = ["mapping.keyframe_every=2", "mapping.optimize.iters=1", "mapping.ablation=local",
              "mapping.association.knn_radius=0.03",
              "graph.init_keyframes=4", "graph.update_every=4"]  # fmt: skip
    args = ["run", "--data", str(root), "--segments", str(root / "segments"), "--out", str(out), "--device",
            "cpu", "--no-progress", *[a for s in budget for a in ("--set", s)], *extra]  # fmt: skip
    with caplog.at_level(logging.INFO):
        assert main(args) == 0
    assert "deg from the cameras" not in caplog.text and "graph.up_axis auto: z (the " in caplog.text
    assert yaml.safe_load((out / "config.yaml").read_text())["graph"]["up_axis"] == [0.0, 0.0, 1.0]
    graph = json.loads((out / "graph.json").read_text())
    z = {n["id"]: n["center"][2] for n in graph["nodes"]}
    rises = [
        z[e["source"]] - z[e["target"]] if e["relation"] == "on" else z[e["target"]] - z[e["source"]]
        for e in graph["edges"]
        if e["relation"] in ("on", "under")
    ]
    assert len(rises) >= 5
    assert np.mean(np.asarray(rises) > 0) >= 0.75, rises


def test_a_tracked_run_on_a_format_without_poses_chooses_from_its_cameras(tmp_path, z_up_frames):
    """A synthetic scene mapped through the Python API (no open_frames): auto is chosen at the first graph
    update from the frames' cameras, z here."""
    cfg = load_config(None, ["graph.init_keyframes=8", "mapping.optimize.iters=0", "graph.min_gaussians=5"])
    m = Mapper(cfg, "cpu")
    f = z_up_frames
    for i in range(8):
        m.process(Frame(index=i, rgb=f.rgb[i], depth=f.depth[i], K=f.K.astype(np.float32), pose=f.poses[i]))
    assert dataclasses.asdict(cfg.graph)["up_axis"] == [0.0, 0.0, 1.0]
