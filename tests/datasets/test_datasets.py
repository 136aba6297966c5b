"""Dataset readers: real samples (depth scale + pose convention by reprojection), every layout on tiny
fabricated sequences, configuration overrides, and every bad-input case."""

from __future__ import annotations

import json
import logging

import cv2
import numpy as np
import pytest
from dataset_files import _png, _pose, _rgb, make_replica, reprojection_error

from ogscene3d.config import DataConfig
from ogscene3d.datasets import detect_kind, open_dataset
from ogscene3d.errors import DataError
from ogscene3d.segmentation.precomputed import write_segments

# --------------------------------------------------------------------------------------- helpers


# --------------------------------------------------------------------------------------- real samples


def test_replica_sample_scale_and_poses(shared_data):
    root = shared_data / "replica_room0_nice_slam"
    kind, scene = detect_kind(root)  # the parent folder holds one scene: it is entered
    assert kind == "replica" and scene.name == "room0"
    ds = open_dataset(root, max_frames=20)
    assert len(ds) == 20
    f0, f19 = ds[0], ds[19]
    assert f0.name == "frame000000" and f0.rgb.shape == (680, 1200, 3)
    # as cam_params.json says: the renders agree with it read with pixel centres at +0.5
    np.testing.assert_allclose(f0.K, [[600, 0, 599.5], [0, 600, 339.5], [0, 0, 1]])
    assert 0.5 < np.median(f0.depth[f0.depth > 0]) < 6.0  # metres: the 6553.5 scale is applied
    med, frac, n = reprojection_error(f0, f19)
    assert n > 1000 and med < 0.02 and frac > 0.8
    # A wrong depth scale breaks the reprojection: the check can fail.
    bad = open_dataset(root, config=DataConfig(depth_scale=1000.0))
    med_bad, _, _ = reprojection_error(bad[0], bad[19])
    assert med_bad > 0.1


def test_sevenscenes_sample_scale_and_poses(shared_data):
    ds = open_dataset(shared_data / "7scenes_redkitchen_stride20")
    assert ds.kind == "sevenscenes" and len(ds) == 50
    f0, f1 = ds[0], ds[1]
    np.testing.assert_allclose(f0.K, [[585, 0, 320.5], [0, 585, 240.5], [0, 0, 1]])
    assert f0.depth.max() < 10.0
    med, frac, n = reprojection_error(f0, f1)
    assert n > 1000 and med < 0.03 and frac > 0.8


def test_labelfusion_sample_shift3_depth_and_labels(shared_data):
    ds = open_dataset(shared_data / "labelfusion_shelf_labels")
    assert ds.kind == "labelfusion" and ds.depth_format == "shift3" and len(ds) == 15
    f0, f5 = ds[0], ds[5]
    assert abs(float(f0.K[0, 0]) - 611.69) < 0.1
    valid = f0.depth[f0.depth > 0]
    assert valid.min() >= 0.3 and np.median(valid) < 2.0  # a shelf bin under a metre or so away
    assert set(np.unique(f0.gt_classes)) <= {0, 8, 22} and f0.gt_instances is None
    med, frac, n = reprojection_error(f0, f5)
    assert n > 200 and med < 0.03 and frac > 0.7
    # Reading the same files as linear millimetres gives depths 8x too large.
    lin = open_dataset(shared_data / "labelfusion_shelf_labels", config=DataConfig(depth_format="linear"))
    assert np.median(lin[0].depth[lin[0].depth > 0]) > 3.0 * np.median(valid)


# --------------------------------------------------------------------------------------- layouts


def test_replica_fabricated_and_frame_selection(tmp_path):
    scene = make_replica(tmp_path, n=6, cam_in_parent=True)
    ds = open_dataset(scene)
    assert ds.kind == "replica" and len(ds) == 6
    f = ds[-1]
    assert f.index == 5 and f.name == "frame000005"
    assert f.depth.dtype == np.float32 and np.allclose(f.depth, 2.0, atol=1e-3)
    assert np.allclose(f.pose[0, 3], 0.5)
    assert [fr.name for fr in open_dataset(scene, stride=2)] == ["frame000000", "frame000002", "frame000004"]
    assert len(open_dataset(scene, max_frames=2)) == 2
    sel = open_dataset(scene, config=DataConfig(start=1, stride=2, max_frames=2))
    assert [fr.name for fr in sel] == ["frame000001", "frame000003"]
    # explicit arguments win over the config
    assert len(open_dataset(scene, stride=1, config=DataConfig(stride=3))) == 6
    med, frac, _ = reprojection_error(ds[0], ds[1], step=1)
    assert med < 1e-3 and frac == 1.0


