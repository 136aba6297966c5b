"""ROS recordings as data sources: bags written with rosbags' writers from a synthetic scene read back as the
scene's own frames, and map as the scene does; the bad cases give clear errors or logged skips."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from robot_recordings import BagSpec, small_scene, write_bag  # noqa: E402

from ogscene3d.config import DataConfig, load_config  # noqa: E402
from ogscene3d.datasets import open_dataset  # noqa: E402
from ogscene3d.datasets.rosbag_tf import Track  # noqa: E402
from ogscene3d.errors import ConfigError, DataError  # noqa: E402
from ogscene3d.mapping.mapper import Mapper  # noqa: E402

SUFFIX = {"ros1": ".bag", "mcap-file": ".mcap", "sqlite3": "", "mcap": ""}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """(scene folder, its frames, K in the OpenCV convention ROS calibrations use)."""
    return small_scene(tmp_path_factory.mktemp("scene") / "s")


def _bag(tmp_path: Path, scene, **spec) -> Path:
    spec = BagSpec(**spec)
    _, frames, K = scene
    tmp_path.mkdir(parents=True, exist_ok=True)
    return write_bag(tmp_path / f"rec{SUFFIX[spec.storage]}", frames, K, spec)


def _open(path: Path, **data) -> object:
    return open_dataset(path, config=DataConfig(**data))


@pytest.mark.parametrize("storage", ["ros1", "sqlite3", "mcap", "mcap-file"])
def test_a_bag_reads_as_the_scenes_frames(tmp_path, scene, storage):
    root, frames, _ = scene
    path = _bag(tmp_path, scene, storage=storage)
    ds = open_dataset(path)  # found by suffix or by the ROS 2 folder's metadata.yaml
    assert ds.kind == "rosbag" and len(ds) == len(frames)
    np.testing.assert_array_equal(ds.K, open_dataset(root).K)
    assert ds.camera.width == 64 and ds.camera.height == 48
    for f, g in zip(frames, ds):
        assert g.name == f.name  # frameNNNNNN: the scene's segments are found by it
        np.testing.assert_array_equal(g.rgb, f.rgb)
        np.testing.assert_array_equal(g.depth, f.depth)
        # world -> camera_link (/tf) chained with camera_link -> optical frame (/tf_static)
        np.testing.assert_allclose(g.pose, f.pose, atol=1e-9)
        assert g.timestamp == pytest.approx(100.0 + 0.1 * f.index)


def test_mapping_a_bag_gives_the_folders_map(tmp_path, scene):
    """One storage is enough: every storage reads back the very same frames (above)."""
    root, _, _ = scene
    path = _bag(tmp_path, scene, storage="ros1")
    cfg = load_config(
        None, ["graph.enabled=false", "mapping.optimize.iters=2", "mapping.ablation=local+global"]
    )
    maps = []
    for ds in (open_dataset(root), open_dataset(path, segments_dir=root / "segments")):
        m = Mapper(cfg, "cpu")
        for frame in ds:
            assert frame.segments is not None
            m.process(frame)
        maps.append(m.map)
    a, b = maps
    assert len(a) == len(b) > 0
    for name in ("means", "colors", "labels", "opacities"):
        np.testing.assert_allclose(
            getattr(b, name).cpu().numpy(), getattr(a, name).cpu().numpy(), atol=1e-5, err_msg=name
        )


@pytest.mark.parametrize(
    ("colour", "depth", "rgb_tol", "depth_tol"),
    [
        ("bgr8", "16UC1", 0, 5e-4),  # millimetres
        ("png", "compressedDepth", 0, 5e-4),
        ("jpeg", "32FC1", 12, 0),
    ],
)
def test_encodings(tmp_path, scene, colour, depth, rgb_tol, depth_tol):
    _, frames, _ = scene
    ds = open_dataset(_bag(tmp_path, scene, colour=colour, depth=depth))
    for f, g in zip(frames, ds):
        assert np.abs(g.rgb.astype(int) - f.rgb).mean() <= rgb_tol
        np.testing.assert_allclose(g.depth, f.depth, atol=depth_tol)


def test_mono8_colour_is_grey(tmp_path, scene):
    ds = open_dataset(_bag(tmp_path, scene, colour="mono8"))
    rgb = ds[0].rgb
    assert np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2])


@pytest.mark.parametrize("poses", ["odometry", "pose"])
def test_poses_from_a_pose_topic(tmp_path, scene, poses):
    _, frames, _ = scene
    ds = open_dataset(_bag(tmp_path, scene, poses=poses, storage="sqlite3"))
    for f, g in zip(frames, ds):
        np.testing.assert_allclose(g.pose, f.pose, atol=1e-9)


def test_track_interpolates_between_samples_and_holds_only_within_tolerance():
    track = Track("world", "cam")
    half = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])  # 90 degrees about z
    track.add(2.0, np.array([2.0, 0.0, 0.0]), half)
    track.add(0.0, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))  # out of order, as bags may store them
    track.finish()
    T = track.at(1.0, 0.01)
    np.testing.assert_allclose(T[:3, 3], [1.0, 0.0, 0.0])
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)  # half of the 90 degrees
    np.testing.assert_allclose(T[:3, :3], [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-12)
    assert (
        track.at(2.005, 0.01) is not None and track.at(2.02, 0.01) is None and track.at(-0.02, 0.01) is None
    )


def test_several_colour_topics_need_an_option_unless_the_others_are_infrared(tmp_path, scene):
    path = _bag(tmp_path, scene, extra_colour_topic=("/camera/infra1/image_rect_raw", "mono8"))
    assert open_dataset(path).rgb_conn.topic == "/camera/color/image_raw"  # mono8 beside colour: infrared
    path = _bag(tmp_path / "b", scene, extra_colour_topic=("/camera2/color/image_raw", "rgb8"))
    with pytest.raises(DataError, match=r"several colour image topics \(/camera/color/image_raw, "
                       r"/camera2/color/image_raw\); choose one with data.ros_rgb_topic"):  # fmt: skip
        open_dataset(path)
    assert _open(path, ros_rgb_topic="/camera/color/image_raw").rgb_conn.topic == "/camera/color/image_raw"


def test_several_depth_topics_take_the_registered_one(tmp_path, scene):
    ds = open_dataset(_bag(tmp_path, scene, extra_depth_topic=True))
    assert ds.depth_conn.topic == "/camera/aligned_depth_to_color/image_raw"
    with pytest.raises(DataError, match="not registered to colour.*camera frames differ"):
        _open(ds.root, ros_depth_topic="/camera/depth/image_rect_raw")


def test_unregistered_depth_is_refused_naming_the_topics(tmp_path, scene):
    path = _bag(tmp_path, scene, depth_size=(24, 32))
    with pytest.raises(
        DataError, match=r"aligned_depth_to_color/image_raw \(32x24\) is not registered .*64x48"
    ):
        open_dataset(path)


def test_a_missing_topic_lists_the_bags_topics(tmp_path, scene):
    path = _bag(tmp_path, scene, depth="none")
    with pytest.raises(
        DataError, match=r"no depth image topic(.|\n)*/camera/color/image_raw  \[sensor_msgs/msg/Image"
    ):
        open_dataset(path)
    path = _bag(tmp_path / "b", scene)
    with pytest.raises(DataError, match="data.ros_rgb_topic = '/nope' is not a topic(.|\n)*/tf_static"):
        _open(path, ros_rgb_topic="/nope")


def test_unsynchronised_streams(tmp_path, scene, caplog):
    path = _bag(tmp_path, scene, depth_offset=0.03)
    with pytest.raises(DataError, match=r"0.030 s apart\): the streams are not synchronised"):
        open_dataset(path)
    assert len(_open(path, ros_sync_tolerance=0.04)) == 4
    path = _bag(tmp_path / "b", scene, missing_depth={1, 2})
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(path)
    assert [r.name for r in ds.records] == ["frame000000", "frame000003"]
    assert "2 of the 4 colour images on /camera/color/image_raw have no depth image" in caplog.text
    assert "frame000001 (t=100.100000), frame000002" in caplog.text


def test_a_corrupt_message_is_an_error_or_a_logged_skip(tmp_path, scene, caplog):
    path = _bag(tmp_path, scene, corrupt_colour={1})
    with pytest.raises(DataError, match="message 1 on /camera/color/image_raw.*corrupt.*on_bad_frame: skip"):
        open_dataset(path)
    with caplog.at_level(logging.WARNING):
        ds = _open(path, on_bad_frame="skip")
    assert [r.name for r in ds.records] == ["frame000000", "frame000002", "frame000003"]
    assert "leaving it out" in caplog.text

    path = _bag(tmp_path / "b", scene, truncated_colour={2})  # pixels cut short: found when read
    ds = open_dataset(path)
    with pytest.raises(DataError, match="colour image of frame000002 on /camera/color/image_raw.*data bytes"):
        ds[2]
    assert [f.name for f in _open(path, on_bad_frame="skip")] == ["frame000000", "frame000001", "frame000003"]


def test_a_bag_without_poses_needs_odometry(tmp_path, scene, caplog):
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(_bag(tmp_path, scene, poses=None))
    assert "no camera poses" in caplog.text and "--poses odometry" in caplog.text
    frame = ds[0]
    assert frame.pose is None
    with pytest.raises(DataError, match="no camera pose.*--poses odometry"):
        Mapper(load_config(None, ["graph.enabled=false"]), "cpu").process(frame)


def test_a_topic_with_several_publishers_is_read_whole(tmp_path, scene):
    """ROS 1 bags hold one connection per publisher: /tf from two nodes gives every transform."""
    _, frames, _ = scene
    ds = open_dataset(_bag(tmp_path, scene, tf_publishers=2))
    assert len(ds.bag.topic_map()["/tf"].connections) == 2 and len(ds) == 4
    for f, g in zip(frames, ds):
        np.testing.assert_allclose(g.pose, f.pose, atol=1e-9)


def test_tf_frame_options(tmp_path, scene):
    path = _bag(tmp_path, scene)
    with pytest.raises(
        DataError, match="tf has no frame 'map'; its frames: camera_color_optical_frame, camera_link"
    ):
        _open(path, ros_world_frame="map")
    # the pose of camera_link in odom: the optical frame's pose less the static link -> optical transform
    ds = _open(path, ros_camera_frame="camera_link")
    _, frames, _ = scene
    from robot_recordings import LINK_TO_OPTICAL

    np.testing.assert_allclose(ds[1].pose, frames[1].pose @ np.linalg.inv(LINK_TO_OPTICAL), atol=1e-9)


def test_distortion_is_warned_about_with_its_size(tmp_path, scene, caplog):
    with caplog.at_level(logging.WARNING):
        open_dataset(_bag(tmp_path, scene, distortion=(0.1, 0.0, 0.0, 0.0, 0.0)))
    assert "lens distortion plumb_bob [0.1, 0.0, 0.0, 0.0, 0.0], which is not corrected" in caplog.text
    assert "px off in the image corners" in caplog.text


def test_a_kind_given_in_the_config_opens_a_bag(tmp_path, scene):
    path = _bag(tmp_path, scene, storage="mcap-file")
    assert open_dataset(config=DataConfig(path=str(path), kind="rosbag")).kind == "rosbag"
    notes = tmp_path / "notes.txt"
    notes.write_text("not a recording")
    with pytest.raises(DataError, match="is a file, but not a .bag, .mcap or .r3d recording"):
        open_dataset(notes)
    (tmp_path / "desk.db3").write_bytes(b"SQLite format 3\x00")
    with pytest.raises(DataError, match="librealsense recording.*--source realsense:FILE.*metadata.yaml"):
        open_dataset(tmp_path / "desk.db3")


def test_without_rosbags_the_error_names_the_extra(tmp_path, scene, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name.startswith("rosbags"):
            raise ImportError("No module named 'rosbags'")
        return real_import(name, *args, **kwargs)

    path = _bag(tmp_path, scene)
    monkeypatch.setattr(builtins, "__import__", fake_import)
    monkeypatch.setattr("importlib.import_module", lambda name: fake_import(name))
    with pytest.raises(ConfigError, match=r'pip install "ogscene3d\[ros\]"'):
        open_dataset(path)


def test_track_and_run_accept_a_bag_path(tmp_path, scene):
    """``run --data BAG`` records the bag and maps it (the CLI path every command shares)."""
    from ogscene3d.cli import main

    path = _bag(tmp_path, scene)
    out = tmp_path / "run"
    code = main(
        ["run", "--data", str(path), "--out", str(out), "--segments", str(scene[0] / "segments"),
         "--set", "graph.enabled=false", "--set", "mapping.optimize.iters=1"]
    )  # fmt: skip
    assert code == 0 and (out / "gaussians.ply").is_file()
    assert dataclasses.asdict(load_config(out / "config.yaml").data)["path"] == str(path.resolve())
    assert main(["track", "--data", str(path), "--out", str(tmp_path / "track")]) == 0
    assert (tmp_path / "track" / "traj.txt").is_file()


def test_image_decoding_details():
    """Row padding, big-endian 16-bit depth, image_transport's 32FC1 compressedDepth, a truncated PNG."""
    import types

    import cv2

    from ogscene3d.datasets.rosbag_io import colour_from_image, depth_from_compressed, depth_from_image

    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    padded = np.zeros((2, 12), np.uint8)  # step 12 > 3 pixels x 3 bytes
    padded[:, :9] = rgb.reshape(2, 9)
    msg = types.SimpleNamespace(
        height=2, width=3, step=12, encoding="rgb8", is_bigendian=0, data=padded.ravel()
    )
    np.testing.assert_array_equal(colour_from_image(msg), rgb)

    mm = np.array([[1000, 2500], [0, 65535]], np.uint16)
    msg = types.SimpleNamespace(
        height=2,
        width=2,
        step=4,
        encoding="16UC1",
        is_bigendian=1,
        data=np.frombuffer(mm.astype(">u2").tobytes(), np.uint8),
    )
    np.testing.assert_array_equal(depth_from_image(msg), mm)

    # compressed_depth_image_transport's 32FC1: q = A / depth + B in a 16-bit PNG, 0 = no depth
    depth = np.array([[0.5, 1.0], [4.0, 0.0]], np.float32)
    A = 100.0 * 101.0
    B = 1.0 - A / 10.0
    q = np.where(depth > 0, np.round(A / np.maximum(depth, 1e-6) + B), 0).astype(np.uint16)
    ok, png = cv2.imencode(".png", q)
    header = np.array([0], "<i4").tobytes() + np.array([A, B], "<f4").tobytes()
    msg = types.SimpleNamespace(
        format="32FC1; compressedDepth png", data=np.frombuffer(header + png.tobytes(), np.uint8)
    )
    np.testing.assert_allclose(depth_from_compressed(msg), depth, rtol=2e-4)

    msg = types.SimpleNamespace(
        format="16UC1; compressedDepth png", data=np.frombuffer(header + png.tobytes()[:-20], np.uint8)
    )
    with pytest.raises(ValueError, match="PNG is truncated"):
        depth_from_compressed(msg)
