import json

import cv2
import numpy as np
import pytest
from layout_scenes import garble_pixels
from mapping_scenes import H, W, _common, _replica_scene

from ogscene3d.cli import main


def test_run_and_resume(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene")
    out = tmp_path / "run"
    common = ["--data", str(scene), "--segments", str(scene / "segs"), "--out", str(out), "--device", "cpu",
              "--no-progress", "--set", "mapping.optimize.iters=1", "--set", "graph.enabled=false",
              "--set", "mapping.association.knn_radius=0.1"]  # fmt: skip
    assert main(["run", *common, "--max-frames", "2", "--ablation", "local+global"]) == 0
    for name in ("gaussians.ply", "map.npz", "graph.json", "timings.json", "config.yaml"):
        assert (out / name).is_file()
    t = json.loads((out / "timings.json").read_text())
    assert t["counts"]["frames"] == 2 and t["ablation"] == "local+global"
    assert main(["run", *common, "--resume", "--ablation", "local+global"]) == 0
    t = json.loads((out / "timings.json").read_text())
    assert t["counts"]["frames"] == 3 and t["counts"]["keyframes"] == 3
    graph = json.loads((out / "graph.json").read_text())
    assert {n["label"] for n in graph["nodes"]} == {0, 1}
    assert "read 1 frames: 1 mapped (3 keyframes in all)" in capsys.readouterr().out


def test_a_new_run_over_an_earlier_map_warns_that_it_replaces_it(tmp_path, caplog):
    scene = _replica_scene(tmp_path / "scene", frames=2)
    out = tmp_path / "run"
    common = ["--data", str(scene), "--segments", str(scene / "segs"), "--out", str(out), "--device", "cpu",
              "--no-progress",
              "--set", "mapping.optimize.iters=1", "--set", "graph.enabled=false"]  # fmt: skip
    assert main(["run", *common]) == 0
    assert "holds a map from an earlier run" not in caplog.text
    assert main(["run", *common]) == 0
    assert "holds a map from an earlier run" in caplog.text and "--resume continues" in caplog.text
    caplog.clear()
    assert main(["run", *common, "--resume"]) == 0
    assert "holds a map from an earlier run" not in caplog.text


def test_run_errors(tmp_path, capsys):
    assert (
        main(["run", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    )
    assert "missing" in capsys.readouterr().err
    scene = _replica_scene(tmp_path / "scene", frames=1)
    assert (
        main(["run", "--data", str(scene), "--out", str(tmp_path / "o2"), "--resume", "--no-progress"]) == 2
    )
    assert "resume" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["run", "--out", str(tmp_path / "o3"), "--ablation", "bogus"])


def test_bad_frames_are_skipped_when_asked_and_resume_goes_on_after_them(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=4)
    garble_pixels(scene / "results" / "depth000001.png")
    out = tmp_path / "run"
    common = ["--data", str(scene), "--segments", str(scene / "segs"), "--out", str(out), "--device", "cpu",
              "--no-progress", "--set", "mapping.optimize.iters=1", "--set", "graph.enabled=false",
              "--set", "mapping.association.knn_radius=0.1"]  # fmt: skip
    assert main(["run", *common, "--max-frames", "3"]) == 2
    assert "depth000001.png" in capsys.readouterr().err
    skip = ["--set", "data.on_bad_frame=skip"]
    assert main(["run", *common, *skip, "--max-frames", "3"]) == 0
    # the skipped frame is counted as read, and said (#31): before, "read 2 frames: 2 mapped"
    assert "read 3 frames: 2 mapped, 1 skipped (data.on_bad_frame: skip)" in capsys.readouterr().out
    assert json.loads((out / "timings.json").read_text())["counts"]["frames_skipped_bad"] == 1
    # the checkpoint records the dataset position, not the count of mapped frames: frame 3 alone is left
    assert main(["run", *common, *skip, "--resume"]) == 0
    assert "read 1 frames: 1 mapped" in capsys.readouterr().out
    t = json.loads((out / "timings.json").read_text())
    assert t["counts"]["frames"] == 3


def test_unusable_device_is_a_clean_error(tmp_path, capsys):
    import torch

    from ogscene3d.device import resolve_device
    from ogscene3d.errors import ConfigError

    for bad in ("bogus", "mps", "cuda:99"):
        with pytest.raises(ConfigError, match="device="):
            resolve_device(bad)
    assert main(["run", "--out", str(tmp_path / "o"), "--device", "bogus", "--no-progress"]) == 2
    assert "device='bogus' is not supported" in capsys.readouterr().err
    if not torch.cuda.is_available():
        assert main(["run", "--out", str(tmp_path / "o"), "--device", "cuda", "--no-progress"]) == 2
        assert "sees no CUDA GPU" in capsys.readouterr().err


def test_resume_goes_on_with_the_runs_own_data_and_settings(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=3)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "2", "--set", "mapping.optimize.iters=2"]) == 0
    import yaml

    saved = yaml.safe_load((out / "config.yaml").read_text())
    assert saved["data"]["path"] == str(scene.resolve()) and saved["mapping"]["optimize"]["iters"] == 2
    capsys.readouterr()
    # no --data, no --config, no --set: the run's own config.yaml says what and how (never a synthetic scene)
    assert main(["run", "--out", str(out), "--resume", "--no-progress"]) == 0
    assert "read 1 frames: 1 mapped (3 keyframes in all)" in capsys.readouterr().out
    assert not (out / "scene").exists()
    t = json.loads((out / "timings.json").read_text())
    # module times go on across the resume: one 'add' per keyframe of the whole run
    assert t["counts"]["frames"] == 3 and t["calls"]["add"] == t["counts"]["keyframes"] == 3
    # (timings.json rounds seconds to the microsecond)
    assert t["ms_per_keyframe"]["add"] == pytest.approx(1000 * t["seconds"]["add"] / 3, abs=1e-2)
    assert len(t["per_keyframe_ms"]["add"]) == 3  # each keyframe's own time, across the resume too
    # a finished run has nothing left to do, and its files stay as they are
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert main(["run", "--out", str(out), "--resume", "--no-progress"]) == 0
    assert "nothing to do" in capsys.readouterr().out
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