def test_config_overrides(tmp_path):
    scene = make_replica(tmp_path)
    d = open_dataset(scene, config=DataConfig(depth_scale=6553.5 / 2))[0].depth
    assert np.allclose(d, 4.0, atol=1e-3)
    f = open_dataset(scene, config=DataConfig(intrinsics=[30.0, 31.0, 15.0, 11.0]))[0]
    np.testing.assert_allclose(f.K, [[30, 0, 15], [0, 31, 11], [0, 0, 1]])  # as Replica's files are read
    given = DataConfig(intrinsics=[30.0, 31.0, 15.0, 11.0], pixel_centers="integer")  # an OpenCV calibration
    np.testing.assert_allclose(
        open_dataset(scene, config=given)[0].K, [[30, 0, 15.5], [0, 31, 11.5], [0, 0, 1]]
    )
    with pytest.raises(DataError, match="data.pixel_centers must be 'auto' or one of"):
        open_dataset(scene, config=DataConfig(pixel_centers="centre"))
    assert not open_dataset(scene, config=DataConfig(max_depth=1.5))[0].depth.any()
    assert not open_dataset(scene, config=DataConfig(min_depth=2.5))[0].depth.any()
    assert open_dataset(scene, config=DataConfig(path=str(scene)), kind="auto").root == scene


def test_data_scale_resizes_every_image_and_the_intrinsics(tmp_path):
    """data.scale: colour by area, depth and ids by the nearest pixel, K scaled (exact with centres at +0.5);
    segments at the folder's size are resized, those made at the scaled size read as they are."""
    scene = make_replica(tmp_path, n=2, w=32, h=24)
    ids = np.zeros((24, 32), np.int32)
    ids[:, 16:] = 7
    write_segments(tmp_path / "segs", "frame000000", ids, {7: 0.9})
    write_segments(tmp_path / "segs", "frame000001", ids[::2, ::2], {7: 0.8})  # segmented at the scale
    ds = open_dataset(scene, segments_dir=tmp_path / "segs", config=DataConfig(scale=0.5))
    np.testing.assert_allclose(ds.K, [[10, 0, 8], [0, 10, 6], [0, 0, 1]])
    assert (ds.camera.width, ds.camera.height) == (16, 12)
    full = open_dataset(scene)[0]
    for i, f in enumerate(ds):
        assert f.rgb.shape == (12, 16, 3) and f.depth.shape == (12, 16) and np.allclose(f.depth, 2.0)
        assert f.segments.shape == (12, 16) and (f.segments[:, 8:] == 7).all() and not f.segments[:, :8].any()
        assert f.segment_scores == {7: 0.9 if i == 0 else 0.8}
    np.testing.assert_allclose(ds[0].rgb, cv2.resize(full.rgb, (16, 12), interpolation=cv2.INTER_AREA))
    # the same rays: a pixel centre maps to the same ray through the scaled K
    assert ds.K[0, 2] / ds.K[0, 0] == pytest.approx(full.K[0, 2] / full.K[0, 0])
    with pytest.raises(DataError, match=r"data.scale must be in \(0, 1\]"):
        open_dataset(scene, config=DataConfig(scale=2.0))


