"""``ogscene3d eval`` on a tiny hand-made run directory and a synthetic-layout ground truth."""

import json

import numpy as np
import pytest
from eval_runs import GAUSSIAN_DTYPE, _main, _run_from_ground_truth, _write_ply
from plyfile import PlyData

from ogscene3d import cli
from ogscene3d.errors import DataError
from ogscene3d.eval import evaluate_run, find_ground_truth, load_ground_truth, pick_frames


def _line(xs):
    xs = np.asarray(xs, dtype=np.float64)
    return np.stack([xs, np.ones_like(xs), np.zeros_like(xs)], axis=1)


@pytest.fixture
def scene(tmp_path):
    """chair (instance 1) at x = 0..4, table (2) at x = 10..14, wall (3) at x = 20..24."""
    gt = tmp_path / "scene" / "gt"
    gt.mkdir(parents=True)
    xs = np.concatenate([np.arange(5), np.arange(10, 15), np.arange(20, 25)]).astype(float)
    inst = np.repeat([1, 2, 3], 5)
    pts = np.zeros(
        15, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("instance", "<i4"), ("class", "<i4")]
    )
    p = _line(xs)
    pts["x"], pts["y"], pts["z"] = p.T
    pts["instance"] = inst
    pts["class"] = inst  # class ids equal instance ids here
    _write_ply(gt / "points.ply", pts)
    mesh = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    _write_ply(gt / "mesh.ply", mesh)  # a second PLY the reader must not pick
    (gt / "instances.json").write_text(
        json.dumps(
            {
                "version": 1,
                "classes": {"1": "chair", "2": "table", "3": "wall"},
                "instances": {
                    "1": {"class": "chair", "class_id": 1},
                    "2": {"class": "table", "class_id": 2},
                    "3": {"class": "wall", "class_id": 3, "structural": True},
                },
                "relations": [[1, "next to", 2], [2, "attached to", 3]],
                "symmetric_relations": ["next to"],
                "inverse_relations": {"on": "under", "under": "on"},
            }
        )
    )
    # Gaussians 5 cm beside every GT point; the one at table x = 10 wrongly carries the chair label 7.
    run = tmp_path / "run"
    run.mkdir()
    g = np.zeros(15, dtype=GAUSSIAN_DTYPE)
    gp = _line(xs + 0.05)
    g["x"], g["y"], g["z"] = gp.T
    g["opacity"] = 2.0
    g["rot_0"] = 1.0
    g["label"] = [7] * 6 + [8] * 4 + [9] * 5
    g["confidence"] = 0.9
    _write_ply(run / "gaussians.ply", g)
    nodes = [{"id": i, "label": i, "tag": t} for i, t in ((7, "Chairs"), (8, "table"), (9, "wall"))]
    edges = [{"source": 8, "target": 7, "relation": "next to", "score": 1.0}]
    (run / "graph.json").write_text(json.dumps({"version": 1, "nodes": nodes, "edges": edges}))
    return run, tmp_path / "scene"


def test_eval_module_is_registered():
    assert "ogscene3d.commands.eval" in cli.COMMAND_MODULES


def test_ground_truth_reader_synthetic_layout(scene):
    _, scene_dir = scene
    gt = load_ground_truth(scene_dir)
    assert gt.class_names == ["chair", "table", "wall"]
    assert gt.points.shape == (15, 3) and gt.classes.tolist() == [0] * 5 + [1] * 5 + [2] * 5
    assert gt.instance_classes == {1: 0, 2: 1, 3: 2} and len(gt.relations) == 2
    assert gt.symmetric_relations == ["next to"]