def test_resume_refuses_another_sequence(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=2)
    other = _replica_scene(tmp_path / "other", frames=3)
    # another recording of the same layout: the same frame names, other images
    first = other / "results" / "frame000000.jpg"
    cv2.imwrite(str(first), 255 - cv2.imread(str(first)))
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out)]) == 0
    capsys.readouterr()
    assert main(["run", *_common(other, out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert f"was mapped from {scene.resolve()} (2 frames" in err and "new --out" in err
    # the same frames moved elsewhere are fine
    moved = tmp_path / "moved"
    scene.rename(moved)
    assert main(["run", *_common(moved, out), "--resume"]) == 0


def test_resume_of_a_bounded_run_from_a_moved_sequence(tmp_path, capsys):
    """A run stopped by --max-frames resumes from its sequence moved elsewhere: the frame count it recorded
    was the bounded selection's, so the first frame's bytes tell that the sequence is the same."""
    scene = _replica_scene(tmp_path / "scene", frames=3)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "1"]) == 0
    moved = tmp_path / "moved"
    scene.rename(moved)
    capsys.readouterr()
    assert main(["run", *_common(moved, out), "--resume"]) == 0
    assert json.loads((out / "timings.json").read_text())["counts"]["frames"] == 3


def test_resume_refuses_another_frame_selection(tmp_path, capsys):
    """The checkpoint's next frame is a position in the run's selection: a resume at another stride would map
    frames that position does not count (frames 0, 1 at stride 1, then frame 4 at stride 2)."""
    scene = _replica_scene(tmp_path / "scene", frames=5)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "2"]) == 0
    capsys.readouterr()
    for change in ("data.stride=2", "data.start=1"):
        assert main(["run", *_common(scene, out), "--resume", "--set", change]) == 2
        err = capsys.readouterr().err
        assert "mapped with data.start 0, data.stride 1" in err
        assert "a resume needs the run's frame selection" in err
    assert main(["run", *_common(scene, out), "--resume"]) == 0