def test_scannet_layout_resizes_colour_to_depth(tmp_path):
    root = tmp_path / "scene0000_00"
    for i in range(2):
        _png(root / "color" / f"{i}.jpg", _rgb(48, 64, i))
        _png(root / "depth" / f"{i}.png", np.full((24, 32), 1500, np.uint16))
        (root / "pose").mkdir(exist_ok=True)
        np.savetxt(root / "pose" / f"{i}.txt", _pose(i * 0.2))
    (root / "intrinsic").mkdir()
    K4 = np.eye(4)
    K4[:3, :3] = [[100.0, 0, 31.5], [0, 100, 23.5], [0, 0, 1]]  # the image centre, pixel centres from 0
    np.savetxt(root / "intrinsic" / "intrinsic_color.txt", K4)
    ds = open_dataset(root)
    assert ds.kind == "scannet"
    f = ds[1]
    assert f.rgb.shape == (24, 32, 3) and np.allclose(f.depth, 1.5)
    # colour K rescaled to depth: the principal point stays at the image centre
    np.testing.assert_allclose(f.K, [[50, 0, 16], [0, 50, 12], [0, 0, 1]])
    assert f.pose[0, 3] == pytest.approx(0.2)
    # the same camera written with pixel centres from 0.5: the centre is then (32, 24), and scales as it is
    K4[:2, 2] = [32, 24]
    np.savetxt(root / "intrinsic" / "intrinsic_color.txt", K4)
    K = open_dataset(root, config=DataConfig(pixel_centers="half")).K
    np.testing.assert_allclose(K, [[50, 0, 16], [0, 50, 12], [0, 0, 1]])
    # ScanNet marks lost tracking with -inf poses: an error naming the pose file, or a skipped frame
    np.savetxt(root / "pose" / "1.txt", np.full((4, 4), -np.inf))
    with pytest.raises(DataError, match=r"1\.txt.*NaN or inf"):
        open_dataset(root)[1]
    assert len(list(open_dataset(root, config=DataConfig(on_bad_frame="skip")))) == 1


