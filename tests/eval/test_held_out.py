"""``eval --held-out``: 2D views among the frames a run did not map (its config.yaml's frame selection, and
how far map.npz says it got), the error when it mapped every frame, refused --view-frames, the report's
fields, and naming frames kept apart from the held-out views."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from eval_runs import _main, make_labelfusion, write_wall_run

from ogscene3d.datasets import open_dataset
from ogscene3d.errors import DataError
from ogscene3d.eval.held_out import pick_held_out, run_frames
from ogscene3d.eval.views import open_view_dataset

N = 8  # frames of the sequence
# camera x per frame: small (the wall run covers every view) and no pixel centre on the class boundary
SHIFTS = [0.0005 + 0.0025 * i for i in range(N)]


def make_sequence(root: Path) -> Path:
    """A label-fusion sequence of N frames of the wall of ``write_wall_run``: class 8 left, 22 right."""
    make_labelfusion(root, SHIFTS)
    (root / "classes.json").write_text(json.dumps({"0": "background", "8": "mug", "22": "box"}))
    return root


def make_run(tmp_path: Path, data: str = "", next_index: int | None = None) -> tuple[Path, Path]:
    """The wall run, recorded as mapped from the sequence with the data settings ``data`` (YAML lines);
    ``next_index``: a map.npz saying the run stopped after that many frames of its selection."""
    seq = make_sequence(tmp_path / "seq")
    run = write_wall_run(tmp_path / "run")
    (run / "config.yaml").write_text(f"data:\n  path: {seq}\n{data}")
    if next_index is not None:
        first = open_dataset(seq).records[0].name
        source = json.dumps({"path": str(seq), "frames": N, "first": first})
        np.savez(run / "map.npz", mapper_next_index=np.array(next_index), mapper_source=np.array(source))
    return seq, run


@pytest.mark.parametrize(
    ("data", "next_index", "mapped", "held_out", "extrapolated"),
    [
        # every odd frame; 7 lies after the last mapped frame (6): extrapolation, left out
        ("  stride: 2\n", None, [0, 2, 4, 6], [1, 3, 5], False),
        # frame 0 lies before the first mapped frame: left out too
        ("  start: 1\n  stride: 2\n", None, [1, 3, 5, 7], [2, 4, 6], False),
        ("  stride: 3\n  max_frames: 2\n", None, [0, 3], [1, 2], False),
        # the run stopped after 2 of its 4 frames (map.npz): 5 is no longer between mapped frames
        ("  stride: 2\n", 2, [0, 2], [1], False),
        # nothing unmapped between mapped frames: the frames after them, flagged as extrapolation
        ("  max_frames: 5\n", None, [0, 1, 2, 3, 4], [5, 6, 7], True),
    ],
)
def test_held_out_frames_are_the_frames_the_run_did_not_map(
    tmp_path, data, next_index, mapped, held_out, extrapolated
):
    seq, run = make_run(tmp_path, data, next_index)
    ds = open_view_dataset(seq, run)
    frames = run_frames(run, ds)
    assert frames.mapped == mapped
    held = pick_held_out(ds, frames, num_views=10)
    assert held.frames == held_out and held.extrapolated == extrapolated
    # fewer views: spread evenly over the same frames
    assert set(pick_held_out(ds, frames, num_views=2).frames) <= set(held_out)


def test_a_checkpoint_of_another_frame_selection_is_refused(tmp_path):
    """map.npz's next frame counts positions in the selection it was mapped with: a config.yaml of another
    stride cannot say which frames those were."""
    seq, run = make_run(tmp_path, "  stride: 2\n")
    first = open_dataset(seq).records[0].name
    source = {"path": str(seq), "frames": N, "first": first, "start": 0, "stride": 1}
    np.savez(run / "map.npz", mapper_next_index=np.array(3), mapper_source=np.array(json.dumps(source)))
    with pytest.raises(DataError, match="mapped with data.stride 1, but the run's config.yaml says 2"):
        run_frames(run, open_view_dataset(seq, run))
    source["stride"] = 2
    np.savez(run / "map.npz", mapper_next_index=np.array(3), mapper_source=np.array(json.dumps(source)))
    assert run_frames(run, open_view_dataset(seq, run)).mapped == [0, 2, 4]


def test_a_run_that_mapped_every_frame_has_no_held_out_view(tmp_path, monkeypatch, capsys):
    seq, run = make_run(tmp_path)
    argv = ["eval", str(run), "--gt", str(seq), "--views", "3", "--held-out", "--no-plots"]
    assert _main(argv, monkeypatch) == 2
    err = capsys.readouterr().err
    assert "no held-out frame" in err and "mapped every frame" in err and "--set data.stride=2" in err


def test_held_out_needs_the_run_config_and_views(tmp_path, monkeypatch, capsys):
    seq, run = make_run(tmp_path, "  stride: 2\n")
    argv = ["eval", str(run), "--gt", str(seq), "--held-out", "--no-plots"]
    assert _main([*argv, "--views", "0"], monkeypatch) == 2
    assert "--held-out needs views to score" in capsys.readouterr().err
    (run / "config.yaml").unlink()
    with pytest.raises(DataError, match="config.yaml"):
        run_frames(run, open_view_dataset(seq))


def test_held_out_eval_reports_novel_views_and_names_labels_from_mapped_frames(tmp_path, monkeypatch, capsys):
    seq, run = make_run(tmp_path, "  stride: 2\n")
    argv = ["eval", str(run), "--gt", str(seq), "--views", "2", "--held-out", "--no-plots"]
    assert _main(argv, monkeypatch) == 0
    out = capsys.readouterr().out
    assert "held-out views [1, 5]: frames the run did not map (novel views between mapped frames" in out
    report = json.loads((run / "metrics.json").read_text())
    v = report["semantic_2d"]
    assert v["held_out"] is True and v["extrapolated"] is False and v["frames"] == [1, 5]
    assert v["protocol"].startswith("rendered-view-2d (held-out novel views")
    assert "not held-out" not in v["protocol"] and "frames [1, 5]" in v["protocol"]
    assert v["run_frames"]["num_mapped"] == 4 and v["run_frames"]["last"] == 6
    # the oracle 2D naming reads as many mapped frames, not the held-out views it is scored on
    assert v["mapping_frames"] == [0, 6] and report["label_mapping"]["frames"] == [0, 6]
    assert any("reads frames [0, 6], none of the held-out views" in n for n in report["notes"])
    assert v["miou"] > 0.9


def test_held_out_view_frames_refuse_frames_the_run_mapped(tmp_path, monkeypatch, capsys):
    seq, run = make_run(tmp_path, "  stride: 2\n")
    argv = ["eval", str(run), "--gt", str(seq), "--held-out", "--no-plots", "--view-frames"]
    assert _main([*argv, "1,2,4"], monkeypatch) == 2
    err = capsys.readouterr().err
    assert "the run mapped view frames 2, 4" in err and "did not map include 1, 3, 5, 7" in err
    # a frame after the last mapped one may be asked for: it is flagged as extrapolation
    assert _main([*argv, "3,7"], monkeypatch) == 0
    v = json.loads((run / "metrics.json").read_text())["semantic_2d"]
    assert v["frames"] == [3, 7] and v["held_out"] and v["extrapolated"]
    assert "extrapolated views" in v["protocol"]


def test_held_out_naming_frames_given_among_the_scored_ones_are_noted(tmp_path, monkeypatch):
    seq, run = make_run(tmp_path, "  stride: 2\n")
    argv = ["eval", str(run), "--gt", str(seq), "--held-out", "--view-frames", "3", "--no-plots"]
    assert _main([*argv, "--mapping-frames", "2,3"], monkeypatch) == 0
    report = json.loads((run / "metrics.json").read_text())
    assert report["semantic_2d"]["mapping_frames"] == [2, 3]
    assert any("reads held-out frames [3] that are scored" in n for n in report["notes"])


def test_ordinary_views_say_which_of_them_the_run_mapped(tmp_path, monkeypatch, capsys):
    seq, run = make_run(tmp_path, "  stride: 2\n")
    assert _main(["eval", str(run), "--gt", str(seq), "--views", "3", "--no-plots"], monkeypatch) == 0
    assert "views [0, 4, 7]: frames of the mapped sequence, 2 of the 3 mapped by the run" in (
        capsys.readouterr().out
    )
    v = json.loads((run / "metrics.json").read_text())["semantic_2d"]
    assert v["held_out"] is False and v["run_frames"] is None and v["scored_frames_mapped"] == [0, 4]
    assert "not held-out novel views" in v["protocol"]


def test_eval_batch_scores_held_out_views(tmp_path, capsys):
    from ogscene3d.cli import main

    seq = make_sequence(tmp_path / "seq")
    run = write_wall_run(tmp_path / "out" / "wall")
    (run / "config.yaml").write_text(f"data:\n  path: {seq}\n  stride: 2\n")
    assert main(["eval-batch", str(tmp_path / "out"), "--no-plots", "--views", "2", "--held-out"]) == 0
    assert "2D mIoU held-out" in capsys.readouterr().out
    rec = json.loads((tmp_path / "out" / "eval_batch.json").read_text())["scenes"][0]
    assert rec["semantic_2d"]["held_out"] is True and "held-out novel views" in rec["semantic_2d"]["protocol"]
    assert json.loads((run / "metrics.json").read_text())["semantic_2d"]["frames"] == [1, 5]


def test_held_out_views_of_a_synthetic_run_with_3d_ground_truth(tmp_path, monkeypatch):
    """With 3D ground truth (and graph tags) nothing is named from renders: only held-out views render."""
    synthetic = pytest.importorskip("ogscene3d.datasets.synthetic")
    from eval_runs import _run_from_ground_truth

    from ogscene3d.eval import load_ground_truth

    scene_dir = synthetic.make_synthetic_scene(tmp_path / "scene", seed=1, frames=3, width=48, height=36)
    run = tmp_path / "run"
    _run_from_ground_truth(load_ground_truth(scene_dir), run)
    (run / "config.yaml").write_text(f"data:\n  path: {scene_dir}\n  stride: 2\n")
    assert _main(["eval", str(run), "--views", "3", "--held-out", "--no-plots"], monkeypatch) == 0
    report = json.loads((run / "metrics.json").read_text())
    v = report["semantic_2d"]
    assert v["frames"] == [1] and v["held_out"] and not v["extrapolated"] and v["mapping_frames"] is None
    assert report["label_mapping"]["method"] == "text" and v["run_frames"]["num_mapped"] == 2
    assert report["semantic_3d"]["hovsg"]["miou"] > 0.7 and v["overall_acc"] > 0.65


def record_map(run: Path, next_index: int) -> None:
    """map.npz as ``ogscene3d run`` writes it for the run's config.yaml: how far it got, and the frames of
    its selection by name."""
    from ogscene3d.config import load_config
    from ogscene3d.mapping.source import dataset_source

    cfg = load_config(run / "config.yaml")
    source = dataset_source(cfg, open_dataset(config=cfg.data))
    np.savez(
        run / "map.npz", mapper_next_index=np.array(next_index), mapper_source=np.array(json.dumps(source))
    )


def test_held_out_refuses_a_sequence_that_changed_since_it_was_mapped(tmp_path, monkeypatch, capsys):
    """Frame 1, held out, removed: the stride-2 selection becomes frames 0, 3, 5, 7, and without the names
    the run recorded, 3 and 5 would count as mapped and 2 and 4, which the run mapped, as held out."""
    seq, run = make_run(tmp_path, "  stride: 2\n")
    record_map(run, next_index=3)
    assert run_frames(run, open_view_dataset(seq, run)).mapped == [0, 2, 4]
    removed = {p: p.read_bytes() for p in seq.glob("frame-000001.*")}
    for p in removed:
        p.unlink()
    with pytest.raises(DataError, match="the sequence changed since the run mapped it") as e:
        run_frames(run, open_view_dataset(seq, run))
    was, now = "'frame-000002.color.png'", "'frame-000003.color.png'"
    assert f"frame 1 of the run's selection was {was} and is now {now}" in str(e.value)
    argv = ["eval", str(run), "--gt", str(seq), "--views", "2", "--held-out", "--no-plots"]
    assert _main(argv, monkeypatch) == 2
    assert "the sequence changed since the run mapped it" in capsys.readouterr().err
    # frames 4 to 7 removed instead: the selection is frames 0 and 2, fewer than the run read
    for p, data in removed.items():
        p.write_bytes(data)
    for i in range(4, N):
        for p in seq.glob(f"frame-{i:06d}.*"):
            p.unlink()
    with pytest.raises(DataError, match="the run read 3 frames of its selection, which now holds 2"):
        run_frames(run, open_view_dataset(seq, run))


def test_held_out_takes_frames_added_after_the_mapped_ones(tmp_path):
    seq, run = make_run(tmp_path, "  stride: 2\n")
    later = {p: p.read_bytes() for p in [*seq.glob("frame-000006.*"), *seq.glob("frame-000007.*")]}
    for p in later:
        p.unlink()
    record_map(run, next_index=3)  # frames 0, 2, 4 of 0..5
    for p, data in later.items():
        p.write_bytes(data)
    ds = open_view_dataset(seq, run)
    frames = run_frames(run, ds)
    assert frames.mapped == [0, 2, 4] and pick_held_out(ds, frames, num_views=10).frames == [1, 3]


def test_held_out_with_a_map_that_records_no_frame_names_notes_it(tmp_path, caplog):
    seq, run = make_run(tmp_path, "  stride: 2\n", next_index=2)  # an older version's map.npz
    with caplog.at_level("INFO", logger="ogscene3d.eval.held_out"):
        assert run_frames(run, open_view_dataset(seq, run)).mapped == [0, 2]
    assert "records no frame names (an older version)" in caplog.text