def test_a_bad_frame_keeps_the_map_built_so_far(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=4)
    depth = scene / "results" / "depth000002.png"
    good = depth.read_bytes()
    garble_pixels(depth)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out)]) == 2
    assert "depth000002.png" in capsys.readouterr().err
    assert (out / "map.npz").is_file()  # frames 0 and 1, saved on the way out
    depth.write_bytes(good)
    assert main(["run", *_common(scene, out), "--resume"]) == 0
    assert "read 2 frames: 2 mapped (4 keyframes in all)" in capsys.readouterr().out


def test_odometry_run_writes_its_trajectory_and_fails_when_nothing_tracks(tmp_path, capsys):
    pytest.importorskip("open3d")
    from ogscene3d.datasets import make_synthetic_scene
    from ogscene3d.eval.trajectory import read_trajectory

    scene = make_synthetic_scene(tmp_path / "scene", seed=0, frames=60, width=96, height=72, progress=False)
    out = tmp_path / "run"
    args = ["run", "--data", str(scene), "--out", str(out), "--device", "cpu", "--no-progress",
            "--poses", "odometry", "--max-frames", "3",
            "--set", "mapping.optimize.iters=1", "--set", "graph.enabled=false"]  # fmt: skip
    assert main(args) == 0
    traj = read_trajectory(out / "traj.txt")
    assert traj.shape == (3, 4, 4)
    from ogscene3d.datasets import open_dataset

    gt = [f.pose for f in open_dataset(scene, max_frames=3)]
    assert np.linalg.norm(traj[2][:3, 3] - gt[2][:3, 3]) < 0.05  # anchored at frame 0's pose, then tracked

    flat = _replica_scene(tmp_path / "flat", frames=3)
    for p in (flat / "results").glob("depth*.png"):  # no depth: odometry cannot anchor any frame
        cv2.imwrite(str(p), np.zeros((H, W), np.uint16))
    capsys.readouterr()
    assert main(["run", *_common(flat, tmp_path / "run2"), "--poses", "odometry"]) == 2
    assert (
        "none of the 3 frames read could be mapped, 3 of them untracked by odometry"
        in capsys.readouterr().err
    )


def test_ctrl_c_stops_after_the_frame_and_saves_the_map(tmp_path, capsys, monkeypatch, stop_after_frame):
    import signal

    from ogscene3d.mapping.mapper import Mapper

    scene = _replica_scene(tmp_path / "scene", frames=4)
    out = tmp_path / "run"
    # Ctrl-C while frame 1 is being mapped
    process = stop_after_frame(1, lambda: signal.raise_signal(signal.SIGINT))
    before = signal.getsignal(signal.SIGINT)  # SIG_IGN where the tests run in the background (nohup ... &)
    assert main(["run", *_common(scene, out)]) == 130
    assert "stopped after 2 frames; the map so far is in" in capsys.readouterr().out
    assert signal.getsignal(signal.SIGINT) is before  # handlers restored
    monkeypatch.setattr(Mapper, "process", process)
    assert main(["run", *_common(scene, out), "--resume"]) == 0
    assert "read 2 frames: 2 mapped (4 keyframes in all)" in capsys.readouterr().out


def test_resume_cleans_up_and_refuses_another_camera(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=2)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "1"]) == 0
    leftover = out / ".map.k3wvhg1h.npz"  # a killed write's temporary file
    leftover.write_bytes(b"x" * 100)
    cam = json.loads((scene / "cam_params.json").read_text())
    cam["camera"]["fx"] = 30.0
    (scene / "cam_params.json").write_text(json.dumps(cam))
    capsys.readouterr()
    assert main(["run", *_common(scene, out), "--resume"]) == 2
    assert "mapped with intrinsics" in capsys.readouterr().err
    assert not leftover.exists()