def test_eval_cli_both_protocols(scene, monkeypatch, capsys, tmp_path):
    run, scene_dir = scene
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    gt_pos = np.random.default_rng(0).normal(size=(6, 3))
    est_pos = gt_pos @ rot.T + 1.0

    def poses(pos):
        return "\n".join(" ".join(map(str, np.r_[np.c_[np.eye(3), p].reshape(-1), 0, 0, 0, 1])) for p in pos)

    (tmp_path / "est.txt").write_text(poses(est_pos))
    (tmp_path / "gt.txt").write_text(poses(gt_pos))
    argv = ["eval", str(run), "--gt", str(scene_dir), "--protocol", "both"]
    assert _main(argv + ["--traj", str(tmp_path / "est.txt"), str(tmp_path / "gt.txt")], monkeypatch) == 0
    out = capsys.readouterr().out
    assert "protocol: hovsg" in out and "protocol: conceptgraphs" in out and "relation recall" in out
    assert "label mapping: text," in out and "oracle" not in out  # tags name the labels, not the GT
    assert "15 Gaussians (0.0% unlabelled" in out
    report = json.loads((run / "metrics.json").read_text())
    assert report["label_mapping"]["method"] == "text"
    assert report["label_mapping"]["num_mapped_labels"] == 3
    h = report["semantic_3d"]["hovsg"]
    # The k=5 vote outvotes the single wrong Gaussian; wall is ignored by default.
    assert h["protocol"].startswith("hovsg") and h["miou"] == pytest.approx(1.0)
    assert h["ignored_classes"] == ["wall"]
    c = report["semantic_3d"]["conceptgraphs"]
    # Counted on Gaussians: chair TP 5 FP 1, table TP 4 FN 1, wall exact.
    assert c["miou"] == pytest.approx((5 / 6 + 4 / 5 + 1.0) / 3)
    assert (run / "iou_hovsg.png").is_file() and (run / "iou_conceptgraphs.png").is_file()
    g = report["scene_graph"]
    assert g["recall"] == pytest.approx(0.5) and g["num_no_edge"] == 1
    assert g["node_matches"] == {"1": 7, "2": 8, "3": 9}
    assert report["trajectory"]["ate_rmse_m"] < 1e-9


def test_eval_overlap_mapping_and_ignore_override(scene):
    run, scene_dir = scene
    res = evaluate_run(run, scene_dir, protocols=["hovsg"], ignore=[], mapping="overlap")
    assert res.label_to_class == {7: 0, 8: 1, 9: 2}
    assert res.report["label_mapping"]["method"] == "overlap"
    assert res.semantic["hovsg"].num_evaluated == 3 and res.semantic["hovsg"].miou == pytest.approx(1.0)


def test_auto_mapping_ignores_heuristic_tags(scene):
    run, scene_dir = scene
    graph = json.loads((run / "graph.json").read_text())
    for n in graph["nodes"]:
        n["caption_source"] = "heuristic"  # e.g. "wall" from geometry: names no object class reliably
    (run / "graph.json").write_text(json.dumps(graph))
    res = evaluate_run(run, scene_dir, protocols=["hovsg"], ignore=[])
    assert res.report["label_mapping"]["method"] == "overlap"


def test_labelled_ply_ground_truth_with_class_table(scene, tmp_path):
    run, _ = scene
    arr = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "<i4")])
    arr["x"] = [0.0, 10.0, 20.0]
    arr["label"] = [4, 9, 99]  # 99 is not in the table: void
    _write_ply(tmp_path / "gt.ply", arr)
    (tmp_path / "names.json").write_text(json.dumps({"4": "chair", "9": "table"}))
    gt = load_ground_truth(tmp_path / "gt.ply", classes=tmp_path / "names.json")
    assert gt.class_names == ["chair", "table"] and gt.classes.tolist() == [0, 1, -1]
    res = evaluate_run(run, tmp_path / "gt.ply", protocols=["conceptgraphs"], classes=tmp_path / "names.json")
    assert res.report["scene_graph"] is None and res.report["notes"]
    with pytest.raises(DataError, match="class-name table"):
        load_ground_truth(tmp_path / "gt.ply")


def test_eval_cli_errors(scene, monkeypatch, capsys, tmp_path):
    run, scene_dir = scene
    (run / "gaussians.ply").unlink()
    assert _main(["eval", str(run), "--gt", str(scene_dir)], monkeypatch) == 2
    assert "gaussians.ply" in capsys.readouterr().err
    (run / "gaussians.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 5\n")
    with pytest.raises(DataError, match="gaussians.ply"):
        evaluate_run(run, scene_dir)
    with pytest.raises(DataError, match="not found"):
        evaluate_run(tmp_path / "nope", scene_dir)
    capsys.readouterr()
    assert _main(["eval", str(run), "--gt", str(scene_dir), "--view-frames", "1,x"], monkeypatch) == 2
    assert "--view-frames" in capsys.readouterr().err


def test_ground_truth_found_from_the_run_config(scene, monkeypatch, capsys):
    run, scene_dir = scene
    assert _main(["eval", str(run), "--no-plots"], monkeypatch) == 2
    assert "no --gt given" in capsys.readouterr().err
    (run / "config.yaml").write_text(f"data:\n  path: {scene_dir}\n")
    assert find_ground_truth(run) == scene_dir
    assert _main(["eval", str(run), "--no-plots"], monkeypatch) == 0
    assert json.loads((run / "metrics.json").read_text())["ground_truth"] == str(scene_dir / "gt")
    assert not (run / "iou_hovsg.png").exists()


