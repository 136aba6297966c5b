"""Dataset conventions checked against how the public reference code reads the same data: 7-Scenes' colour
is not registered to its depth (warned), TUM's freiburg sensor from the innermost folder that names one and
its fr1/fr2 lens distortion (warned), and intrinsics of another image size than the depth (warned)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from dataset_files import _png, _pose, _rgb

from ogscene3d.datasets import open_dataset


def _warnings(caplog, word: str) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING and word in r.getMessage()]


# --------------------------------------------------------------------------------------- 7-Scenes


def _sevenscenes(folder: Path, K: np.ndarray | None, n: int = 2) -> Path:
    for i in range(n):
        _png(folder / f"frame-{i:06d}.color.png", _rgb(24, 32, i))
        _png(folder / f"frame-{i:06d}.depth.png", np.full((24, 32), 1500, np.uint16))
        np.savetxt(folder / f"frame-{i:06d}.pose.txt", _pose(i))
    if K is not None:
        np.savetxt(folder / "camera-intrinsics.txt", K)
    return folder


def test_sevenscenes_depth_camera_warns_that_colour_is_not_registered(tmp_path, caplog):
    K585 = np.array([[585.0, 0, 16], [0, 585.0, 12], [0, 0, 1]])
    with caplog.at_level(logging.WARNING):
        open_dataset(_sevenscenes(tmp_path / "kitchen", K585))[0]
    (msg,) = _warnings(caplog, "not registered")
    assert "depth camera" in msg and "585" in msg
    caplog.clear()
    with caplog.at_level(logging.WARNING):  # another camera in the same layout (e.g. 3DMatch's sun3d scenes)
        open_dataset(_sevenscenes(tmp_path / "sun3d", np.array([[570.3, 0, 16], [0, 570.3, 12], [0, 0, 1]])))
    assert not _warnings(caplog, "not registered")


def test_sevenscenes_sample_warns_that_colour_is_not_registered(shared_data, caplog):
    with caplog.at_level(logging.WARNING):
        open_dataset(shared_data / "7scenes_redkitchen_stride20")
    assert len(_warnings(caplog, "not registered")) == 1
    caplog.clear()
    with caplog.at_level(logging.WARNING):  # label-fusion reads the same names with its own camera
        open_dataset(shared_data / "labelfusion_shelf_labels")
    assert not _warnings(caplog, "not registered")


# --------------------------------------------------------------------------------------- TUM


def _tum(root: Path, n: int = 2) -> Path:
    rgb, depth = [], []
    for i in range(n):
        t = 100.0 + 0.1 * i
        _png(root / "rgb" / f"{t:.6f}.png", _rgb(24, 32, i))
        _png(root / "depth" / f"{t:.6f}.png", np.full((24, 32), 5000, np.uint16))
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth.append(f"{t:.6f} depth/{t:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (root / "depth.txt").write_text("\n".join(depth) + "\n")
    return root


def test_tum_sensor_is_the_one_the_innermost_folder_names(tmp_path):
    # a parent folder naming another sensor must not decide the calibration of the sequence in it
    ds = open_dataset(_tum(tmp_path / "freiburg1_runs" / "rgbd_dataset_freiburg3_long_office_household"))
    np.testing.assert_allclose(ds.K[0, 0], 535.4)
    np.testing.assert_allclose(ds.K[:2, 2], [320.1 + 0.5, 247.6 + 0.5])
    ds = open_dataset(_tum(tmp_path / "freiburg3_runs" / "rgbd_dataset_freiburg2_xyz"))
    np.testing.assert_allclose(ds.K[0, 0], 520.9)
    ds = open_dataset(_tum(tmp_path / "rgbd_dataset_freiburg1_desk" / "copy"))  # a sub-folder: its parent's
    np.testing.assert_allclose(ds.K[0, 0], 517.3)


def test_tum_fr1_fr2_lens_distortion_is_warned(tmp_path, caplog):
    for name, warned in (("rgbd_dataset_freiburg1_desk", True), ("rgbd_dataset_freiburg2_xyz", True),
                         ("rgbd_dataset_freiburg3_office", False)):  # fmt: skip
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            open_dataset(_tum(tmp_path / name))
        assert len(_warnings(caplog, "distortion")) == int(warned), name


# --------------------------------------------------------------------------------------- intrinsics size


def test_intrinsics_of_the_colour_size_are_warned(tmp_path, caplog):
    """A bring-your-own ScanNet-style export with colour larger than depth and intrinsics.txt written for
    the colour image: the frames are back-projected at the depth size with a K that is not its."""
    root = tmp_path / "byo"
    for i in range(2):
        _png(root / "color" / f"{i:06d}.png", _rgb(48, 64, i))
        _png(root / "depth" / f"{i:06d}.png", np.full((24, 32), 1500, np.uint16))
    np.savetxt(root / "intrinsics.txt", [[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])  # the colour's
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(root)
        ds[0], ds[1]
    (msg,) = _warnings(caplog, "principal point")
    assert "32x24" in msg and "colour" in msg
    caplog.clear()
    np.savetxt(root / "intrinsics.txt", [[50.0, 0, 15.5], [0, 50.0, 11.5], [0, 0, 1]])  # the depth's
    with caplog.at_level(logging.WARNING):
        open_dataset(root)[0]
    assert not _warnings(caplog, "principal point")