def test_a_corrupt_checkpoint_and_an_unwritable_out_are_clean_errors(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=2)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "1"]) == 0
    data = (out / "map.npz").read_bytes()
    (out / "map.npz").write_bytes(data[: len(data) // 2])
    capsys.readouterr()
    assert main(["run", *_common(scene, out), "--resume"]) == 2
    assert "corrupt or truncated" in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    assert main(["run", *_common(scene, tmp_path / "file" / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ogscene3d run: error: ") and "Traceback" not in err


def test_resume_names_a_missing_memory_view_file(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=2)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "1"]) == 0
    (view,) = (out / "map_memory").iterdir()  # the first keyframe's view, in its own file
    view.unlink()
    capsys.readouterr()
    assert main(["run", *_common(scene, out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert f"{view}: memory view of keyframe 0 that map.npz needs does not exist" in err
    assert "Traceback" not in err


class _Killed(Exception):
    """A run killed while mapping (SIGKILL, out of memory): nothing after it runs, so nothing is saved."""


def _killed_run(argv):
    """``main(argv)``, killed at its first frame."""
    from ogscene3d.mapping.mapper import Mapper

    def killed(self, frame):
        raise _Killed

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Mapper, "process", killed)
        with pytest.raises(_Killed):
            main(argv)


def test_resume_refuses_a_map_beside_a_later_runs_config(tmp_path, capsys):
    """A new run into an old --out rewrites config.yaml at once but replaces map.npz only at its first save:
    killed before that, --resume would go on with the old map and the new settings."""
    scene = _replica_scene(tmp_path / "scene", frames=3)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "2"]) == 0
    old_map, old_config = (out / "map.npz").read_bytes(), (out / "config.yaml").read_text()
    _killed_run(["run", *_common(scene, out), "--set", "mapping.optimize.iters=2"])
    assert (out / "map.npz").read_bytes() == old_map and (out / "config.yaml").read_text() != old_config
    capsys.readouterr()
    assert main(["run", "--out", str(out), "--resume", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"{out / 'map.npz'} was not written by the run whose {out / 'config.yaml'} is there" in err
    assert "stopped before saving a map" in err and "without --resume" in err
    assert (out / "map.npz").read_bytes() == old_map  # refused before anything was written
    # the earlier run's config.yaml put back: the map goes on with its own settings
    (out / "config.yaml").write_text(old_config)
    assert main(["run", "--out", str(out), "--resume", "--no-progress"]) == 0
    assert "read 1 frames: 1 mapped (3 keyframes in all)" in capsys.readouterr().out


def test_resume_of_a_map_beside_a_later_runs_config_takes_its_settings_by_config(tmp_path, capsys):
    """The earlier run's settings passed with --config instead of put back into --out."""
    scene = _replica_scene(tmp_path / "scene", frames=3)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "2"]) == 0
    old = tmp_path / "old.yaml"
    old.write_text((out / "config.yaml").read_text())
    _killed_run(["run", *_common(scene, out), "--set", "mapping.optimize.iters=2"])
    capsys.readouterr()
    assert main(["run", "--out", str(out), "--resume", "--no-progress", "--config", str(old),
                 "--set", "mapping.optimize.iters=2"]) == 2  # fmt: skip
    assert "pass it with --config" in capsys.readouterr().err
    assert main(["run", "--out", str(out), "--resume", "--no-progress", "--config", str(old)]) == 0
    assert "read 1 frames: 1 mapped (3 keyframes in all)" in capsys.readouterr().out
    assert (out / "config.yaml").read_text() == old.read_text()


def test_resume_takes_an_earlier_map_made_with_the_same_settings(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=3)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "2"]) == 0
    _killed_run(["run", *_common(scene, out)])  # the same settings (--max-frames is not one)
    capsys.readouterr()
    assert main(["run", "--out", str(out), "--resume", "--no-progress"]) == 0
    assert "read 1 frames: 1 mapped (3 keyframes in all)" in capsys.readouterr().out


def test_a_resume_with_other_settings_killed_early_can_be_resumed_again(tmp_path, capsys):
    """The run id, not the settings, says whose map it is: a resume may change settings (--set)."""
    scene = _replica_scene(tmp_path / "scene", frames=3)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "2"]) == 0
    run_id = (out / "run_id").read_text()
    _killed_run(["run", *_common(scene, out), "--resume", "--set", "mapping.optimize.iters=2"])
    assert (out / "run_id").read_text() == run_id
    capsys.readouterr()
    assert main(["run", "--out", str(out), "--resume", "--no-progress"]) == 0
    assert "read 1 frames: 1 mapped (3 keyframes in all)" in capsys.readouterr().out