def test_pick_frames():
    assert pick_frames(10, 3) == [0, 4, 9]
    assert pick_frames(2, 5) == [0, 1]
    assert pick_frames(0, 3) == [] and pick_frames(5, 0) == []


def test_eval_cli_on_a_generated_synthetic_scene(tmp_path, monkeypatch, capsys):
    synthetic = pytest.importorskip("ogscene3d.datasets.synthetic")
    scene_dir = synthetic.make_synthetic_scene(tmp_path / "scene", seed=1, frames=2, width=48, height=36)
    gt = load_ground_truth(scene_dir)
    assert gt.class_ids is not None and "wall" in gt.class_names and gt.relations
    run = tmp_path / "run"
    _run_from_ground_truth(gt, run)
    argv = ["eval", str(run), "--gt", str(scene_dir), "--views", "1", "--protocol", "both"]
    assert _main(argv + ["--cg-voxel-size", "0"], monkeypatch) == 0
    report = json.loads((run / "metrics.json").read_text())
    # Every Gaussian sits on its own GT point: exact under ConceptGraphs' nearest-point protocol (not
    # resampled: a voxel's mean can lie nearer another class, e.g. the wall behind a picture); the
    # HOV-SG k=5 vote blurs thin objects (doors, pictures) into the wall behind them.
    assert report["semantic_3d"]["conceptgraphs"]["miou"] == pytest.approx(1.0)
    assert 0.7 < report["semantic_3d"]["hovsg"]["miou"] < 1.0
    assert report["scene_graph"]["recall"] == pytest.approx(1.0)
    v = report["semantic_2d"]
    assert v["frames"] == [0] and v["protocol"].startswith("rendered-view-2d")
    assert "not held-out novel views" in v["protocol"]
    # Splats of a perfect labelling reproduce the GT class image up to the 2D dilation of small
    # splats (eps2d) at this tiny resolution, which fattens thin objects by about a pixel.
    assert v["overall_acc"] > 0.65
    wall = next(c for c in v["per_class"] if c["name"] == "wall")
    assert wall["iou"] > 0.7
    pic = run / v["pictures"][0]
    assert pic.is_file()
    import cv2

    assert cv2.imread(str(pic)).shape == (36 + 22, 4 * 48 + 3 * 4, 3)


def test_unobserved_gt_points_are_void_unless_asked_for(scene, monkeypatch, capsys):
    """gt/points.ply's ``observed`` flag: points no frame saw are left out by default (--gt-points all
    keeps them). Here the table is never seen and the map labels its Gaussians as chairs."""
    run, scene_dir = scene
    ply = scene_dir / "gt" / "points.ply"
    v = PlyData.read(str(ply))["vertex"].data
    arr = np.zeros(len(v), dtype=v.dtype.descr + [("observed", "u1")])
    for n in v.dtype.names:
        arr[n] = v[n]
    arr["observed"] = np.asarray(v["instance"]) != 2
    _write_ply(ply, arr)
    g = PlyData.read(str(run / "gaussians.ply"))["vertex"].data.copy()
    g["label"] = [7] * 10 + [9] * 5  # the table's Gaussians carry the chair label
    _write_ply(run / "gaussians.ply", g)
    gt = load_ground_truth(scene_dir)
    assert gt.observed.tolist() == [True] * 5 + [False] * 5 + [True] * 5
    seen = evaluate_run(run, scene_dir, protocols=["hovsg"], ignore=["wall"], mapping="overlap")
    every = evaluate_run(
        run, scene_dir, protocols=["hovsg"], ignore=["wall"], mapping="overlap", gt_points="all"
    )
    assert seen.report["gt_points"] == {"points": "observed", "num_scored": 10, "observed_fraction": 2 / 3}
    assert every.report["gt_points"]["points"] == "all"
    # observed: the chair is exact and the table is not scored; all: the unseen table counts as chair
    assert seen.semantic["hovsg"].miou == pytest.approx(1.0)
    assert every.semantic["hovsg"].miou == pytest.approx((5 / 10 + 0.0) / 2)
    with pytest.raises(ValueError, match="gt_points"):
        evaluate_run(run, scene_dir, gt_points="some")
    argv = ["eval", str(run), "--gt", str(scene_dir), "--mapping", "overlap", "--no-plots"]
    capsys.readouterr()
    assert _main(argv, monkeypatch) == 0
    out = capsys.readouterr().out
    assert "scored on the 10 labelled GT points some frame saw (67% of all" in out
    assert "label mapping: overlap (oracle: names scene labels from the GT)" in out
    assert _main(argv + ["--gt-points", "all"], monkeypatch) == 0
    assert "some frame saw" not in capsys.readouterr().out
    assert json.loads((run / "metrics.json").read_text())["gt_points"]["points"] == "all"
    # ConceptGraphs averages the classes of the scored (observed) GT points: the unseen table is out.
    cg = evaluate_run(run, scene_dir, protocols=["conceptgraphs"], ignore=[], mapping="overlap")
    assert cg.semantic["conceptgraphs"].evaluated.tolist() == [True, False, True]


