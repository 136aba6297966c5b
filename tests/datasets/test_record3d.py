"""Record3D ``.r3d`` captures written from a synthetic scene read back as its frames and map as it does."""

from __future__ import annotations

import logging
import zipfile

import numpy as np
import pytest

from ogscene3d.config import DataConfig, load_config
from ogscene3d.datasets import open_dataset
from ogscene3d.datasets.record3d import arkit_to_opencv, lzfse_module
from ogscene3d.errors import ConfigError, DataError
from ogscene3d.mapping.mapper import Mapper

try:
    lzfse_module()
except ConfigError:
    pytest.skip("no LZFSE bindings (pip install lzfse)", allow_module_level=True)

from robot_recordings import small_scene, write_r3d  # noqa: E402


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return small_scene(tmp_path_factory.mktemp("scene") / "s")


def _r3d(tmp_path, scene, name="cap.r3d", **kw):
    _, frames, K = scene
    return write_r3d(tmp_path / name, frames, K, **kw)


def test_arkit_poses_become_opencv_camera_to_world_with_up_minus_y():
    # ARKit: camera 1 m up (+y), looking down -z; ours: 1 m along -y (up), looking down +z
    T = arkit_to_opencv(np.array([0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0]))
    np.testing.assert_allclose(
        T,
        np.diag([1.0, 1.0, 1.0, 1.0]) + np.array([[0, 0, 0, 0], [0, 0, 0, -1.0], [0, 0, 0, 0], [0, 0, 0, 0]]),
    )
    # ARKit: turned 90 degrees left (about +y): looks down -x. Ours: the optical axis (+z) points to world -x
    q = [0.0, np.sin(np.pi / 4), 0.0, np.cos(np.pi / 4)]
    T = arkit_to_opencv(np.array([*q, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(T[:3, 2], [-1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(T[:3, 1], [0.0, 1.0, 0.0], atol=1e-12)  # image down is world down (+y)


def test_a_capture_reads_as_the_scenes_frames(tmp_path, scene):
    root, frames, _ = scene
    ds = open_dataset(_r3d(tmp_path, scene))
    assert ds.kind == "record3d" and len(ds) == 4 and ds.camera.width == 64
    np.testing.assert_allclose(ds.K, open_dataset(root).K, atol=1e-5)
    for f, g in zip(frames, ds):
        assert g.name == f.name
        np.testing.assert_array_equal(g.depth, f.depth)
        np.testing.assert_allclose(g.pose, f.pose, atol=1e-9)
        assert np.abs(g.rgb.astype(int) - f.rgb).mean() < 4  # JPEG


def test_colour_larger_than_depth_is_resampled_and_K_scaled(tmp_path, scene):
    root, frames, _ = scene
    ds = open_dataset(_r3d(tmp_path, scene, rgb_scale=3, with_depth_size=False))  # older metadata: no dw/dh
    assert ds.camera.width == 64 and ds.camera.height == 48
    np.testing.assert_allclose(ds.K, open_dataset(root).K, atol=1e-4)
    assert ds[0].rgb.shape == (48, 64, 3)


def test_low_confidence_depth_is_left_out(tmp_path, scene):
    _, frames, _ = scene
    conf = [np.full((48, 64), 2, np.uint8) for _ in frames]
    conf[0][:, :10] = 0
    conf[0][:, 10:20] = 1
    path = _r3d(tmp_path, scene, conf=conf)
    depth = open_dataset(path)[0].depth
    assert not depth[:, :10].any() and (depth[:, 10:20] > 0).all()
    depth = open_dataset(path, config=DataConfig(r3d_min_confidence=2))[0].depth
    assert not depth[:, :20].any()
    assert (open_dataset(path, config=DataConfig(r3d_min_confidence=0))[0].depth > 0).all()


def test_mapping_a_capture_gives_the_folders_map(tmp_path, scene):
    root, _, _ = scene
    cfg = load_config(
        None, ["graph.enabled=false", "mapping.optimize.iters=2", "mapping.ablation=local+global"]
    )
    maps = []
    # colour stored losslessly: this compares what the reader makes of poses, intrinsics and depth, not JPEG
    capture = _r3d(tmp_path, scene, lossless=True)
    for ds in (open_dataset(root), open_dataset(capture, segments_dir=root / "segments")):
        m = Mapper(cfg, "cpu")
        for frame in ds:
            m.process(frame)
        maps.append(m.map)
    a, b = maps
    assert len(a) == len(b) > 0
    for name in ("means", "colors", "labels", "opacities"):
        np.testing.assert_allclose(
            getattr(b, name).cpu().numpy(), getattr(a, name).cpu().numpy(), atol=1e-5, err_msg=name
        )


def _rewrite(src, dst, change):
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            data = change(item.filename, zin.read(item.filename))
            if data is not None:
                zout.writestr(item.filename, data)
    return dst


def test_bad_captures(tmp_path, scene, caplog):
    path = _r3d(tmp_path, scene)
    bad = _rewrite(path, tmp_path / "bad.r3d", lambda n, d: b"garbage" if n == "rgbd/2.depth" else d)
    ds = open_dataset(bad)
    with pytest.raises(DataError, match=r"bad.r3d: rgbd/2.depth is not LZFSE-compressed data"):
        ds[2]
    with caplog.at_level(logging.WARNING):
        names = [f.name for f in open_dataset(bad, config=DataConfig(on_bad_frame="skip"))]
    assert names == ["frame000000", "frame000001", "frame000003"] and "skipping frame 2" in caplog.text

    gone = _rewrite(path, tmp_path / "gone.r3d", lambda n, d: None if n == "rgbd/1.depth" else d)
    with pytest.raises(DataError, match=r"1 of 4 frames lack data: frame 1 \(depth\)"):
        open_dataset(gone)
    assert len(open_dataset(gone, config=DataConfig(on_bad_frame="skip"))) == 3
    # a frame without its colour image, or with an empty one, is named too (it used to vanish unnamed)
    for member, lacks in (("rgbd/1.jpg", "colour"), ("rgbd/3.jpg", "empty colour")):
        gap = None if lacks == "colour" else b""
        drop = _rewrite(path, tmp_path / "drop.r3d", lambda n, d, m=member, g=gap: g if n == m else d)
        frame = member[5]
        with pytest.raises(DataError, match=rf"1 of 4 frames lack data: frame {frame} \({lacks}\)"):
            open_dataset(drop)

    (tmp_path / "zip.r3d").write_bytes(b"not a zip")
    with pytest.raises(DataError, match="an .r3d is a zip file"):
        open_dataset(tmp_path / "zip.r3d")
    nometa = _rewrite(path, tmp_path / "nometa.r3d", lambda n, d: None if n == "metadata" else d)
    with pytest.raises(DataError, match="no 'metadata' entry"):
        open_dataset(nometa)
