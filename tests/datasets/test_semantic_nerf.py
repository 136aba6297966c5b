"""Replica as Semantic-NeRF rendered it: Sequence_N/ with rgb/rgb_i.png, depth/depth_i.png (mm),
semantic_class/semantic_class_i.png and traj_w_c.txt; intrinsics from a 90-degree horizontal field of view;
class names from the release's semantic_info/<scene>/info_semantic.json. SNI-SLAM's 1200x680 renders: the
same frame folders with traj.txt, in the scene folder."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
from dataset_files import _png

from ogscene3d.config import DataConfig
from ogscene3d.datasets import detect_kind, open_dataset
from ogscene3d.errors import DataError
from ogscene3d.eval import load_ground_truth
from ogscene3d.eval.readers import read_class_table

W, H = 32, 24
Z = 2.0  # metres to the wall
STEP = 0.1  # camera x per frame
BOUNDARY = 0.05  # world x where the wall's class changes (no pixel ray passes through it exactly)
LEFT, RIGHT = 3, 7  # Replica class ids of the two halves
COLOURS = {LEFT: (40, 90, 200), RIGHT: (220, 200, 30)}  # BGR
INFO = {
    "classes": [{"id": 0, "name": "undefined"}, {"id": 3, "name": "chair"}, {"id": 7, "name": "table"}],
    "objects": [],
}


def _pose(i: int) -> np.ndarray:
    p = np.eye(4)
    p[0, 3] = STEP * i
    return p


def _classes(i: int, w: int = W, h: int = H) -> np.ndarray:
    """The wall's class ids as Semantic-NeRF's renderer sees them: pixel i's ray is (i - (W - 1) / 2) / fx
    (pixel centres at integers), fx = W / 2 for its 90-degree field of view."""
    fx = w / 2.0
    world_x = (np.arange(w) - (w - 1) / 2.0) / fx * Z + STEP * i
    return np.repeat(np.where(world_x < BOUNDARY, LEFT, RIGHT)[None], h, axis=0).astype(np.uint8)


def make_sequence(seq: Path, n: int = 3, w: int = W, h: int = H, labels: bool = True) -> Path:
    """A Semantic-NeRF sequence of a fronto-parallel wall at Z, the camera stepping STEP in x, whose colour
    and class maps split at world x = BOUNDARY; with a colourised class map that the reader must ignore."""
    for i in range(n):
        cls = _classes(i, w, h)
        rgb = np.zeros((h, w, 3), np.uint8)
        for c, bgr in COLOURS.items():
            rgb[cls == c] = bgr
        _png(seq / "rgb" / f"rgb_{i}.png", rgb)
        _png(seq / "depth" / f"depth_{i}.png", np.full((h, w), int(Z * 1000), np.uint16))
        if labels:
            _png(seq / "semantic_class" / f"semantic_class_{i}.png", cls)
            _png(seq / "semantic_class" / f"vis_sem_class_{i}.png", rgb)
    (seq / "traj_w_c.txt").write_text("".join(" ".join(map(str, _pose(i).ravel())) + "\n" for i in range(n)))
    return seq


def make_release(root: Path, scene: str = "room_0", n: int = 3, info: bool = True) -> Path:
    """``root/<scene>/Sequence_1`` and ``root/semantic_info/<scene>/info_semantic.json``, as released."""
    make_sequence(root / scene / "Sequence_1", n)
    if info:
        (root / "semantic_info" / scene).mkdir(parents=True)
        (root / "semantic_info" / scene / "info_semantic.json").write_text(json.dumps(INFO))
    return root / scene


# --------------------------------------------------------------------------------------- detection


def test_sequence_folder_is_detected(tmp_path):
    seq = make_sequence(tmp_path / "Sequence_1")
    assert detect_kind(seq) == ("semantic_nerf", seq)
    ds = open_dataset(seq)
    assert ds.kind == "semantic_nerf" and len(ds) == 3 and ds.root == seq


def test_scene_folder_reads_its_first_sequence_with_a_log_line(tmp_path, caplog):
    scene = tmp_path / "office_4"
    make_sequence(scene / "Sequence_10", n=2)
    make_sequence(scene / "Sequence_2", n=4)
    (scene / "Sequence_3").mkdir()  # not a sequence: left out
    assert detect_kind(scene) == ("semantic_nerf", scene)
    with caplog.at_level(logging.INFO, logger="ogscene3d.datasets.semantic_nerf"):
        ds = open_dataset(scene)
    assert ds.root == scene / "Sequence_2" and len(ds) == 4  # by number: 2 before 10
    assert "holds Sequence_2, Sequence_10: reading Sequence_2" in caplog.text
    assert open_dataset(scene / "Sequence_10").root.name == "Sequence_10"


def test_release_folder_with_one_scene_is_entered_and_with_two_is_an_error(tmp_path):
    root = tmp_path / "Replica_Dataset"
    make_release(root, "room_0")
    assert detect_kind(root) == ("semantic_nerf", root / "room_0")
    make_release(root, "office_3", info=False)
    with pytest.raises(DataError, match="several scenes .*office_3, room_0"):
        open_dataset(root)


def test_explicit_kind_and_the_layout_list_of_unknown_folders(tmp_path):
    seq = make_sequence(tmp_path / "Sequence_1")
    assert open_dataset(seq, kind="semantic_nerf").kind == "semantic_nerf"
    (tmp_path / "other" / "rgb").mkdir(parents=True)
    (tmp_path / "other" / "depth").mkdir()  # no traj_w_c.txt: not this layout
    listed = r"semantic_nerf \(rgb/rgb_N.png \+ depth/depth_N.png \+ traj_w_c.txt"
    with pytest.raises(DataError, match=listed):
        open_dataset(tmp_path / "other")


# --------------------------------------------------------------------------------------- frames


def test_frames_are_numbered_without_padding_and_posed_by_line(tmp_path):
    seq = make_sequence(tmp_path / "Sequence_1", n=12)
    ds = open_dataset(seq)
    assert [ds[i].name for i in (0, 2, 10, 11)] == ["rgb_0", "rgb_2", "rgb_10", "rgb_11"]  # not 0, 1, 10, 11
    for i in (2, 10):
        np.testing.assert_allclose(ds[i].pose, _pose(i))
    assert ds[10].timestamp == 10.0


def test_depth_is_millimetres(tmp_path):
    ds = open_dataset(make_sequence(tmp_path / "Sequence_1"))
    np.testing.assert_allclose(ds[0].depth, Z)
    assert open_dataset(tmp_path / "Sequence_1", config=DataConfig(depth_scale=500.0))[0].depth[0, 0] == 4.0


def test_intrinsics_from_a_90_degree_field_of_view(tmp_path):
    ds = open_dataset(make_sequence(tmp_path / "big", n=1, w=640, h=480, labels=False))
    # Semantic-NeRF's 320, 320, 319.5, 239.5 with pixel centres at integers = ours at +0.5
    np.testing.assert_allclose(ds.K, [[320, 0, 320], [0, 320, 240], [0, 0, 1]])
    assert (ds.camera.width, ds.camera.height) == (640, 480)
    # a convention asked for changes how given intrinsics are read, not the camera the field of view fixes
    for conv in ("integer", "half"):
        same = open_dataset(tmp_path / "big", config=DataConfig(pixel_centers=conv))
        np.testing.assert_allclose(same.K, ds.K)
    over = open_dataset(tmp_path / "big", config=DataConfig(intrinsics=[300.0, 301.0, 310.0, 230.0]))
    np.testing.assert_allclose(over.K[:2], [[300, 0, 310], [0, 301, 230]])


def test_back_projected_pixels_land_where_semantic_nerf_rays_do(tmp_path):
    """Each pixel's back-projection (our K, pose, depth) has the class the renderer gave that pixel: the
    principal point matches Semantic-NeRF's rays, not half a pixel off."""
    ds = open_dataset(make_sequence(tmp_path / "Sequence_1", n=2, w=64, h=48))
    for i in range(2):
        f = ds[i]
        pts = f.camera.backproject(f.depth).reshape(-1, 3) @ f.pose[:3, :3].T + f.pose[:3, 3]
        fx = 64 / 2.0
        expected = (np.arange(64) - 31.5) / fx * Z + STEP * i
        np.testing.assert_allclose(pts[:64, 0], expected, atol=1e-5)
        assert np.array_equal(np.where(pts[:, 0] < BOUNDARY, LEFT, RIGHT).reshape(48, 64), f.gt_classes)