def _set_gaussians(run, **fields):
    g = PlyData.read(str(run / "gaussians.ply"))["vertex"].data.copy()
    for name, values in fields.items():
        g[name] = values
    _write_ply(run / "gaussians.ply", g)


def test_unnamed_scene_labels_vote_no_class_under_hovsg(scene):
    """A labelled Gaussian whose tag names no GT class is a prediction of *no class*: under HOV-SG
    it votes so, instead of letting the chair and wall Gaussians around fill the table's space."""
    run, scene_dir = scene
    graph = json.loads((run / "graph.json").read_text())
    graph["nodes"][1]["tag"] = "lamp"  # label 8 (the table's Gaussians at x = 11..14) names no class
    (run / "graph.json").write_text(json.dumps(graph))
    res = evaluate_run(run, scene_dir, protocols=["hovsg", "conceptgraphs"], ignore=[])
    assert res.label_to_class == {7: 0, 9: 2}
    h = res.semantic["hovsg"]
    # Every table GT point's 5 nearest Gaussians are mostly label 8: no class, a miss; chair and wall
    # take no false positive from them.
    np.testing.assert_allclose(h.iou, [1.0, 0.0, 1.0])
    assert h.to_dict()["unassigned_predictions"] == 5
    c = res.semantic["conceptgraphs"]
    np.testing.assert_allclose(c.iou, [5 / 6, 0.0, 1.0])  # table: 4 unnamed misses, 1 taken as chair


def test_unlabelled_gaussians_are_misses_under_conceptgraphs_only(scene, tmp_path):
    """Unlabelled Gaussians (label -1) are kept for ConceptGraphs, which counts on predicted points,
    as predictions of no class; HOV-SG's vote leaves them out; min_opacity still filters."""
    run, scene_dir = scene
    labels = np.array([7] * 6 + [8] * 4 + [9] * 5)
    labels[1:5] = -1  # four of the chair's five Gaussians carry no label
    opacity = np.full(15, 2.0)
    opacity[4] = -5.0  # a floater, below min_opacity
    _set_gaussians(run, label=labels, opacity=opacity)
    res = evaluate_run(run, scene_dir, protocols=["hovsg", "conceptgraphs"], ignore=[], min_opacity=0.5)
    rep = res.report
    assert rep["num_gaussians_evaluated"] == 14 and rep["num_gaussians_labelled"] == 11
    assert rep["unlabelled_fraction"] == pytest.approx(3 / 14)
    # chair: TP 1 (x=0), FN 3 (unlabelled), FP 1 (the chair label at table x=10).
    c = res.semantic["conceptgraphs"]
    np.testing.assert_allclose(c.iou, [1 / 5, 4 / 5, 1.0])
    assert c.to_dict()["unassigned_predictions"] == 3
    # HOV-SG: exactly as if the unlabelled Gaussians were not in the map.
    bare = tmp_path / "bare"
    bare.mkdir()
    g = PlyData.read(str(run / "gaussians.ply"))["vertex"].data
    _write_ply(bare / "gaussians.ply", g[(labels >= 0)])
    (bare / "graph.json").write_text((run / "graph.json").read_text())
    ref = evaluate_run(bare, scene_dir, protocols=["hovsg"], ignore=[])
    np.testing.assert_array_equal(res.semantic["hovsg"].confusion, ref.semantic["hovsg"].confusion)
    _set_gaussians(run, label=np.full(15, -1))
    with pytest.raises(DataError, match="no labelled Gaussians"):
        evaluate_run(run, scene_dir, protocols=["conceptgraphs"])