def test_tum_layout_association_and_quaternions(tmp_path):
    root = tmp_path / "rgbd_dataset_freiburg1_desk"
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_lines, depth_lines = ["# color images"], ["# depth maps"]
    for i in range(3):
        t = 100.0 + i * 0.1
        _png(root / "rgb" / f"{t:.6f}.png", _rgb(24, 32, i))
        _png(root / "depth" / f"{t + 0.005:.6f}.png", np.full((24, 32), 5000 * (i + 1), np.uint16))
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth_lines.append(f"{t + 0.005:.6f} depth/{t + 0.005:.6f}.png")
    rgb_lines.append("100.500000 rgb/100.500000.png")  # no depth within 20 ms: not a frame
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    s = np.sqrt(0.5)  # 90 degrees about z
    gt = ["# timestamp tx ty tz qx qy qz qw"] + [
        f"{100.0 + i * 0.1 + 0.002:.6f} {i} 2 3 0 0 {s} {s}" for i in range(3)
    ]
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    ds = open_dataset(root)
    assert ds.kind == "tum" and len(ds) == 3
    np.testing.assert_allclose(ds.K[0, 0], 517.3)  # freiburg1 calibration from the folder name
    f = ds[2]
    assert np.allclose(f.depth, 3.0)  # 5000 units per metre
    np.testing.assert_allclose(f.pose[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-9)
    np.testing.assert_allclose(f.pose[:3, 3], [2, 2, 3])
    assert f.timestamp == pytest.approx(100.2)
    # a non-unit quaternion is a bad pose at that frame
    gt[2] = "100.102000 1 2 3 0 0 0.9 0.9"
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    with pytest.raises(DataError, match="groundtruth.txt.*non-rigid"):
        open_dataset(root)[1]


def test_sevenscenes_invalid_depth_and_sequences(tmp_path):
    root = tmp_path / "chess"
    for s in (1, 2):
        for i in range(2):
            d = np.full((24, 32), 1200, np.uint16)
            d[0, 0] = 65535
            _png(root / f"seq-0{s}" / f"frame-{i:06d}.color.png", _rgb(24, 32, i))
            _png(root / f"seq-0{s}" / f"frame-{i:06d}.depth.png", d)
            np.savetxt(root / f"seq-0{s}" / f"frame-{i:06d}.pose.txt", _pose(i))
    ds = open_dataset(root)
    assert ds.kind == "sevenscenes" and len(ds) == 4
    f = ds[0]
    assert f.depth[0, 0] == 0.0 and np.allclose(f.depth[1:], 1.2)
    assert f.name == "frame-000000.color"
    np.testing.assert_allclose(f.K[0, 0], 585.0)
    # a missing pose file is found when the dataset is opened, not when its frame is reached
    (root / "seq-02" / "frame-000001.pose.txt").unlink()
    with pytest.raises(
        DataError, match=r"1 of the 4 selected .*sevenscenes layout.*seq-02/frame-000001\.pose\.txt"
    ):
        open_dataset(root)
    assert len(list(open_dataset(root, config=DataConfig(on_bad_frame="skip")))) == 3


def test_segments_dir_is_read_and_checked(tmp_path):
    scene = make_replica(tmp_path)
    seg = tmp_path / "seg"
    ids = np.zeros((24, 32), np.int32)
    ids[:, 16:] = 7
    for i in range(3):
        write_segments(seg, f"frame{i:06d}", ids, {7: 0.93}, names={7: "chair"} if i == 1 else None)
    f = open_dataset(scene, segments_dir=seg)[1]
    assert np.array_equal(f.segments, ids) and f.segment_scores == {7: pytest.approx(0.93)}
    assert f.segment_names == {7: "chair"}  # a detector's class, as `segment --backend sam+detector` wrote
    assert open_dataset(scene, segments_dir=seg)[0].segment_names == {}
    write_segments(seg, "frame000002", np.zeros((12, 16), np.int32))
    with pytest.raises(DataError, match=r"frame000002\.png.*16x12"):
        open_dataset(scene, segments_dir=seg)[2]
    (seg / "frame000002.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    with pytest.raises(DataError, match=r"frame000002\.png: cannot decode segments PNG"):
        open_dataset(scene, segments_dir=seg)[2]
    with pytest.raises(DataError, match="segments folder does not exist"):
        open_dataset(scene, segments_dir=tmp_path / "nope")


# --------------------------------------------------------------------------------------- bad input


def _rm(name):
    return lambda s: (s / "results" / name).unlink()


def _write(name, data):
    return lambda s: (s / "results" / name).write_bytes(data)


def _cut(name, keep):
    return lambda s: (s / "results" / name).write_bytes((s / "results" / name).read_bytes()[keep])


def _img(name, img):
    return lambda s: _png(s / "results" / name, img)


@pytest.mark.parametrize(
    "damage, match",
    [
        (_write("depth000001.png", b"not a png"), r"results/depth000001\.png: depth file is not a PNG image"),
        (_write("frame000001.jpg", b""), r"results/frame000001\.jpg: rgb file is empty"),
        (_cut("depth000001.png", slice(0, 60)), r"depth000001\.png: depth PNG is truncated \(no IEND"),
        (_cut("depth000001.png", slice(0, 20)), r"depth000001\.png: depth PNG is truncated \(no IHDR"),
        (_cut("frame000001.jpg", slice(0, -300)), r"frame000001\.jpg: rgb JPEG is truncated"),
        (_cut("frame000001.jpg", slice(0, 40)), r"frame000001\.jpg: rgb JPEG is truncated"),
        (
            _img("depth000001.png", np.zeros((12, 16), np.uint16)),
            r"depth000001\.png: depth is 16x12, the other frames' 32x24, "
            r"results/frame000001\.jpg: rgb is 32x24, its depth image 16x12",
        ),
        (
            _img("depth000001.png", np.zeros((24, 32), np.uint8)),
            r"depth000001\.png: depth image must be 16-bit, got 8-bit",
        ),
        (_img("depth000001.png", np.zeros((24, 32, 3), np.uint16)), r"must be single-channel, got 3"),
        (
            _write("frame000001.jpg", cv2.imencode(".png", _rgb(24, 32))[1].tobytes()),
            r"frame000001\.jpg: rgb file is not a JPEG image",
        ),
    ],
)
def test_broken_files_are_found_when_the_dataset_opens(tmp_path, caplog, damage, match):
    """Each file's first and last bytes are read when the dataset opens: a broken folder fails at once, naming
    the file and what is wrong, or under data.on_bad_frame: skip leaves that frame out with a warning."""
    scene = make_replica(tmp_path)
    damage(scene)
    head = r"1 of the 3 selected frames cannot be mapped \(replica layout\); .*"
    with pytest.raises(DataError, match=head + match):
        open_dataset(scene)
    with caplog.at_level(logging.WARNING, logger="ogscene3d.datasets.base"):
        skip = open_dataset(scene, config=DataConfig(on_bad_frame="skip"))
    assert [f.name for f in skip] == ["frame000000", "frame000002"] and skip.frames_left_out == 1
    (warning,) = [r.getMessage() for r in caplog.records]
    assert "000001." in warning and "leaving those frames out" in warning


def _corrupt_middle(name):
    """Garble a file's middle: its header and end marker stay, its pixels no longer decode."""

    def damage(s):
        path = s / "results" / name
        data = bytearray(path.read_bytes())
        mid = len(data) // 2
        data[mid - 8 : mid + 8] = b"\x00" * 16
        path.write_bytes(bytes(data))

    return damage


def test_what_only_decoding_finds_fails_that_frame_naming_the_file(tmp_path, caplog):
    """Pixels garbled between a sound header and end marker: found when the frame is read, naming the file."""
    scene = make_replica(tmp_path)
    _corrupt_middle("depth000001.png")(scene)
    match = r"depth000001\.png: cannot decode depth image"
    ds = open_dataset(scene)
    ds[0]
    with pytest.raises(DataError, match=match):
        ds[1]
    with pytest.raises(DataError, match=match):
        list(ds)
    skip = open_dataset(scene, config=DataConfig(on_bad_frame="skip"))
    with caplog.at_level(logging.WARNING, logger="ogscene3d.datasets.base"):
        names = [f.name for f in skip]
    assert names == ["frame000000", "frame000002"]
    assert any("frame000001" in r.getMessage() for r in caplog.records)


def test_missing_colour_file_is_named_or_skipped(tmp_path, caplog):
    """A frame whose colour image is missing (its depth image is there) is an error naming the file, or a
    logged skip under data.on_bad_frame: skip; it used to vanish from the sequence without a word."""
    scene = make_replica(tmp_path)
    (scene / "results" / "frame000001.jpg").unlink()
    with pytest.raises(DataError, match=r"1 of the 3 selected frames.*results/frame000001\.jpg.*bad_frame"):
        open_dataset(scene)
    with caplog.at_level(logging.WARNING, logger="ogscene3d.datasets.base"):
        skip = open_dataset(scene, config=DataConfig(on_bad_frame="skip"))
    assert [f.name for f in skip] == ["frame000000", "frame000002"] and skip.frames_left_out == 1
    assert any("frame000001.jpg" in r.getMessage() for r in caplog.records)


def test_sevenscenes_missing_colour_file_is_named(tmp_path):
    root = tmp_path / "chess"
    for i in range(3):
        _png(root / f"frame-{i:06d}.color.png", _rgb(24, 32, i))
        _png(root / f"frame-{i:06d}.depth.png", np.full((24, 32), 1200, np.uint16))
        np.savetxt(root / f"frame-{i:06d}.pose.txt", _pose(i))
    (root / "frame-000001.color.png").unlink()
    with pytest.raises(DataError, match=r"frame-000001\.color\.png"):
        open_dataset(root)
    assert len(list(open_dataset(root, config=DataConfig(on_bad_frame="skip")))) == 2


@pytest.mark.parametrize(
    "row, match", [("1 0 0 x " * 4, "non-numeric pose"), ("1 0 0 0", "expected 16 numbers .* found 4")]
)
def test_bad_traj_line_fails_or_skips_that_frame(tmp_path, caplog, row, match):
    """A line of traj.txt that holds no pose: a clear error naming the file and line, or under
    data.on_bad_frame: skip that frame left out with a logged warning (the whole run used to stop)."""
    scene = make_replica(tmp_path)
    lines = (scene / "traj.txt").read_text().splitlines()
    lines[1] = row
    (scene / "traj.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=rf"traj\.txt:2: {match}.*on_bad_frame: skip"):
        open_dataset(scene)
    skip = open_dataset(scene, config=DataConfig(on_bad_frame="skip"))
    with pytest.raises(DataError, match=rf"traj\.txt:2: {match}"):
        skip[1]
    with caplog.at_level(logging.WARNING, logger="ogscene3d.datasets.base"):
        names = [f.name for f in skip]
    assert names == ["frame000000", "frame000002"]
    assert any("traj.txt:2" in r.getMessage() and "frame000001" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("key, value", [("w", 64), ("h", 48)])
def test_cam_params_size_is_checked_against_the_images(tmp_path, key, value):
    scene = make_replica(tmp_path)
    cam = json.loads((scene / "cam_params.json").read_text())
    cam["camera"][key] = value
    (scene / "cam_params.json").write_text(json.dumps(cam))
    w, h = (value, 24) if key == "w" else (32, value)
    with pytest.raises(DataError, match=rf"cam_params\.json: the camera is {w}x{h} .*images are 32x24"):
        open_dataset(scene)
    # data.intrinsics replaces the file's camera: its size is not used
    assert len(open_dataset(scene, config=DataConfig(intrinsics=[20.0, 20.0, 16.0, 12.0]))) == 3


@pytest.mark.parametrize("depth_scale, warned", [(6553.5, False), (6.5535, True), (6553500.0, True)])
def test_implausible_depth_warns_once(tmp_path, caplog, depth_scale, warned):
    """A wrong depth scale (the wall at 2 km or 2 mm): one warning naming the setting, at the first frame."""
    scene = make_replica(tmp_path)
    ds = open_dataset(scene, config=DataConfig(depth_scale=depth_scale))
    with caplog.at_level(logging.WARNING, logger="ogscene3d.datasets.base"):
        frames = list(ds)
    assert len(frames) == 3
    messages = [r.getMessage() for r in caplog.records if "implausible" in r.getMessage()]
    assert len(messages) == int(warned)
    if warned:
        assert "depth000000.png" in messages[0] and "data.depth_scale" in messages[0]


@pytest.mark.parametrize(
    "row, match",
    [
        ("nan " * 16, "NaN or inf"),
        ("2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", "non-rigid"),
        ("1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1", r"last row"),
    ],
)
def test_bad_poses(tmp_path, row, match):
    scene = make_replica(tmp_path)
    lines = (scene / "traj.txt").read_text().splitlines()
    lines[1] = row
    (scene / "traj.txt").write_text("\n".join(lines) + "\n")
    ds = open_dataset(scene)
    with pytest.raises(DataError, match=rf"traj\.txt:2.*{match}"):
        ds[1]
    assert [f.name for f in open_dataset(scene, config=DataConfig(on_bad_frame="skip"))] == [
        "frame000000",
        "frame000002",
    ]


def test_bad_layouts_and_metadata(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        open_dataset(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="folder is empty"):
        open_dataset(tmp_path / "empty")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("hello")
    with pytest.raises(DataError, match="no known dataset layout"):
        open_dataset(tmp_path / "other")
    with pytest.raises(DataError, match="unknown dataset kind"):
        open_dataset(tmp_path / "other", kind="kitti")
    scene = make_replica(tmp_path / "r")
    with pytest.raises(DataError, match="does not look like a tum dataset"):
        open_dataset(scene, kind="tum")
    # traj.txt shorter than the frames
    (scene / "traj.txt").write_text((scene / "traj.txt").read_text().splitlines()[0] + "\n")
    with pytest.raises(DataError, match=r"frame000001\.jpg: no pose: traj\.txt has poses for frames 0 to 0"):
        open_dataset(scene)
    (scene / "traj.txt").write_text("1 2 3\n")
    with pytest.raises(DataError, match=r"traj\.txt:1: expected 16 numbers"):
        open_dataset(scene)
    scene2 = make_replica(tmp_path / "r2")
    (scene2 / "cam_params.json").write_text("{not json")
    with pytest.raises(DataError, match="cam_params.json: malformed camera parameters"):
        open_dataset(scene2)
    (scene2 / "cam_params.json").unlink()
    with pytest.raises(DataError, match="cam_params.json not found"):
        open_dataset(scene2)
    assert open_dataset(scene2, config=DataConfig(intrinsics=[20.0, 20.0, 16.0, 12.0]))[0].K[0, 0] == 20.0
    with pytest.raises(DataError, match="selects none"):
        open_dataset(scene2, config=DataConfig(start=10, intrinsics=[20.0, 20.0, 16.0, 12.0]))
    with pytest.raises(DataError, match="on_bad_frame"):
        open_dataset(scene2, config=DataConfig(on_bad_frame="ignore", intrinsics=[20.0, 20.0, 16.0, 12.0]))
    for p in (scene2 / "results").iterdir():
        p.unlink()
    with pytest.raises(DataError, match="no frame"):
        open_dataset(scene2, kind="replica")


def test_tum_depth_images_are_paired_one_to_one_as_associate_py_does():
    """A depth image goes to one colour frame only, the closest; the other takes its next depth within
    20 ms, or is no frame. Poses (100 Hz ground truth) stay nearest-stamp."""
    from ogscene3d.datasets.tum import associate

    rgb = np.array([0.000, 0.012, 0.060])
    depth = np.array([0.030, 0.005])
    assert associate(rgb, depth).tolist() == [1, 1, -1]  # nearest: depth 0.005 twice
    assert associate(rgb, depth, one_to_one=True).tolist() == [1, 0, -1]  # 0.012 takes 0.030 (18 ms)
    assert associate(rgb, np.array([0.005]), one_to_one=True).tolist() == [0, -1, -1]
    assert associate(rgb, np.array([]), one_to_one=True).tolist() == [-1, -1, -1]