def test_the_run_id_check(tmp_path, caplog):
    """resumed_run_id: a map of an older version (no record) is resumed as it always was; a run killed
    between writing its id and its config.yaml leaves the earlier config.yaml, which the map matches."""
    from ogscene3d.config import load_config
    from ogscene3d.errors import DataError
    from ogscene3d.runs import resumed_run_id, start_run_dir

    out = tmp_path / "run"
    record = start_run_dir(out, load_config(None))
    assert resumed_run_id(out, record) == record["run_id"]
    assert resumed_run_id(out, {"path": "/x", "frames": 3}) is None
    (out / "run_id").write_text("another run\n")
    with caplog.at_level("INFO", logger="ogscene3d.runs.record"):
        assert resumed_run_id(out, record) == record["run_id"]
    assert "mapped by an earlier run with the settings of" in caplog.text
    start_run_dir(out, load_config(None, ["seed=1"]))
    with pytest.raises(DataError, match="was not written by the run whose"):
        resumed_run_id(out, record)
    with pytest.raises(DataError, match="was not written by the run whose"):
        resumed_run_id(out, record, load_config(None, ["seed=2"]))
    assert resumed_run_id(out, record, load_config(None)) == record["run_id"]  # the map's own settings
    assert resumed_run_id(out, {"path": "/x", "frames": 3}) is None


def test_resume_refuses_a_sequence_whose_mapped_frames_changed(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=4)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "2"]) == 0
    removed = {p: p.read_bytes() for p in (scene / "results").glob("*00001.*")}
    for p in removed:
        p.unlink()  # frame 1, mapped: frame 3 is now at position 2, where the resume would read frame 2
    capsys.readouterr()
    assert main(["run", *_common(scene, out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert f"{out / 'map.npz'}: the sequence changed since it was mapped" in err
    assert "frame 1 of the run's selection was 'results/frame000001.jpg' and is now " in err
    for p, data in removed.items():
        p.write_bytes(data)
    assert main(["run", *_common(scene, out), "--resume"]) == 0
    assert "read 2 frames: 2 mapped (4 keyframes in all)" in capsys.readouterr().out


def test_resume_maps_frames_added_after_the_mapped_ones(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=2)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out)]) == 0
    longer = _replica_scene(tmp_path / "longer", frames=3)
    for name in ("results/frame000002.jpg", "results/depth000002.png", "traj.txt"):
        (scene / name).write_bytes((longer / name).read_bytes())
    for p in (longer / "segs").iterdir():
        (scene / "segs" / p.name).write_bytes(p.read_bytes())
    capsys.readouterr()
    assert main(["run", *_common(scene, out), "--resume"]) == 0
    assert "read 1 frames: 1 mapped (3 keyframes in all)" in capsys.readouterr().out


def test_a_wrong_depth_scale_is_warned_about_once(tmp_path, caplog):
    """Frames from a dataset: its warning, naming data.depth_scale, and not the mapper's as well (which
    Frames given to the Mapper directly still get: test_mapping_mapper)."""
    from ogscene3d.config import load_config
    from ogscene3d.datasets import open_dataset
    from ogscene3d.mapping.mapper import Mapper

    scene = _replica_scene(tmp_path / "scene", frames=2)
    cfg = load_config(None, ["graph.enabled=false", "mapping.optimize.iters=1", "data.depth_scale=6.5535"])
    mapper = Mapper(cfg, "cpu")
    with caplog.at_level("WARNING"):
        for frame in open_dataset(scene, config=cfg.data):  # the wall 2 km away
            mapper.process(frame)
    warned = [r.getMessage() for r in caplog.records if "implausible" in r.getMessage()]
    assert len(warned) == 1 and "depth000000.png" in warned[0] and "data.depth_scale" in warned[0]


def test_a_resume_bounded_short_of_the_map_keeps_the_names_of_the_frames_it_read(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=4)
    depth = scene / "results" / "depth000002.png"
    good = depth.read_bytes()
    garble_pixels(depth)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out)]) == 2  # frames 0 and 1 saved on the way out
    # reads no frame, but finishes and saves the map: still naming both frames it has read
    assert main(["run", *_common(scene, out), "--resume", "--max-frames", "1"]) == 0
    depth.write_bytes(good)
    capsys.readouterr()
    assert main(["run", *_common(scene, out), "--resume"]) == 0
    assert "read 2 frames: 2 mapped (4 keyframes in all)" in capsys.readouterr().out