def test_void_gt_points_are_hovsg_false_positives(scene):
    """A GT point of a class id absent from the table is void; HOV-SG counts the class predicted on it
    as a false positive (its ignore list holds -1 like wall), ConceptGraphs skips it."""
    run, scene_dir = scene
    ply = scene_dir / "gt" / "points.ply"
    v = PlyData.read(str(ply))["vertex"].data.copy()
    v["instance"][14] = 99  # the wall point at x = 24, beside wall Gaussians: no instance, no class
    _write_ply(ply, v)
    res = evaluate_run(run, scene_dir, protocols=["hovsg", "conceptgraphs"], ignore=[], gt_points="all")
    h = res.semantic["hovsg"]
    np.testing.assert_allclose(h.iou, [1.0, 1.0, 4 / 5])  # the k=5 vote outvotes the stray chair label
    assert res.report["semantic_3d"]["hovsg"]["void_false_positives"] == 1
    c = res.semantic["conceptgraphs"]
    assert c.iou[2] == 1.0 and c.support[2] == 4


def test_eval_cli_conceptgraphs_voxel_size(scene, monkeypatch, capsys):
    run, scene_dir = scene
    argv = [
        "eval",
        str(run),
        "--gt",
        str(scene_dir),
        "--protocol",
        "conceptgraphs",
        "--no-plots",
        "--views",
        "0",
    ]

    def counted(extra):
        assert _main(argv + extra, monkeypatch) == 0
        block = json.loads((run / "metrics.json").read_text())["semantic_3d"]["conceptgraphs"]
        return block["protocol"], sum(c["support"] for c in block["per_class"])

    # The Gaussians are 1 m apart: the default 2.5 cm voxels keep every one of them.
    proto, n = counted([])
    assert "0.025 m voxel" in proto and n == 15
    proto, n = counted(["--cg-voxel-size", "0"])
    assert "not resampled" in proto and n == 15
    # 3 m voxels merge each label's neighbours (x = 0..4 chair, 11..14 table, 20..24 wall).
    proto, n = counted(["--cg-voxel-size", "3"])
    assert "3 m voxel" in proto and n < 15
    capsys.readouterr()
    assert _main(argv + ["--cg-voxel-size", "-1"], monkeypatch) == 2
    assert "--cg-voxel-size" in capsys.readouterr().err


def test_unknown_ignore_names_are_warned_and_reported(scene, monkeypatch, capsys, caplog):
    run, scene_dir = scene
    with caplog.at_level("WARNING", logger="ogscene3d.eval.metrics"):
        res = evaluate_run(run, scene_dir, protocols=["hovsg", "conceptgraphs"], ignore=["wall", "ceilng"])
    assert "'ceilng'" in caplog.text and "chair, table, wall" in caplog.text
    assert caplog.text.count("ceilng") == 1  # once, not once per protocol
    for block in res.report["semantic_3d"].values():
        assert block["ignore_unknown"] == ["ceilng"] and block["ignored_classes"] == ["wall"]
    # The protocols' own defaults are recorded but not warned about: a scene may lack a ceiling.
    caplog.clear()
    with caplog.at_level("WARNING", logger="ogscene3d.eval.metrics"):
        res = evaluate_run(run, scene_dir, protocols=["hovsg"])
    assert not caplog.text and res.report["semantic_3d"]["hovsg"]["ignore_unknown"] == ["floor", "ceiling"]


def test_eval_of_a_missing_run_directory_says_so(monkeypatch, capsys, tmp_path):
    assert _main(["eval", str(tmp_path / "nope")], monkeypatch) == 2
    assert f"{tmp_path / 'nope'}: no such run directory" in capsys.readouterr().err


def _posed_sequence(root, frames):
    """A Replica-layout sequence (no semantic ground truth) whose camera moves along a curve."""
    import cv2

    res = root / "results"
    res.mkdir(parents=True)
    cam = {"camera": {"w": 16, "h": 12, "fx": 10.0, "fy": 10.0, "cx": 8.0, "cy": 6.0, "scale": 6553.5}}
    (root / "cam_params.json").write_text(json.dumps(cam))
    poses = []
    for i in range(frames):
        pose = np.eye(4)
        pose[:3, 3] = [0.2 * i, 0.05 * i * i, 0.1 * np.sin(i)]
        poses.append(pose)
        cv2.imwrite(str(res / f"frame{i:06d}.jpg"), np.full((12, 16, 3), 100, np.uint8))
        cv2.imwrite(str(res / f"depth{i:06d}.png"), np.full((12, 16), 13107, np.uint16))
    (root / "traj.txt").write_text("\n".join(" ".join(f"{v:.6f}" for v in p.ravel()) for p in poses) + "\n")
    return np.stack(poses)


