"""The pose-jump check (mapping/pose_jump.py): limits, and the mapper's warn / skip / error choices."""

import json
import math

import numpy as np
import pytest
from mapping_scenes import _common, _replica_scene

from ogscene3d.cli import main
from ogscene3d.config import load_config
from ogscene3d.errors import ConfigError
from ogscene3d.frame import Frame
from ogscene3d.mapping.mapper import Mapper
from ogscene3d.mapping.pose_jump import PoseJumpCheck, PoseJumpError

W, H, F = 32, 24, 24.0
K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]], dtype=np.float32)


def _pose(x: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    a = math.radians(yaw_deg)
    pose = np.eye(4)
    pose[:3, :3] = [[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]]
    pose[0, 3] = x
    return pose


def test_limits_scale_with_the_steps_since_the_last_accepted_frame():
    c = PoseJumpCheck(0.5, 30.0, "warn")
    assert c.check(0, _pose(9.0)) is None  # no reference yet
    c.accept(0, _pose())
    assert c.check(1, _pose(0.45, 25.0)) is None
    jump = c.check(1, _pose(0.6), "f1")
    assert jump is not None and jump.translation == pytest.approx(0.6) and jump.rotation_deg == 0.0
    assert "frame 1 (f1)" in jump.describe() and "from frame 0" in jump.describe()
    assert c.check(1, _pose(0.0, 40.0)).rotation_deg == pytest.approx(40.0)
    # two steps after the reference (a frame left out in between): twice the limits
    assert c.check(2, _pose(0.9, 50.0)) is None
    assert c.check(2, _pose(1.1)).limit_translation == pytest.approx(1.0)
    off = PoseJumpCheck(0.0, 0.0, "warn")  # 0 = no limit
    off.accept(0, _pose())
    assert off.check(1, _pose(100.0, 170.0)) is None
    restored = PoseJumpCheck(0.5, 30.0, "skip")
    restored.load_state(c.state())
    assert restored.last_index == 0 and restored.check(1, _pose(0.6)) is not None
    restored.load_state({})  # a checkpoint from before the check: no reference
    assert restored.check(1, _pose(0.6)) is None


def test_limits_scale_with_the_data_stride():
    """A run at data.stride=3 compares frames three folder frames apart: the per-step limits triple
    (7-Scenes every 20th frame at stride 3 steps 0.58 m / 32 deg, under 0.5 m / 30 deg x 3)."""
    cfg = load_config(None, ["data.stride=3"])
    mapper = Mapper(cfg, "cpu")
    assert mapper.pose_check.stride == 3 and mapper._get_tracker().frame_step == 3  # odometry's limits too
    c = PoseJumpCheck(0.5, 30.0, "warn", stride=3)
    c.accept(0, _pose())
    assert c.check(1, _pose(0.58, 32.0)) is None
    jump = c.check(1, _pose(1.6), "f1")
    assert jump is not None and jump.limit_translation == pytest.approx(1.5)
    assert "3 x mapping.max_pose_step" in jump.describe()
    assert c.check(2, _pose(3.1)).limit_translation == pytest.approx(3.0)  # a frame left out: 2 x 3


@pytest.mark.parametrize(
    "args, match",
    [((-0.1, 30.0, "warn"), "max_pose_step"), ((0.5, math.nan, "warn"), "max_pose_step"),
     ((0.5, 30.0, "ignore"), "on_pose_jump")],
)  # fmt: skip
def test_bad_settings_are_config_errors(args, match):
    with pytest.raises(ConfigError, match=match):
        PoseJumpCheck(*args)
    with pytest.raises(ConfigError, match="on_pose_jump"):
        Mapper(load_config(None, ["graph.enabled=false", "mapping.on_pose_jump=ignore"]), "cpu")


# the camera moves 0.2 m per frame along x in front of a wall 2 m ahead; frame 2's pose is 3 m off
XS = [0.0, 0.2, 3.0, 0.6]


def _frame(i: int) -> Frame:
    seg = np.full((H, W), 2, np.int32)
    seg[:, : W // 2] = 1
    rgb = np.full((H, W, 3), 128, np.uint8)
    return Frame(
        i, rgb, np.full((H, W), 2.0, np.float32), K, _pose(XS[i]), name=f"f{i}", segments=seg,
        segment_scores={1: 0.97, 2: 0.97},
    )  # fmt: skip


def _mapper(action: str) -> Mapper:
    cfg = load_config(
        None,
        ["graph.enabled=false", "mapping.optimize.iters=0", "mapping.ablation=local",
         "mapping.association.knn_radius=0.1",
         f"mapping.on_pose_jump={action}"],
    )  # fmt: skip
    return Mapper(cfg, "cpu")


def test_warn_maps_the_frame_and_names_it(caplog):
    m = _mapper("warn")
    with caplog.at_level("WARNING", logger="ogscene3d.mapping.mapper"):
        assert all(m.process(_frame(i)) for i in range(4))
    warned = [r.getMessage() for r in caplog.records if "pose jumped" in r.getMessage()]
    # out to the glitch and back from it: both steps jump
    assert len(warned) == 2 and "frame 2 (f2)" in warned[0] and "2.800 m" in warned[0]
    c = m.timings.as_dict()["counts"]
    assert c["pose_jumps"] == 2 and c["frames"] == 4 and "frames_skipped_pose_jump" not in c
    assert float(m.map.means[:, 0].max()) > 4.0  # the glitched frame's wall, 3 m off


def test_skip_leaves_the_frame_out_and_keeps_the_reference(caplog):
    m = _mapper("skip")
    with caplog.at_level("WARNING", logger="ogscene3d.mapping.mapper"):
        kept = [m.process(_frame(i)) for i in range(4)]
    assert kept == [True, True, False, True]  # frame 3 is 0.4 m from frame 1, over two steps
    assert any("frame 2 (f2)" in r.getMessage() and "left out" in r.getMessage() for r in caplog.records)
    c = m.timings.as_dict()["counts"]
    assert c["pose_jumps"] == 1 and c["frames_skipped_pose_jump"] == 1 and c["frames"] == 3
    assert m.next_index == 4
    assert float(m.map.means[:, 0].max()) < 2.0  # nothing from the glitched frame


def test_error_stops_before_the_frame_counts_and_a_resume_rechecks_it(tmp_path):
    m = _mapper("error")
    m.process(_frame(0))
    m.process(_frame(1))
    with pytest.raises(PoseJumpError, match=r"frame 2 \(f2\).*on_pose_jump"):
        m.process(_frame(2))
    assert m.next_index == 2 and m.frames_seen == 2  # a resume retries frame 2
    m.save_checkpoint(tmp_path / "map.npz")
    resumed = _mapper("skip")
    resumed.load_checkpoint(tmp_path / "map.npz")
    assert not resumed.process(_frame(2))  # the reference pose came through the checkpoint
    assert resumed.process(_frame(3))


def test_run_saves_the_map_at_a_pose_jump_error_and_resumes(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=4)
    traj = scene / "traj.txt"
    rows = traj.read_text().splitlines()
    pose = np.array(rows[2].split(), dtype=float).reshape(4, 4)
    pose[0, 3] = 3.0
    rows[2] = " ".join(f"{v:.6f}" for v in pose.reshape(-1))
    traj.write_text("\n".join(rows) + "\n")
    out = tmp_path / "run"
    common = _common(scene, out)
    assert main(["run", *common, "--set", "mapping.on_pose_jump=error"]) == 2
    err = capsys.readouterr().err
    assert "frame 2 (frame000002)" in err and "mapping.on_pose_jump" in err
    assert (out / "map.npz").is_file()
    assert main(["run", *common, "--resume", "--set", "mapping.on_pose_jump=skip"]) == 0
    assert "read 2 frames: 1 mapped (3 keyframes in all), 1 pose jumps left out" in capsys.readouterr().out
    t = json.loads((out / "timings.json").read_text())
    assert t["counts"]["frames"] == 3 and t["counts"]["frames_skipped_pose_jump"] == 1