# --------------------------------------------------------------------------------------- class maps


def test_class_maps_and_names_from_the_release_semantic_info(tmp_path):
    scene = make_release(tmp_path / "Replica_Dataset")
    ds = open_dataset(scene)
    assert ds.has_class_maps and ds.class_names == {3: "chair", 7: "table"}  # 0 is void
    f = ds[1]
    assert f.gt_classes.dtype == np.int32 and np.array_equal(f.gt_classes, _classes(1))
    assert f.gt_instances is None
    gt = load_ground_truth(scene)
    assert not gt.has_3d and gt.class_names == ["chair", "table"] and gt.class_ids == [3, 7]


def test_info_semantic_beside_the_sequence_is_found_and_none_leaves_names_to_classes(tmp_path):
    seq = make_sequence(tmp_path / "room_1" / "Sequence_1")
    ds = open_dataset(seq)
    assert ds.has_class_maps and ds.class_names is None
    with pytest.raises(DataError, match="carry class ids but no class names: pass --classes"):
        load_ground_truth(seq)
    (seq.parent / "info_semantic.json").write_text(json.dumps(INFO))  # in the scene folder
    assert open_dataset(seq).class_names == {3: "chair", 7: "table"}


def test_classes_option_takes_replica_info_semantic_json(tmp_path):
    path = tmp_path / "info_semantic.json"
    path.write_text(json.dumps(INFO))
    assert read_class_table(path) == {0: "undefined", 3: "chair", 7: "table"}
    # given for a Semantic-NeRF sequence, id 0 stays void there, as with the release's own table
    gt = load_ground_truth(make_sequence(tmp_path / "Sequence_1"), classes=path)
    assert gt.class_names == ["chair", "table"] and gt.class_ids == [3, 7]
    path.write_text(json.dumps({"classes": [{"id": 3}]}))
    with pytest.raises(DataError, match="needs an integer 'id' and a 'name'"):
        read_class_table(path)


