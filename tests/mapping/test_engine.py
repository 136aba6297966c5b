"""The run lifecycle of mapping/engine.py through the commands: one writer per run directory, a stop or a
full disk never loses the map, an empty map is an error, and the counts of the summary line (#31, #30)."""

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import cv2
import numpy as np
import pytest
from layout_scenes import garble_pixels
from mapping_scenes import H, W, _common, _replica_scene

from ogscene3d.cli import main
from ogscene3d.runs import LOCK, RunDirBusyError, RunDirLock, run_directory

# ------------------------------------------------------------------------------------------- the lock

_HOLDER = textwrap.dedent(
    """
    import sys, time
    from ogscene3d.runs import RunDirLock
    lock = RunDirLock(sys.argv[1], "run")
    lock.acquire()
    print("locked", flush=True)
    time.sleep(120)
    """
)


def _holder(out):
    """A second process holding the lock on ``out`` (started, and locked, when this returns)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    line = proc.stdout.readline()
    assert line.strip() == "locked", proc.stderr.read()
    return proc


def test_a_second_writer_is_refused_naming_the_holder_and_a_killed_ones_lock_does_not_block(tmp_path, capsys):
    scene = _replica_scene(tmp_path / "scene", frames=2)
    out = tmp_path / "run"
    out.mkdir()
    proc = _holder(out)
    try:
        assert main(["run", *_common(scene, out)]) == 2
        err = capsys.readouterr().err
        assert f"pid {proc.pid} on " in err and "is being written by another run" in err
        assert "give another --out" in err and "started " in err
        assert not (out / "config.yaml").exists()  # refused before writing anything
    finally:
        proc.send_signal(signal.SIGKILL)  # kill -9: the lock file stays, the kernel drops the lock
        proc.wait()
    assert (out / LOCK).is_file()
    assert main(["run", *_common(scene, out)]) == 0
    assert (out / "map.npz").is_file() and not (out / LOCK).exists()  # released at the end


def test_the_lock_is_one_per_folder_and_free_again_after_release(tmp_path):
    out = tmp_path / "run"
    out.mkdir()  # kept: run_directory removes only a folder it created and left empty
    with run_directory(out, "run"):
        with pytest.raises(RunDirBusyError, match=f"pid {os.getpid()} "):
            RunDirLock(out, "live").acquire()
        (tmp_path / "other").mkdir()
        with RunDirLock(tmp_path / "other", "run"):  # another folder: another lock
            pass
    with RunDirLock(out, "live"):  # released: free again
        pass


def test_a_filesystem_without_locks_warns_and_runs(tmp_path, monkeypatch, caplog):
    import fcntl

    def no_locks(fd, op):
        raise OSError(errno.ENOLCK, os.strerror(errno.ENOLCK))

    monkeypatch.setattr(fcntl, "flock", no_locks)
    with caplog.at_level("WARNING"), RunDirLock(tmp_path, "run"):
        pass
    assert "refuses file locks" in caplog.text and not (tmp_path / LOCK).exists()


def test_run_batch_scenes_and_live_take_the_lock(tmp_path, capsys):
    from ogscene3d.batch import SceneSpec, map_scene
    from ogscene3d.commands.live import main as live_main

    scene = _replica_scene(tmp_path / "scene", frames=2)
    out = tmp_path / "batch"
    (out / "a").mkdir(parents=True)
    proc = _holder(out / "a")
    try:
        with pytest.raises(RunDirBusyError, match=f"pid {proc.pid} "):
            map_scene(SceneSpec("a", data=str(scene)), out, overrides=["graph.enabled=false"], device="cpu")
        assert live_main(["--data", str(scene), "--out", str(out / "a"), "--port", "0"]) == 2
        assert f"pid {proc.pid} " in capsys.readouterr().err
    finally:
        proc.kill()
        proc.wait()


def test_a_run_refused_before_its_first_write_leaves_no_empty_folder(tmp_path, capsys):
    out = tmp_path / "runs" / "y"
    assert main(["run", "--data", str(tmp_path / "nonexistent"), "--out", str(out), "--no-progress"]) == 2
    assert "nonexistent" in capsys.readouterr().err
    assert not out.exists()
    out.mkdir(parents=True)  # a folder that was there before stays
    assert main(["run", "--data", str(tmp_path / "nonexistent"), "--out", str(out), "--no-progress"]) == 2
    assert out.is_dir() and not any(out.iterdir())


# ------------------------------------------------------------------------------------------- stops


def test_a_stopped_run_leaves_what_eval_and_the_viewer_read(tmp_path, capsys, monkeypatch, stop_after_frame):
    from ogscene3d.eval import read_run
    from ogscene3d.mapping.mapper import Mapper
    from ogscene3d.viewer.runs import load_run

    scene = _replica_scene(tmp_path / "scene", frames=4)
    out = tmp_path / "run"
    process = stop_after_frame(1, lambda: signal.raise_signal(signal.SIGTERM))
    assert main(["run", *_common(scene, out)]) == 130
    assert "--resume --out" in capsys.readouterr().out
    for name in ("map.npz", "gaussians.ply", "graph.json", "timings.json", "config.yaml"):
        assert (out / name).is_file(), name
    snap, info = load_run(out)  # the viewer's reader
    assert snap.total_gaussians > 0
    assert len(read_run(out).means) == snap.total_gaussians  # eval's reader
    with np.load(out / "map.npz") as z:
        assert not bool(z["mapper_finalized"])  # a resume goes on from it
    monkeypatch.setattr(Mapper, "process", process)
    assert main(["run", *_common(scene, out), "--resume"]) == 0
    assert "read 2 frames: 2 mapped (4 keyframes in all)" in capsys.readouterr().out


def test_live_mapping_saves_the_map_on_sigterm(tmp_path, capsys, monkeypatch, stop_after_frame):
    """Before: the map was saved only once mapping finished; a stop exited 0 with no folder."""
    from ogscene3d.commands.live import main as live_main
    from ogscene3d.mapping.mapper import Mapper

    scene = _replica_scene(tmp_path / "scene", frames=4)
    out = tmp_path / "live"

    def terminate():
        os.kill(os.getpid(), signal.SIGTERM)  # handled by the main thread, which stops the session
        time.sleep(1.0)

    process = stop_after_frame(1, terminate)
    args = ["--data", str(scene), "--segments", str(scene / "segs"), "--out", str(out), "--port", "0",
            "--device", "cpu", "--set", "graph.enabled=false",
            "--set", "mapping.optimize.iters=1"]  # fmt: skip
    assert live_main(args) == 130
    assert "the map so far is in" in capsys.readouterr().out
    for name in ("map.npz", "gaussians.ply", "config.yaml", "run_id"):
        assert (out / name).is_file(), name
    assert not (out / LOCK).exists()
    monkeypatch.setattr(Mapper, "process", process)
    # the live run goes on with `ogscene3d run --resume`
    assert main(["run", "--out", str(out), "--resume", "--no-progress"]) == 0
    assert "read 2 frames: 2 mapped (4 keyframes in all)" in capsys.readouterr().out


def test_a_stopped_batch_scene_keeps_its_map_and_stops_the_batch(tmp_path, stop_after_frame):
    from ogscene3d.batch import SceneSpec, map_scene

    scene = _replica_scene(tmp_path / "scene", frames=4)
    stop_after_frame(1, lambda: signal.raise_signal(signal.SIGINT))
    spec = SceneSpec("a", data=str(scene), segments=str(scene / "segs"))
    ov = ["graph.enabled=false", "mapping.optimize.iters=1", "mapping.association.knn_radius=0.1"]
    with pytest.raises(KeyboardInterrupt, match="stopped after 2 frames"):
        map_scene(spec, tmp_path / "out", overrides=ov, device="cpu")
    run = tmp_path / "out" / "a"
    assert (run / "map.npz").is_file() and (run / "gaussians.ply").is_file()
    assert json.loads((run / "timings.json").read_text())["finalized"] is False


# --------------------------------------------------------------------------------------- full disk


def _full_disk(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_full_disk_at_the_exports_keeps_the_resumable_map_and_says_how_on(tmp_path, capsys, monkeypatch):
    from ogscene3d.gaussians import GaussianMap

    scene = _replica_scene(tmp_path / "scene", frames=2)
    out = tmp_path / "run"
    export = GaussianMap.export_ply
    monkeypatch.setattr(GaussianMap, "export_ply", _full_disk)
    assert main(["run", *_common(scene, out)]) == 2
    err = capsys.readouterr().err
    assert f"could not write {out / 'gaussians.ply'}: No space left on device" in err
    assert "written: config.yaml, map.npz" in err
    assert f"free some space, then `ogscene3d run --resume --out {out}` writes the rest" in err
    assert (out / "map.npz").is_file() and not (out / "gaussians.ply").exists()
    monkeypatch.setattr(GaussianMap, "export_ply", export)
    assert main(["run", *_common(scene, out), "--resume"]) == 0
    assert "nothing to do" in capsys.readouterr().out
    assert (out / "gaussians.ply").is_file() and (out / "graph.json").is_file()


def test_a_full_disk_at_the_map_names_what_is_left(tmp_path, capsys, monkeypatch):
    from ogscene3d.gaussians import GaussianMap

    scene = _replica_scene(tmp_path / "scene", frames=2)
    out = tmp_path / "run"
    monkeypatch.setattr(GaussianMap, "save_npz", _full_disk)
    assert main(["run", *_common(scene, out)]) == 2
    err = capsys.readouterr().err
    assert f"could not write {out / 'map.npz'}: No space left on device; written: config.yaml" in err
    assert "free some space (or give another --out) and run again" in err
    # with a checkpoint of the run on disk, the message points at it
    monkeypatch.undo()
    assert main(["run", *_common(scene, out), "--max-frames", "1"]) == 0
    monkeypatch.setattr(GaussianMap, "save_npz", _full_disk)
    assert main(["run", *_common(scene, out), "--resume"]) == 2
    assert (
        "holds an earlier checkpoint: free some space, then `ogscene3d run --resume"
        in capsys.readouterr().err
    )


# ------------------------------------------------------------------------------------------- depth 0


def _zero_depth(scene, frames):
    for i in frames:
        cv2.imwrite(str(scene / "results" / f"depth{i:06d}.png"), np.zeros((H, W), np.uint16))


def test_all_zero_depth_fails_the_run_and_each_such_keyframe_is_warned_about(tmp_path, capsys, caplog):
    scene = _replica_scene(tmp_path / "scene", frames=3)
    _zero_depth(scene, range(3))
    out = tmp_path / "run"
    with caplog.at_level("WARNING"):
        assert main(["run", *_common(scene, out)]) == 2
    err = capsys.readouterr().err
    assert "nothing could be mapped, the map has 0 Gaussians" in err and "3 of its 3 keyframes" in err
    assert "data.depth_scale" in err
    warned = [r.getMessage() for r in caplog.records if "without a valid depth pixel" in r.getMessage()]
    assert len(warned) == 3 and "frame 0 " in warned[0]
    assert not (out / "map.npz").exists()


def test_one_zero_depth_keyframe_is_warned_about_and_the_run_goes_on(tmp_path, capsys, caplog):
    scene = _replica_scene(tmp_path / "scene", frames=3)
    _zero_depth(scene, [1])
    out = tmp_path / "run"
    with caplog.at_level("WARNING"):
        assert main(["run", *_common(scene, out)]) == 0
    warned = [r.getMessage() for r in caplog.records if "without a valid depth pixel" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith("frame 1 (")
    assert json.loads((out / "timings.json").read_text())["counts"]["keyframes_no_depth"] == 1


# ---------------------------------------------------------------------------------------- counters


def test_a_resume_bounded_at_or_before_the_map_says_so(tmp_path, capsys, caplog):
    scene = _replica_scene(tmp_path / "scene", frames=3)
    depth = scene / "results" / "depth000002.png"
    garble_pixels(depth)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out)]) == 2  # frames 0 and 1 saved on the way out
    with caplog.at_level("WARNING"):
        assert main(["run", *_common(scene, out), "--resume", "--max-frames", "2"]) == 0
    assert "--max-frames ends at or before frame 2, where the map already is" in caplog.text
    assert "leave --max-frames out, or raise it" in caplog.text


def test_bad_frames_skipped_before_a_failing_frame_are_counted_in_the_saved_map(tmp_path, monkeypatch):
    from ogscene3d.errors import DataError
    from ogscene3d.mapping.mapper import Mapper

    scene = _replica_scene(tmp_path / "scene", frames=4)
    garble_pixels(scene / "results" / "depth000001.png")
    out = tmp_path / "run"
    process = Mapper.process

    def fails_at_frame_3(self, frame):
        if frame.index == 3:
            raise DataError("frame 3: a segmenter's bad output")
        return process(self, frame)

    monkeypatch.setattr(Mapper, "process", fails_at_frame_3)
    assert main(["run", *_common(scene, out), "--set", "data.on_bad_frame=skip"]) == 2
    assert json.loads((out / "timings.json").read_text())["counts"]["frames_skipped_bad"] == 1


def test_timings_count_the_labels_of_the_final_map(tmp_path):
    """The final pass relabels and prunes: the counts are the saved map's, not the last keyframe's."""
    from ogscene3d.config import load_config
    from ogscene3d.datasets import open_dataset
    from ogscene3d.gaussians import GaussianMap
    from ogscene3d.mapping.mapper import Mapper
    from ogscene3d.mapping.source import record_data

    scene = _replica_scene(tmp_path / "scene", frames=2)
    cfg = load_config(
        None, ["graph.enabled=false", "mapping.optimize.iters=1", "mapping.association.knn_radius=0.1"]
    )
    record_data(cfg, scene, scene / "segs")
    mapper = Mapper(cfg, "cpu")
    for frame in open_dataset(config=cfg.data):
        mapper.process(frame)
    labels = mapper.map.labels
    assert int(mapper.timings.counts["labels"]) >= 2
    mapper.map.opacity_logits[labels == labels.max()] = -20.0  # one label's Gaussians all pruned at the end
    mapper.finalize()
    mapper.save(tmp_path / "run")
    saved = GaussianMap.load_npz(tmp_path / "run" / "map.npz")
    counts = json.loads((tmp_path / "run" / "timings.json").read_text())["counts"]
    assert counts["labels"] == len(set(saved.labels[saved.labels >= 0].tolist()))
    assert counts["gaussians"] == len(saved)


def test_observers_see_every_keyframe_and_the_end_and_one_that_fails_is_dropped(tmp_path, caplog):
    """MappingEngine's observers (Rerun logging, the run-time estimate): called after each keyframe with its
    seconds and after the final pass; one that raises is warned about and dropped, and the run goes on."""
    from ogscene3d.config import load_config
    from ogscene3d.datasets import open_dataset
    from ogscene3d.mapping.engine import MappingEngine
    from ogscene3d.mapping.mapper import Mapper
    from ogscene3d.mapping.source import record_data

    class Watcher:
        def __init__(self, fail: bool = False) -> None:
            self.fail, self.seen, self.ended = fail, [], False

        def keyframe(self, mapper, frame, seconds):
            if self.fail:
                raise RuntimeError("viewer gone")
            self.seen.append((frame.index, mapper.keyframe_count, seconds))

        def finished(self, mapper):
            self.ended = True

    scene = _replica_scene(tmp_path / "scene", frames=4)
    cfg = load_config(None, ["graph.enabled=false", "mapping.optimize.iters=1", "mapping.keyframe_every=2"])
    record_data(cfg, scene, scene / "segs")
    good, bad = Watcher(), Watcher(fail=True)
    engine = MappingEngine(Mapper(cfg, "cpu"), tmp_path / "run", scene, observers=[bad, good])
    engine.open(cfg, open_dataset(config=cfg.data))
    with caplog.at_level("WARNING", logger="ogscene3d.mapping.engine"):
        summary = engine.run(open_dataset(config=cfg.data).frames(), total=4)
    assert summary.status == "finished" and (tmp_path / "run" / "map.npz").is_file()
    assert [(i, k) for i, k, _ in good.seen] == [(0, 1), (2, 2)] and all(s > 0 for *_, s in good.seen)
    assert good.ended and engine.observers == [good]
    assert "Watcher stopped after an error: RuntimeError: viewer gone" in caplog.text


# ------------------------------------------------------------------------------------------- #30 live


def test_live_synthetic_uses_the_synthetic_config_and_renders_only_the_mapped_frames(tmp_path, monkeypatch):
    from ogscene3d.commands.live import build_parser, live_config, live_data

    monkeypatch.chdir(tmp_path)  # the default scene folder, outputs/live-synthetic, is relative
    small = ["--set", "synthetic.width=32", "--set", "synthetic.height=24"]
    args = build_parser().parse_args(["--synthetic", "--max-frames", "3", *small])
    cfg = live_config(args)
    assert cfg.mapping.keyframe_every == 2 and cfg.synthetic.frames == 60  # configs/synthetic.yaml
    data = live_data(args, cfg)
    assert len(list((data / "results").glob("frame*.jpg"))) == 3
    # that default folder is a cache: other settings make the scene again there
    args = build_parser().parse_args(["--synthetic", "--max-frames", "2", *small])
    assert live_data(args, live_config(args)) == data
    assert len(list((data / "results").glob("frame*.jpg"))) == 2
    # a folder the user named is never overwritten
    args = build_parser().parse_args(
        ["--synthetic", "--synthetic-dir", str(data), "--max-frames", "3", *small]
    )
    with pytest.raises(Exception, match="give another --synthetic-dir"):
        live_data(args, live_config(args))
    args = build_parser().parse_args(["--synthetic", "--config", str(tmp_path / "missing.yaml")])
    with pytest.raises(Exception, match="missing.yaml"):
        live_config(args)


def test_frames_the_dataset_leaves_out_at_open_count_as_skipped(tmp_path, capsys):
    # a frame whose colour file is missing is left out when the dataset opens (data.on_bad_frame: skip),
    # before the frame loop: the summary and timings.json count it with the other skipped frames
    scene = _replica_scene(tmp_path / "scene", frames=4)
    (scene / "results" / "frame000002.jpg").unlink()
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--set", "data.on_bad_frame=skip"]) == 0
    assert "read 4 frames: 3 mapped, 1 skipped (data.on_bad_frame: skip)" in capsys.readouterr().out
    assert json.loads((out / "timings.json").read_text())["counts"]["frames_skipped_bad"] == 1


def test_run_says_which_config_to_use_for_small_images(tmp_path, caplog):
    # the paper's optimisation budget on small images is slow and moves the Gaussians off the surfaces
    # (docs/defaults.md): `run` names the config to use, and stays quiet with that config's budget
    scene = _replica_scene(tmp_path / "scene", frames=2)
    with caplog.at_level("WARNING"):
        assert main(["run", *_common(scene, tmp_path / "a"), "--set", "mapping.optimize.iters=10"]) == 0
    assert "use --config synthetic" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):
        assert main(["run", *_common(scene, tmp_path / "b"), "--set", "mapping.optimize.iters=3"]) == 0
    assert "use --config synthetic" not in caplog.text


def test_a_resume_bounded_at_a_finished_maps_end_says_so(tmp_path, capsys):
    # the map was finished at --max-frames 2: a resume bounded there reads nothing, and must not claim the
    # map covers every frame of the sequence
    scene = _replica_scene(tmp_path / "scene", frames=3)
    out = tmp_path / "run"
    assert main(["run", *_common(scene, out), "--max-frames", "2"]) == 0
    capsys.readouterr()
    assert main(["run", *_common(scene, out), "--resume", "--max-frames", "2"]) == 0
    said = capsys.readouterr().out
    assert "--max-frames 2 ends at or before frame 2" in said and "every frame" not in said
