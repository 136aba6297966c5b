"""2D rendered-view evaluation of real-data layouts whose frames carry class maps: label-fusion's segm
images, ScanNet's label-filt (raw ids -> NYU40 through scannetv2-labels.combined.tsv), with or without 3D
ground truth."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
from dataset_files import _png, _rgb
from eval_runs import (
    K_FILE,
    SHIFTS,
    H,
    K,
    W,
    Z,
    _left_right,
    _main,
    _pose,
    _write_ply,
    make_labelfusion,
    write_wall_run,
)

from ogscene3d.datasets import open_dataset
from ogscene3d.datasets.scannet import NYU40_CLASSES
from ogscene3d.errors import DataError
from ogscene3d.eval import load_ground_truth
from ogscene3d.eval.views import open_view_dataset, overlap_mapping_2d, render_views

TSV = (
    "id\traw_category\tcategory\tcount\tnyu40id\teigen13id\tnyu40class\n"
    "1\tchair\tchair\t10\t5\t4\tchair\n"
    "40\ttable\ttable\t10\t7\t10\ttable\n"
    "41\tdecoration\tdecoration\t3\t\t\t\n"  # a category without an NYU40 class
)


def make_scannet(root: Path, tsv: bool = True, label_scale: int = 2) -> Path:
    """A ScanNet export of the same wall: colour (and label-filt) at twice the depth size, raw category 1
    (NYU40 chair) left, 40 (table) right, a column of raw 41 (no NYU40 class) and one of 999 (not in the
    tsv)."""
    for i, tx in enumerate(SHIFTS):
        _png(root / "color" / f"{i}.jpg", _rgb(H * label_scale, W * label_scale, i))
        _png(root / "depth" / f"{i}.png", np.full((H, W), int(Z * 1000), np.uint16))
        (root / "pose").mkdir(exist_ok=True)
        np.savetxt(root / "pose" / f"{i}.txt", _pose(tx))
        raw = _left_right(tx, 1, 40, W * label_scale, H * label_scale).astype(np.uint16)
        raw[:, :label_scale] = 41
        raw[:, -label_scale:] = 999
        _png(root / "label-filt" / f"{i}.png", raw)
    (root / "intrinsic").mkdir()
    np.savetxt(
        root / "intrinsic" / "intrinsic_depth.txt", np.pad(K_FILE, ((0, 1), (0, 1))) + np.diag([0, 0, 0, 1])
    )
    if tsv:
        (root.parent / "scannetv2-labels.combined.tsv").write_text(
            TSV
        )  # beside the scenes, as ScanNet has it
    return root


# --------------------------------------------------------------------------------------- readers


def test_scannet_label_filt_becomes_nyu40_class_maps(tmp_path):
    # at 3x the depth size a depth pixel's centre is a label pixel's centre (at 2x it lies between two)
    ds = open_dataset(make_scannet(tmp_path / "scans" / "scene0000_00", label_scale=3))
    assert ds.kind == "scannet" and ds.has_class_maps and ds.class_names == NYU40_CLASSES
    f = ds[1]
    # resampled from 96x72 to the depth size by nearest neighbour; raw ids -> NYU40, unmapped -> 0 (void)
    expected = _left_right(SHIFTS[1], 5, 7)
    expected[:, 0] = 0
    expected[:, -1] = 0
    np.testing.assert_array_equal(f.gt_classes, expected)


def test_scannet_label_filt_without_label_map_is_warned_about(tmp_path, caplog):
    root = make_scannet(tmp_path / "scene0000_00", tsv=False)
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(root)
    assert not ds.has_class_maps and ds[0].gt_classes is None and ds.class_names is None
    assert any("scannetv2-labels.combined.tsv" in r.getMessage() for r in caplog.records)


def test_scannet_label_image_of_another_shape_is_an_error(tmp_path):
    root = make_scannet(tmp_path / "scans" / "scene0000_00")
    _png(root / "label-filt" / "2.png", np.zeros((H, 2 * W), np.uint16))
    with pytest.raises(DataError, match=r"label-filt/2\.png: ScanNet label is 64x24"):
        open_dataset(root)[2]


def test_scannet_label_resampling_samples_pixel_centres(tmp_path):
    """ScanNet's 1296x968 labels go to 640x480 depth beside INTER_AREA colour: each label pixel must come from
    the source pixel under its centre (INTER_NEAREST takes the top-left one, ~1 source pixel off)."""
    from ogscene3d.datasets.base import read_label_png

    src_w, src_h = 65, 49  # 2.03x the 32x24 depth, as 1296x968 is 2.025x 640x480
    cols = np.repeat(np.arange(src_w, dtype=np.uint16)[None], src_h, axis=0)
    rows = np.repeat(np.arange(src_h, dtype=np.uint16)[:, None], src_w, axis=1)
    for img, n_src, n_dst, axis in ((cols, src_w, W, 1), (rows, src_h, H, 0)):
        out = read_label_png(_png(tmp_path / f"l{axis}.png", img), (H, W), "label", resize=True)
        centre = (np.arange(n_dst) + 0.5) * n_src / n_dst - 0.5  # source coordinate under each pixel centre
        got = out.mean(axis=1 - axis)
        assert np.abs(got - centre).max() <= 0.55 and abs(float(np.mean(got - centre))) < 0.2


def test_bad_scannet_label_map_is_an_error_naming_the_file(tmp_path):
    root = make_scannet(tmp_path / "scans" / "scene0000_00")
    tsv = tmp_path / "scans" / "scannetv2-labels.combined.tsv"
    tsv.write_text("id\tnyu40\n1\t5\n")
    with pytest.raises(DataError, match=r"scannetv2-labels\.combined\.tsv: .*'nyu40id'"):
        open_dataset(root)
    tsv.write_text("id\tnyu40id\nchair\t5\n")
    with pytest.raises(DataError, match=r"tsv: line 2: id='chair'"):
        open_dataset(root)


def test_labelfusion_folder_is_a_2d_only_ground_truth(tmp_path):
    seq = make_labelfusion(tmp_path / "shelf")
    with pytest.raises(
        DataError, match=r"shelf: its labelfusion frames carry class ids but no class names.*--classes"
    ):
        load_ground_truth(seq)
    (seq / "classes.json").write_text(json.dumps({"0": "background", "8": "mug", "22": "box"}))
    gt = load_ground_truth(seq)
    assert not gt.has_3d and gt.points.shape == (0, 3)
    assert gt.class_names == ["background", "mug", "box"] and gt.class_ids == [0, 8, 22]
    table = tmp_path / "names.json"
    table.write_text(json.dumps(["a"] * 8 + ["cup"] + ["b"] * 13 + ["crate"]))
    assert load_ground_truth(seq, classes=table).class_names[8] == "cup"  # --classes wins


def test_scannet_labels_ply_gets_nyu40_names_and_is_preferred(tmp_path):
    root = make_scannet(tmp_path / "scans" / "scene0000_00")
    gt = load_ground_truth(root)  # no labels PLY: the frames' NYU40 maps only
    assert not gt.has_3d and gt.class_names == list(NYU40_CLASSES.values())
    _write_labels_ply(root)
    mesh = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    _write_ply(root / "scene0000_00_vh_clean_2.ply", mesh)  # the unlabelled mesh beside it
    gt = load_ground_truth(root)
    assert gt.has_3d and gt.source.endswith("scene0000_00_vh_clean_2.labels.ply")
    assert gt.class_names[gt.classes[0]] == "chair" and gt.class_names[gt.classes[-1]] == "table"


def _write_labels_ply(root: Path) -> None:
    xs, ys = np.meshgrid(np.arange(-0.4, 0.46, 0.02), np.arange(-0.3, 0.31, 0.02))
    pts = np.zeros(xs.size, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "<u2")])
    pts["x"], pts["y"], pts["z"] = xs.ravel(), ys.ravel(), Z
    pts["label"] = np.where(xs.ravel() < 0, 5, 7)  # NYU40 chair, table
    order = np.argsort(pts["x"], kind="stable")
    _write_ply(root / "scene0000_00_vh_clean_2.labels.ply", pts[order])


def test_scannet_labels_ply_warns_only_about_ids_no_table_explains(tmp_path, caplog):
    """ScanNet's id 0 (unannotated) and the NYU40 ids a scannet20 table voids on purpose are void without
    a warning; an id outside NYU40 is warned about."""
    pts = np.zeros(4, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "<u2")])
    pts["x"] = np.arange(4)
    pts["label"] = [0, 5, 13, 45]  # unannotated, chair, blinds (not in the 20), no NYU40 class
    _write_ply(tmp_path / "scene0000_00_vh_clean_2.labels.ply", pts)
    for classes, void in ((None, [0, 3]), ("scannet20", [0, 2, 3])):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            gt = load_ground_truth(tmp_path / "scene0000_00_vh_clean_2.labels.ply", classes=classes)
        assert np.flatnonzero(gt.classes < 0).tolist() == void
        warned = [r.getMessage() for r in caplog.records if "absent from" in r.getMessage()]
        assert len(warned) == 1 and ": 1 points have class ids" in warned[0], warned


# --------------------------------------------------------------------------------------- rendering


def test_rendered_views_name_scene_labels_by_2d_overlap(tmp_path):
    seq = make_labelfusion(tmp_path / "shelf")
    (seq / "classes.json").write_text(json.dumps({"8": "mug", "22": "box"}))
    gt = load_ground_truth(seq)
    run = write_wall_run(tmp_path / "run")
    views = render_views(run, open_view_dataset(seq, run), gt, [0, 2])
    assert sorted(views) == [0, 2] and views[2].name == "frame-000002.color"
    assert overlap_mapping_2d(views.values()) == {3: 0, 7: 1}
    assert overlap_mapping_2d([]) == {}


def test_overlap_mapping_counts_weights():
    from ogscene3d.eval import majority_overlap_mapping

    assert majority_overlap_mapping(np.array([1, 1]), np.array([0, 2])) == {1: 0}  # a tie: smaller id
    assert majority_overlap_mapping(np.array([1, 1]), np.array([0, 2]), weights=[1, 5]) == {1: 2}
    with pytest.raises(ValueError, match="weights"):
        majority_overlap_mapping(np.array([1, 1]), np.array([0, 2]), weights=[1, -5])


# --------------------------------------------------------------------------------------- eval


def _labelfusion_run(tmp_path, graph=None):
    seq = make_labelfusion(tmp_path / "shelf")
    (seq / "classes.json").write_text(json.dumps({"0": "background", "8": "mug", "22": "box"}))
    return seq, write_wall_run(tmp_path / "run", graph=graph)


def test_labelfusion_eval_is_2d_only_with_an_oracle_2d_naming(tmp_path, monkeypatch, capsys):
    seq, run = _labelfusion_run(tmp_path)
    assert _main(["eval", str(run), "--gt", str(seq), "--views", "3"], monkeypatch) == 0
    out = capsys.readouterr().out
    assert (
        "label mapping: overlap (oracle: names scene labels from the GT) from the rendered frames [0, 1, 2]"
        in out
    )
    assert "no 3D ground truth: 2D only" in out and "frames scored: frame-000000.color" in out
    report = json.loads((run / "metrics.json").read_text())
    assert not report["has_3d_ground_truth"] and report["semantic_3d"] == {} and report["gt_points"] is None
    assert report["scene_graph"] is None and any(
        "rendered-view (2D) scores only" in n for n in report["notes"]
    )
    m = report["label_mapping"]
    assert m["method"] == "overlap" and m["space"] == "2d" and m["frames"] == [0, 1, 2]
    assert "oracle" in m["description"] and m["num_mapped_labels"] == 2
    v = report["semantic_2d"]
    assert (
        v["frames"] == [0, 1, 2] and v["mapping_frames"] == [0, 1, 2] and v["dataset_kind"] == "labelfusion"
    )
    # the splats reproduce the two halves but for the class boundary's column
    assert v["miou"] > 0.9 and {c["name"] for c in v["per_class"] if c["iou"] is not None} == {"mug", "box"}
    assert len(v["pictures"]) == 3 and (run / v["pictures"][0]).is_file()


def test_2d_naming_frames_and_scored_frames_are_reported_apart(tmp_path, monkeypatch):
    seq, run = _labelfusion_run(tmp_path)
    argv = ["eval", str(run), "--gt", str(seq), "--view-frames", "2", "--mapping-frames", "0,1", "--no-plots"]
    assert _main(argv, monkeypatch) == 0
    report = json.loads((run / "metrics.json").read_text())
    assert report["label_mapping"]["frames"] == [0, 1]
    assert report["semantic_2d"]["frames"] == [2] and report["semantic_2d"]["mapping_frames"] == [0, 1]
    assert report["semantic_2d"]["frame_names"] == ["frame-000002.color"]


def test_2d_only_eval_names_labels_by_text_without_3d_ground_truth(tmp_path, monkeypatch, capsys):
    graph = {"nodes": [{"id": 3, "tag": "mugs"}, {"id": 7, "tag": "box"}], "edges": []}
    seq, run = _labelfusion_run(tmp_path, graph=graph)
    (run / "config.yaml").write_text(f"data:\n  path: {seq}\n  stride: 2\n")  # eval finds the GT here
    assert _main(["eval", str(run), "--views", "2", "--no-plots"], monkeypatch) == 0
    assert "oracle" not in capsys.readouterr().out
    report = json.loads((run / "metrics.json").read_text())
    assert report["label_mapping"]["method"] == "text" and report["semantic_2d"]["mapping_frames"] is None
    assert report["semantic_2d"]["frames"] == [0, 2]  # every frame of the sequence, not the run's stride
    assert report["semantic_2d"]["miou"] > 0.9


def test_2d_only_eval_needs_views(tmp_path, monkeypatch, capsys):
    seq, run = _labelfusion_run(tmp_path)
    assert _main(["eval", str(run), "--gt", str(seq), "--views", "0"], monkeypatch) == 2
    assert "no 3D ground truth, only per-frame class maps: render views" in capsys.readouterr().err
    assert _main(["eval", str(run), "--gt", str(seq), "--view-frames", "7"], monkeypatch) == 2
    assert "view frame 7 out of range [0, 3)" in capsys.readouterr().err


def test_scannet_folder_scored_in_2d_alone_then_in_3d_and_2d(tmp_path, monkeypatch):
    root = make_scannet(tmp_path / "scans" / "scene0000_00")
    run = write_wall_run(tmp_path / "run")
    assert _main(["eval", str(run), "--gt", str(root), "--views", "2", "--no-plots"], monkeypatch) == 0
    report = json.loads((run / "metrics.json").read_text())
    assert not report["has_3d_ground_truth"] and report["label_mapping"]["space"] == "2d"
    named = {c["name"]: c["iou"] for c in report["semantic_2d"]["per_class"] if c["iou"] is not None}
    assert set(named) == {"chair", "table"} and min(named.values()) > 0.85  # NYU40 names, void edges

    _write_labels_ply(root)  # ScanNet's 3D ground truth: now the naming is 3D overlap, both blocks scored
    argv = ["eval", str(run), "--gt", str(root), "--views", "2", "--no-plots", "--mapping-frames", "1"]
    assert _main(argv, monkeypatch) == 0
    report = json.loads((run / "metrics.json").read_text())
    assert report["has_3d_ground_truth"] and report["label_mapping"]["space"] == "3d"
    assert report["semantic_3d"]["hovsg"]["miou"] == pytest.approx(1.0)
    assert report["semantic_2d"]["miou"] > 0.85 and report["semantic_2d"]["mapping_frames"] is None
    assert any("mapping frames not used" in n for n in report["notes"])
    # the labels PLY inside the scene folder: its frames are rendered when the run mapped that folder
    (run / "config.yaml").write_text(f"data:\n  path: {root}\n")
    argv = ["eval", str(run), "--gt", str(root / "scene0000_00_vh_clean_2.labels.ply"), "--views", "1"]
    assert _main([*argv, "--no-plots"], monkeypatch) == 0
    assert json.loads((run / "metrics.json").read_text())["semantic_2d"]["frames"] == [0]


def test_evenly_spread_views_pass_over_lost_tracking_poses(tmp_path, monkeypatch, capsys):
    """ScanNet writes -inf poses where tracking was lost: an even spread of views picks other frames (and
    says so); a lost frame asked for by number is an error naming its pose file."""
    root = make_scannet(tmp_path / "scans" / "scene0000_00")
    np.savetxt(root / "pose" / "1.txt", np.full((4, 4), -np.inf))
    run = write_wall_run(tmp_path / "run")
    assert _main(["eval", str(run), "--gt", str(root), "--views", "3", "--no-plots"], monkeypatch) == 0
    report = json.loads((run / "metrics.json").read_text())
    assert report["semantic_2d"]["frames"] == [0, 2]
    assert any("1 frames without a valid pose" in n for n in report["notes"])
    capsys.readouterr()
    argv = ["eval", str(run), "--gt", str(root), "--view-frames", "1", "--no-plots"]
    assert _main(argv, monkeypatch) == 2
    assert "1.txt" in capsys.readouterr().err


def test_scannet20_classes_give_hovsg_scannet_preset_its_class_set(tmp_path, monkeypatch):
    """HOV-SG scores ScanNet on the 20 benchmark classes: --classes scannet20 keeps those (other NYU40 ids
    void: their predictions are HOV-SG false positives), and the preset over all 40 NYU40 names says that
    classes outside the 20 stay in the means."""
    from ogscene3d.datasets.scannet import SCANNET20_IDS

    root = make_scannet(tmp_path / "scans" / "scene0000_00")
    xs, ys = np.meshgrid(np.arange(-0.4, 0.46, 0.02), np.arange(-0.3, 0.31, 0.02))
    pts = np.zeros(xs.size, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "<u2")])
    pts["x"], pts["y"], pts["z"] = xs.ravel(), ys.ravel(), Z
    # NYU40 chair | table, and a top band of ceiling (22), which is not one of ScanNet's 20 classes
    pts["label"] = np.where(ys.ravel() > 0.2, 22, np.where(xs.ravel() < 0, 5, 7))
    _write_ply(root / "scene0000_00_vh_clean_2.labels.ply", pts)
    run = write_wall_run(tmp_path / "run")
    argv = ["eval", str(run), "--gt", str(root), "--views", "0", "--no-plots", "--mapping", "overlap",
            "--ignore", "preset:hovsg-scannet"]  # fmt: skip

    assert _main(argv, monkeypatch) == 0
    report = json.loads((run / "metrics.json").read_text())
    hovsg = report["semantic_3d"]["hovsg"]
    assert [c["name"] for c in hovsg["per_class"] if c["evaluated"]] == ["chair", "table", "ceiling"]
    assert any("preset:hovsg-scannet" in n and "ceiling" in n for n in report["notes"])

    assert _main([*argv, "--classes", "scannet20"], monkeypatch) == 0
    report = json.loads((run / "metrics.json").read_text())
    hovsg = report["semantic_3d"]["hovsg"]
    assert len(hovsg["per_class"]) == 20 and "ceiling" not in [c["name"] for c in hovsg["per_class"]]
    assert [c["name"] for c in hovsg["per_class"] if c["evaluated"]] == ["chair", "table"]
    assert hovsg["void_false_positives"] == int((pts["label"] == 22).sum())
    assert not any("preset:hovsg-scannet" in n for n in report["notes"])
    assert load_ground_truth(root, "scannet20").class_ids == list(SCANNET20_IDS)


def test_eval_batch_takes_a_class_table_for_2d_only_scenes(tmp_path, capsys):
    """A label-fusion run whose data folder has no classes.json: eval-batch's error asks for --classes, so
    eval-batch must take it (and --views, which 2D-only scenes need)."""
    from ogscene3d.cli import main

    data = make_labelfusion(tmp_path / "shelf")
    run = write_wall_run(tmp_path / "out" / "shelf")
    (run / "config.yaml").write_text(f"data:\n  path: {data}\n")
    (tmp_path / "names.json").write_text(json.dumps({"8": "box", "22": "mug"}))
    argv = ["eval-batch", str(tmp_path / "out"), "--no-plots", "--views", "2"]
    assert main(argv) == 2  # (every scene failed)
    assert "--classes" in capsys.readouterr().out
    assert main([*argv, "--classes", str(tmp_path / "names.json")]) == 0
    rec = json.loads((tmp_path / "out" / "eval_batch.json").read_text())["scenes"][0]
    assert rec["status"] == "ok" and rec["semantic_3d"] == {} and rec["semantic_2d"]["miou"] > 0.85


def test_shared_labelfusion_sample_end_to_end(shared_data, tmp_path, monkeypatch, capsys):
    """Map the real label-fusion sample (every third frame, no optimisation steps, classical segments),
    then score it in 2D against its segm images."""
    from ogscene3d import cli

    seq = shared_data / "labelfusion_shelf_labels"
    run = tmp_path / "run"
    sets = [
        "data.stride=3",
        "mapping.init.pixels_per_gaussian=64",
        "mapping.optimize.iters=0",
        "segmentation.backend=classical",
    ]
    argv = ["run", "--data", str(seq), "--out", str(run), "--device", "cpu", "--no-progress"]
    for s in sets:
        argv += ["--set", s]
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["ogscene3d.commands.run", "ogscene3d.commands.eval"])
    assert cli.main(argv) == 0
    table = tmp_path / "classes.json"
    table.write_text(json.dumps({"0": "background", "8": "object 8", "22": "object 22"}))
    assert cli.main(["eval", str(run), "--classes", str(table), "--views", "3", "--no-plots"]) == 0
    report = json.loads((run / "metrics.json").read_text())
    assert report["ground_truth"].startswith(str(seq.resolve())) and not report["has_3d_ground_truth"]
    v = report["semantic_2d"]
    assert v["frames"] == [0, 7, 14] and report["label_mapping"]["frames"] == [0, 7, 14]
    assert 0.0 < v["miou"] <= 1.0 and 0.0 < v["overall_acc"] <= 1.0
    print(json.dumps({k: v[k] for k in ("miou", "fmiou", "macc", "overall_acc")}))
    print({c["name"]: c["iou"] for c in v["per_class"]})


def test_views_of_a_run_mapped_before_pixel_centres_use_the_camera_it_was_mapped_with(tmp_path):
    """A label-fusion run whose map.npz records the colour intrinsics unshifted (mapped before
    data.pixel_centers) is rendered with them; one mapped with today's K, or without a map, with today's."""
    from ogscene3d.config import Config, save_config

    seq = make_labelfusion(tmp_path / "shelf")
    run = tmp_path / "run"
    run.mkdir()
    cfg = Config()
    cfg.data.path = str(seq)
    save_config(cfg, run / "config.yaml")
    np.testing.assert_allclose(open_view_dataset(seq, run).K, K)
    np.savez(run / "map.npz", mapper_source=json.dumps({"K": K_FILE.ravel().tolist()}))
    np.testing.assert_allclose(open_view_dataset(seq, run).K, K_FILE)
    np.savez(run / "map.npz", mapper_source=json.dumps({"K": K.ravel().tolist()}))
    np.testing.assert_allclose(open_view_dataset(seq, run).K, K)


def test_a_scannet_map_of_colour_intrinsics_made_before_pixel_centres_is_recognised(tmp_path):
    """ScanNet's colour K rescaled to the depth size: today's differs from the one read before
    data.pixel_centers by half a pixel times the scale (here 0.25 px), not by 0.5; eval still renders such a
    map with the camera it was mapped with, and --resume still names the setting that resumes it."""
    from ogscene3d.config import Config, DataConfig, save_config
    from ogscene3d.mapping.source import check_same_source, matching_pixel_centers

    seq = make_scannet(tmp_path / "scans" / "scene0000_00")
    (seq / "intrinsic" / "intrinsic_depth.txt").unlink()
    half = np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])
    K_colour = np.diag([2.0, 2.0, 1.0]) @ K - half  # the camera at the colour size, pixel centres from 0
    np.savetxt(
        seq / "intrinsic" / "intrinsic_color.txt", np.pad(K_colour, ((0, 1), (0, 1))) + np.diag([0, 0, 0, 1])
    )
    ds = open_dataset(seq)
    np.testing.assert_allclose(ds.K, K)
    before = K - half / 2  # the colour K scaled as it is
    assert matching_pixel_centers(ds, before.ravel()) == "half"
    assert matching_pixel_centers(ds, (before + half / 5).ravel()) is None
    run = tmp_path / "run"
    run.mkdir()
    cfg = Config()
    cfg.data.path = str(seq)
    save_config(cfg, run / "config.yaml")
    np.savez(run / "map.npz", mapper_source=json.dumps({"K": before.ravel().tolist()}))
    np.testing.assert_allclose(open_view_dataset(seq, run).K, before)
    current = {"K": ds.K.ravel().tolist()}

    def matching(K):
        return matching_pixel_centers(ds, K)

    with pytest.raises(DataError, match="resume with --set data.pixel_centers=half"):
        check_same_source(run / "map.npz", {"K": before.ravel().tolist()}, current, 0, matching)
    other = (before + half / 5).ravel().tolist()  # another camera: not taken for the old reading
    np.savez(run / "map.npz", mapper_source=json.dumps({"K": other}))
    np.testing.assert_allclose(open_view_dataset(seq, run).K, K)
    with pytest.raises(DataError, match="another camera or image size"):
        check_same_source(run / "map.npz", {"K": other}, current, 0, matching)
    # read with either setting, the other one is named; label-fusion's files are shifted by 0.5
    assert matching_pixel_centers(open_dataset(seq, config=DataConfig(pixel_centers="half")), K.ravel()) == (
        "integer"
    )
    assert matching_pixel_centers(open_dataset(make_labelfusion(tmp_path / "lf")), K_FILE.ravel()) == "half"


def test_views_read_no_segments_of_the_run(tmp_path, caplog):
    """eval renders the map: the run's data.segments_dir is not read (no warning about frames without
    segments, which held-out frames often are)."""
    from ogscene3d.config import Config, save_config

    seq = make_labelfusion(tmp_path / "shelf")
    run = tmp_path / "run"
    run.mkdir()
    (tmp_path / "segs").mkdir()
    cfg = Config()
    cfg.data.path = str(seq)
    cfg.data.segments_dir = str(tmp_path / "segs")
    save_config(cfg, run / "config.yaml")
    ds = open_view_dataset(seq, run)
    with caplog.at_level("WARNING"):
        frame = ds[0]
    assert frame.segments is None and "segments" not in caplog.text