def test_sequence_without_class_maps(tmp_path):
    ds = open_dataset(make_sequence(tmp_path / "Sequence_1", labels=False))
    assert not ds.has_class_maps and ds.class_names is None and ds[0].gt_classes is None


def test_a_frame_without_its_class_map_has_none(tmp_path):
    seq = make_sequence(tmp_path / "Sequence_1")
    (seq / "semantic_class" / "semantic_class_1.png").unlink()
    ds = open_dataset(seq)
    assert ds.has_class_maps and ds[1].gt_classes is None and ds[2].gt_classes is not None


# --------------------------------------------------------------------------------------- errors


def test_too_few_poses_name_the_trajectory(tmp_path):
    seq = make_sequence(tmp_path / "Sequence_1")
    lines = (seq / "traj_w_c.txt").read_text().splitlines()
    (seq / "traj_w_c.txt").write_text("\n".join(lines[:2]) + "\n")
    with pytest.raises(DataError, match=r"rgb/rgb_2.png: no pose: traj_w_c.txt has poses for frames 0 to 1"):
        open_dataset(seq)
    # or that frame left out, named in a warning
    assert len(open_dataset(seq, config=DataConfig(on_bad_frame="skip"))) == 2


def test_malformed_pose_line_names_file_and_line(tmp_path):
    seq = make_sequence(tmp_path / "Sequence_1")
    lines = (seq / "traj_w_c.txt").read_text().splitlines()
    lines[1] = " ".join(lines[1].split()[:15])
    (seq / "traj_w_c.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"traj_w_c.txt:2: expected 16 numbers"):
        open_dataset(seq)
    # under skip only that frame is left out (the whole sequence used to be refused)
    skip = open_dataset(seq, config=DataConfig(on_bad_frame="skip"))
    assert [f.name for f in skip] == ["rgb_0", "rgb_2"]


def test_missing_depth_is_reported_at_open(tmp_path):
    seq = make_sequence(tmp_path / "Sequence_1")
    (seq / "depth" / "depth_1.png").unlink()
    with pytest.raises(DataError, match=r"1 of the 3 selected frames lack files .*depth/depth_1.png"):
        open_dataset(seq)
    assert len(open_dataset(seq, config=DataConfig(on_bad_frame="skip"))) == 2


def test_no_rgb_images_and_duplicate_numbers_are_errors(tmp_path):
    seq = make_sequence(tmp_path / "Sequence_1")
    (seq / "rgb" / "rgb_1.png").rename(seq / "rgb" / "rgb_01.png")
    _png(seq / "rgb" / "rgb_1.png", np.zeros((H, W, 3), np.uint8))
    with pytest.raises(DataError, match="rgb_01.png and rgb_1.png are both frame 1"):
        open_dataset(seq)
    for p in (seq / "rgb").iterdir():
        p.unlink()
    with pytest.raises(DataError, match=r"rgb: no rgb_<i>.png images"):
        open_dataset(seq)


def test_class_map_of_another_size_is_an_error_naming_it(tmp_path):
    seq = make_sequence(tmp_path / "Sequence_1")
    _png(seq / "semantic_class" / "semantic_class_0.png", np.zeros((H // 2, W // 2), np.uint8))
    with pytest.raises(DataError, match=r"semantic_class_0.png: Semantic-NeRF class is 16x12"):
        open_dataset(seq)[0]


# --------------------------------------------------------------------------------------- SNI-SLAM's renders


def _turned_pose(i: int) -> np.ndarray:
    """_pose(i) turned about the camera's y axis: a pose read transposed or with SNI-SLAM's y/z column flip
    (its own OpenGL convention, not the file's) would differ."""
    a = 0.1 * (i + 1)
    p = _pose(i)
    p[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    p[:3, 3] += [0.25, -0.5, 1.5]
    return p


def make_sni_scene(scene: Path, n: int = 3, w: int = W, h: int = H, turned: bool = False) -> Path:
    """SNI-SLAM's ``data/replica/<scene>``: the Semantic-NeRF frame folders with NICE-SLAM's ``traj.txt``
    (no traj_w_c.txt), in the scene folder itself."""
    make_sequence(scene, n, w, h)
    (scene / "traj_w_c.txt").unlink()
    pose = _turned_pose if turned else _pose
    (scene / "traj.txt").write_text(
        "".join(" ".join(repr(float(x)) for x in pose(i).ravel()) + "\n" for i in range(n))
    )
    return scene


def test_sni_slam_scene_with_traj_txt_is_detected_and_posed_by_line(tmp_path):
    root = tmp_path / "data" / "replica"
    scene = make_sni_scene(root / "room_0", n=12, turned=True)
    assert detect_kind(scene) == ("semantic_nerf", scene)
    assert detect_kind(root) == ("semantic_nerf", scene)  # the data folder holding one scene is entered
    ds = open_dataset(root)
    assert ds.kind == "semantic_nerf" and ds.root == scene and len(ds) == 12
    assert [ds[i].name for i in (0, 2, 10)] == ["rgb_0", "rgb_2", "rgb_10"]
    for i in (0, 2, 10, 11):
        np.testing.assert_allclose(ds[i].pose, _turned_pose(i), atol=1e-12)
    np.testing.assert_allclose(ds[1].depth, Z)  # millimetres, not NICE-SLAM's 6553.5 per metre
    assert ds.has_class_maps and np.array_equal(ds[1].gt_classes, _classes(1))


def test_sni_slam_1200x680_intrinsics_cast_its_loaders_rays(tmp_path):
    """SNI-SLAM's replica.yaml: 1200x680, fx = fy = 600, cx = 599.5, cy = 339.5 with pixel centres at
    integers; our K (centres at +0.5) must back-project every pixel along the same ray."""
    ds = open_dataset(make_sni_scene(tmp_path / "room_0", n=1, w=1200, h=680))
    np.testing.assert_allclose(ds.K, [[600, 0, 600], [0, 600, 340], [0, 0, 1]])
    assert (ds.camera.width, ds.camera.height) == (1200, 680)
    pts = ds.camera.backproject(ds[0].depth)
    for v, u in ((0, 0), (679, 1199), (339, 600), (17, 911)):
        sni_ray = np.array([(u - 599.5) / 600.0, (v - 339.5) / 600.0, 1.0])
        np.testing.assert_allclose(pts[v, u], sni_ray * Z, atol=1e-5)


def test_sni_slam_back_projected_pixels_land_on_their_classes(tmp_path):
    ds = open_dataset(make_sni_scene(tmp_path / "room_0", n=2, w=64, h=48))
    for i in range(2):
        f = ds[i]
        pts = f.camera.backproject(f.depth).reshape(-1, 3) @ f.pose[:3, :3].T + f.pose[:3, 3]
        assert np.array_equal(np.where(pts[:, 0] < BOUNDARY, LEFT, RIGHT).reshape(48, 64), f.gt_classes)


def test_traj_txt_alone_is_no_sign_of_the_layout(tmp_path):
    """Only rgb/rgb_<i>.png frames make a folder with traj.txt this layout; NICE-SLAM's stays replica."""
    other = tmp_path / "other"
    _png(other / "rgb" / "000000.png", np.zeros((H, W, 3), np.uint8))
    _png(other / "depth" / "000000.png", np.zeros((H, W), np.uint16))
    (other / "traj.txt").write_text(" ".join(map(str, np.eye(4).ravel())) + "\n")
    with pytest.raises(DataError, match=r"other: no known dataset layout.*or SNI-SLAM's traj.txt"):
        open_dataset(other)
    nice = make_sni_scene(tmp_path / "room0", n=1)
    _png(nice / "results" / "frame000000.jpg", np.zeros((H, W, 3), np.uint8))
    assert detect_kind(nice) == ("replica", nice)


def test_traj_w_c_is_read_where_both_pose_files_are(tmp_path):
    scene = make_sni_scene(tmp_path / "room_0", n=3, turned=True)
    (scene / "traj_w_c.txt").write_text(
        "".join(" ".join(map(str, _pose(i).ravel())) + "\n" for i in range(3))
    )
    np.testing.assert_allclose(open_dataset(scene)[2].pose, _pose(2))


def test_sni_slam_scene_class_names_and_pose_errors_name_traj_txt(tmp_path):
    scene = make_sni_scene(tmp_path / "room_0", n=3)
    assert open_dataset(scene).class_names is None
    (scene / "habitat").mkdir()
    (scene / "habitat" / "info_semantic.json").write_text(json.dumps(INFO))  # as in Replica's scene folder
    ds = open_dataset(scene)
    assert ds.class_info == scene / "habitat" / "info_semantic.json"
    assert ds.class_names == {3: "chair", 7: "table"}
    lines = (scene / "traj.txt").read_text().splitlines()
    (scene / "traj.txt").write_text("\n".join(lines[:2]) + "\n")
    with pytest.raises(DataError, match=r"room_0: 1 of the 3 .* rgb/rgb_2.png: no pose: traj.txt has"):
        open_dataset(scene)


# --------------------------------------------------------------------------------------- end to end


def test_run_then_2d_only_eval(tmp_path, monkeypatch):
    """``ogscene3d run --data <scene>`` maps the sequence, then ``eval --views 2`` finds its class maps
    through the run's data.path and scores the rendered views against them, in 2D only."""
    from ogscene3d import cli

    scene = make_release(tmp_path / "Replica_Dataset", n=4)
    run = tmp_path / "run"
    config = Path(__file__).resolve().parents[2] / "configs" / "replica_semantic_nerf.yaml"
    argv = ["run", "--config", str(config), "--data", str(scene), "--out", str(run)]
    argv += ["--device", "cpu", "--no-progress", "--set", "segmentation.backend=classical"]
    argv += ["--set", "mapping.keyframe_every=1", "--set", "mapping.init.pixels_per_gaussian=4"]
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["ogscene3d.commands.run", "ogscene3d.commands.eval"])
    assert cli.main(argv) == 0
    assert cli.main(["eval", str(run), "--views", "2", "--no-plots"]) == 0
    report = json.loads((run / "metrics.json").read_text())
    assert report["ground_truth"].startswith(str(scene)) and not report["has_3d_ground_truth"]
    v = report["semantic_2d"]
    assert v["dataset_kind"] == "semantic_nerf" and v["frames"] == [0, 3]
    assert v["frame_names"] == ["rgb_0", "rgb_3"]
    assert {c["name"] for c in v["per_class"]} == {"chair", "table"}
    assert v["miou"] > 0.8  # the two colours segment the wall where its classes split


def test_eval_reads_a_run_recorded_as_its_scene_folder_from_either_path(tmp_path):
    """``run --data room_0`` records the scene folder but maps room_0/Sequence_1: eval given either path
    renders with the run's camera and knows which scored frames the run mapped."""
    from ogscene3d.datasets.base import K_from_values
    from ogscene3d.eval.views import _scored_mapped, open_view_dataset

    scene = make_release(tmp_path / "Replica_Dataset", n=4)
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text(f"data:\n  path: {scene}\n  stride: 2\n  intrinsics: [10, 10, 16, 12]\n")
    for folder in (scene, scene / "Sequence_1"):
        ds = open_view_dataset(folder, run)
        assert ds.root == scene / "Sequence_1" and len(ds) == 4  # every frame, not the run's selection
        np.testing.assert_allclose(ds.K, K_from_values(10, 10, 16, 12))
        assert _scored_mapped(run, ds, [0, 1, 2, 3]) == [0, 2]