def test_resume_of_a_map_read_with_the_other_pixel_centres_names_the_setting(tmp_path, capsys):
    """A map made before data.pixel_centers shifted this layout's intrinsics (here: forced with --set) is
    refused with the setting that resumes it, and resumes with that setting."""
    scene = _replica_scene(tmp_path / "scene", frames=2)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "1"]) == 0
    capsys.readouterr()
    assert main(["run", *_common(scene, out), "--resume", "--set", "data.pixel_centers=integer"]) == 2
    err = capsys.readouterr().err
    assert "the same camera, read with data.pixel_centers=half" in err
    assert "resume with --set data.pixel_centers=half" in err
    assert main(["run", *_common(scene, out), "--resume", "--set", "data.pixel_centers=half"]) == 0
    # the other way round: its config.yaml keeps the setting a map was made with, unless --set again
    out = tmp_path / "run2"
    integer = ["--set", "data.pixel_centers=integer"]
    assert main(["run", *_common(scene, out), "--max-frames", "1", *integer]) == 0
    capsys.readouterr()
    assert main(["run", *_common(scene, out), "--resume", "--set", "data.pixel_centers=half"]) == 2
    assert "resume with --set data.pixel_centers=integer" in capsys.readouterr().err
    assert main(["run", *_common(scene, out), "--resume"]) == 0


def test_a_save_outside_a_run_leaves_no_earlier_runs_id_to_vouch_for_its_config(tmp_path, capsys):
    """The live viewer saves with Mapper.save, whose map names no run: stopped between its config.yaml and
    its map.npz in a run's folder, the run's id left there would pair the run's map with the viewer's
    settings on --resume."""
    from ogscene3d.config import load_config
    from ogscene3d.datasets import open_dataset
    from ogscene3d.mapping.mapper import Mapper
    from ogscene3d.mapping.source import dataset_source, record_data

    scene = _replica_scene(tmp_path / "scene", frames=3)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "2"]) == 0
    cfg = load_config(
        None, ["graph.enabled=false", "mapping.optimize.iters=2", "mapping.association.knn_radius=0.1"]
    )
    record_data(cfg, scene, scene / "segs")
    ds = open_dataset(config=cfg.data)
    mapper = Mapper(cfg, "cpu")
    mapper.source = dataset_source(cfg, ds)  # as ogscene3d-live sets it
    for frame in ds:
        mapper.process(frame)
    mapper.finalize()

    def full(self, path):
        raise OSError("no space left on device")

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Mapper, "save_checkpoint", full)
        with pytest.raises(OSError):
            mapper.save(out)
    assert "iters: 2" in (out / "config.yaml").read_text() and not (out / "run_id").exists()
    capsys.readouterr()
    assert main(["run", "--out", str(out), "--resume", "--no-progress"]) == 2
    assert "was not written by the run whose" in capsys.readouterr().err
    # saved in full, the viewer's map (no run recorded) resumes, as before
    mapper.save(out)
    assert main(["run", "--out", str(out), "--resume", "--no-progress"]) == 0


def test_an_older_map_resumed_short_of_where_it_got_is_resumed_again(tmp_path, capsys):
    """A map.npz of an older version names no frames: a resume bounded by --max-frames before its next frame
    names only those it selected, fewer than the map has read, which read as frames removed since."""
    scene = _replica_scene(tmp_path / "scene", frames=4)
    depth = scene / "results" / "depth000002.png"
    good = depth.read_bytes()
    garble_pixels(depth)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out)]) == 2  # frames 0 and 1 saved on the way out
    with np.load(out / "map.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    source = json.loads(str(arrays["mapper_source"]))
    for key in ("names", "run_id", "config"):  # what an older version recorded
        del source[key]
    arrays["mapper_source"] = np.array(json.dumps(source))
    np.savez(out / "map.npz", **arrays)
    assert main(["run", *_common(scene, out), "--resume", "--max-frames", "1"]) == 0
    depth.write_bytes(good)
    capsys.readouterr()
    assert main(["run", *_common(scene, out), "--resume"]) == 0
    assert "read 2 frames: 2 mapped (4 keyframes in all)" in capsys.readouterr().out