def test_traj_against_the_dataset_folder_without_semantic_ground_truth(monkeypatch, capsys, tmp_path):
    """--traj RUN/traj.txt DATA: the dataset's poses of the frames the run read (its selection), the ATE
    alone when there is no semantic ground truth; a count that does not pair is refused."""
    from ogscene3d.config import Config, save_config

    poses = _posed_sequence(tmp_path / "seq", frames=8)
    run = tmp_path / "run"
    run.mkdir()
    cfg = Config()
    cfg.data.path = str(tmp_path / "seq")
    cfg.data.stride = 2  # frames 0, 2, 4, 6
    save_config(cfg, run / "config.yaml")
    est = poses[::2].copy()
    est[:, :3, 3] += [0.5, -0.25, 1.0]  # a rigid offset: aligned away
    est[1, 0, 3] += 0.03  # and one error
    lines = "\n".join(" ".join(f"{v:.6f}" for v in p.ravel()) for p in est) + "\n"
    (run / "traj.txt").write_text(lines)
    argv = ["eval", str(run), "--traj", str(run / "traj.txt"), str(tmp_path / "seq")]
    assert _main(argv, monkeypatch) == 0
    out = capsys.readouterr().out
    assert "ground truth: none (trajectory only)" in out and "(4 poses)" in out
    report = json.loads((run / "metrics.json").read_text())
    assert report["ground_truth"] is None
    assert 0.005 < report["trajectory"]["ate_rmse_m"] < 0.03
    # aligned without the error: zero
    (run / "traj.txt").write_text(lines.replace(f"{est[1, 0, 3]:.6f}", f"{est[1, 0, 3] - 0.03:.6f}", 1))
    assert _main(argv, monkeypatch) == 0
    assert json.loads((run / "metrics.json").read_text())["trajectory"]["ate_rmse_m"] < 1e-5
    capsys.readouterr()
    (run / "traj.txt").write_text("\n".join(lines.splitlines()[:3]) + "\n")
    assert _main(argv, monkeypatch) == 2
    assert "has 3 poses, but the run read 4 frames of" in capsys.readouterr().err
    # no --traj and no ground truth: the error it always was
    assert _main(["eval", str(run)], monkeypatch) == 2
    assert "no ground truth found" in capsys.readouterr().err


def test_traj_leaves_out_frames_whose_dataset_pose_is_invalid(monkeypatch, capsys, tmp_path):
    """A 7-Scenes-style frame with a non-finite pose (lost tracking) is left out of both trajectories."""
    import cv2

    from ogscene3d.config import Config, save_config

    seq = tmp_path / "seq"
    seq.mkdir()
    poses = []
    for i in range(5):
        pose = np.eye(4)
        pose[:3, 3] = [0.2 * i, 0.05 * i * i, 0.1 * np.sin(i)]
        poses.append(pose)
        cv2.imwrite(str(seq / f"frame-{i:06d}.color.png"), np.full((12, 16, 3), 100, np.uint8))
        cv2.imwrite(str(seq / f"frame-{i:06d}.depth.png"), np.full((12, 16), 2000, np.uint16))
        written = np.full((4, 4), -np.inf) if i == 2 else pose
        np.savetxt(seq / f"frame-{i:06d}.pose.txt", written)
    run = tmp_path / "run"
    run.mkdir()
    cfg = Config()
    cfg.data.path = str(seq)
    save_config(cfg, run / "config.yaml")
    est = np.stack(poses)
    est[2, :3, 3] += 5.0  # the frame left out: its error does not count
    (run / "traj.txt").write_text("\n".join(" ".join(f"{v:.6f}" for v in p.ravel()) for p in est) + "\n")
    assert _main(["eval", str(run), "--traj", str(run / "traj.txt"), str(seq)], monkeypatch) == 0
    assert "(4 poses; 1 frames without a valid dataset pose left out)" in capsys.readouterr().out
    t = json.loads((run / "metrics.json").read_text())["trajectory"]
    assert t["num_left_out"] == 1 and t["ate_rmse_m"] < 1e-5
