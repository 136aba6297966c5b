"""Dataset layouts as users bring them: zero-padded ScanNet-style exports, missing files found when a
dataset is opened, default intrinsics that warn, a parent folder with data.kind set, and partial
precomputed segments."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pytest
from dataset_files import _png, _pose, _rgb, make_replica

from ogscene3d.config import DataConfig
from ogscene3d.datasets import base, open_dataset
from ogscene3d.errors import DataError
from ogscene3d.segmentation.precomputed import write_segments

K3 = np.array([[100.0, 0, 16], [0, 100.0, 12], [0, 0, 1]])
HALF = np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])  # what reading adds to a file K (OpenCV centres)


def make_byo(root: Path, n: int = 3, pad: str = "{:06d}", ext: str = ".png", poses: bool = False) -> Path:
    """A bring-your-own-camera export: color/, depth/ (mm), intrinsics.txt and optionally pose/."""
    for i in range(n):
        _png(root / "color" / f"{pad.format(i)}{ext}", _rgb(24, 32, i))
        _png(root / "depth" / f"{pad.format(i)}.png", np.full((24, 32), 1000 + 100 * i, np.uint16))
        if poses:
            (root / "pose").mkdir(exist_ok=True)
            np.savetxt(root / "pose" / f"{pad.format(i)}.txt", _pose(0.5 * i))
    np.savetxt(root / "intrinsics.txt", K3)
    return root


# --------------------------------------------------------------------------------------- ScanNet-style names


@pytest.mark.parametrize("pad", ["{:06d}", "{}", "{:05d}"])
@pytest.mark.parametrize("ext", [".png", ".jpg"])
def test_scannet_layout_any_zero_padding(tmp_path, pad, ext):
    root = make_byo(tmp_path / "cam", pad=pad, ext=ext, poses=True)
    ds = open_dataset(root)
    assert ds.kind == "scannet" and len(ds) == 3
    f = ds[2]
    assert f.name == pad.format(2) and np.allclose(f.depth, 1.2)
    assert f.pose[0, 3] == pytest.approx(1.0)
    np.testing.assert_allclose(f.K, K3 + HALF)  # intrinsics.txt counts pixel centres from 0


def test_scannet_layout_matches_files_by_number(tmp_path):
    """Colour, depth and pose files with different padding still pair up by frame number."""
    root = make_byo(tmp_path / "cam", pad="{:06d}")
    for i in range(3):
        (root / "depth" / f"{i:06d}.png").rename(root / "depth" / f"{i}.png")
    (root / "pose").mkdir()
    for i in range(3):
        np.savetxt(root / "pose" / f"{i:04d}.txt", _pose(0.5 * i))
    f = open_dataset(root)[1]
    assert f.name == "000001" and np.allclose(f.depth, 1.1) and f.pose[0, 3] == pytest.approx(0.5)
    # two files claiming one frame number are ambiguous
    shutil.copy(root / "depth" / "1.png", root / "depth" / "01.png")
    with pytest.raises(DataError, match=r"depth: 01\.png and 1\.png are both frame 1"):
        open_dataset(root)


# ------------------------------------------------------------------------------------ missing files at open


def test_missing_files_are_reported_at_open_all_at_once(tmp_path, monkeypatch, caplog):
    scene = make_replica(tmp_path, n=10)
    for i in (1, 3, 4, 5, 6, 7, 8):
        (scene / "results" / f"depth{i:06d}.png").unlink()

    def no_reading(*args, **kwargs):
        raise AssertionError("opening a dataset must not read images")

    with monkeypatch.context() as m:
        m.setattr(base.cv2, "imdecode", no_reading)
        with pytest.raises(DataError) as err:
            open_dataset(scene)
    msg = str(err.value)
    assert msg.startswith(f"{scene}: 7 of the 10 selected frames lack files (replica layout); 7 missing: ")
    assert "results/depth000001.png, results/depth000003.png" in msg and "and 2 more" in msg
    assert "depth000008.png" not in msg and "data.on_bad_frame" in msg
    # only the selected frames are checked
    assert len(open_dataset(scene, config=DataConfig(start=0, stride=9))) == 2
    # skip: one warning at open, the frames left out
    with caplog.at_level(logging.WARNING, logger="ogscene3d.datasets.base"):
        ds = open_dataset(scene, config=DataConfig(on_bad_frame="skip"))
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1 and "7 missing" in warnings[0] and "leaving those frames out" in warnings[0]
    assert [f.name for f in ds] == ["frame000000", "frame000002", "frame000009"]
    with pytest.raises(DataError, match="no selected frame is left"):
        open_dataset(scene, config=DataConfig(on_bad_frame="skip", start=3, max_frames=3))


def test_missing_files_in_other_layouts(tmp_path):
    # ScanNet-style: per-frame pose files are checked too
    root = make_byo(tmp_path / "cam", poses=True)
    (root / "pose" / "000001.txt").unlink()
    (root / "depth" / "000002.png").unlink()
    with pytest.raises(DataError, match=r"2 of the 3 .*scannet layout.*pose/000001\.txt, depth/000002\.png"):
        open_dataset(root)
    # an empty pose/ holds no poses to miss: the frames need tracking, as without pose/
    empty = make_byo(tmp_path / "cam2")
    (empty / "pose").mkdir()
    assert open_dataset(empty)[0].pose is None
    # TUM: the files rgb.txt / depth.txt name
    tum = tmp_path / "tum"
    (tum / "rgb").mkdir(parents=True)
    _png(tum / "rgb" / "1.000000.png", _rgb(24, 32))
    (tum / "rgb.txt").write_text("1.000000 rgb/1.000000.png\n")
    (tum / "depth.txt").write_text("1.001000 depth/1.001000.png\n")
    with pytest.raises(DataError, match=r"tum layout.*depth/1\.001000\.png"):
        open_dataset(tum, config=DataConfig(intrinsics=[100.0, 100.0, 16.0, 12.0]))


def test_file_removed_after_open_fails_that_frame(tmp_path):
    scene = make_replica(tmp_path)
    ds = open_dataset(scene)
    (scene / "results" / "depth000001.png").unlink()
    with pytest.raises(DataError, match=r"depth000001\.png: depth file is missing"):
        ds[1]


# --------------------------------------------------------------------------------------- intrinsics


def _sevenscenes(folder: Path, n: int = 2) -> Path:
    for i in range(n):
        _png(folder / f"frame-{i:06d}.color.png", _rgb(24, 32, i))
        _png(folder / f"frame-{i:06d}.depth.png", np.full((24, 32), 1500, np.uint16))
        np.savetxt(folder / f"frame-{i:06d}.pose.txt", _pose(i))
    return folder


def _k_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "default intrinsics" in r.getMessage()]


def test_sevenscenes_default_intrinsics_warn(tmp_path, caplog):
    root = _sevenscenes(tmp_path / "chess")
    with caplog.at_level(logging.WARNING, logger="ogscene3d.datasets.sevenscenes"):
        ds = open_dataset(root)
        list(ds)
    (msg,) = _k_warnings(caplog)
    assert "camera-intrinsics.txt" in msg and "data.intrinsics" in msg and "585" in msg
    np.testing.assert_allclose(ds.K[0], [585, 0, 320.5])
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="ogscene3d.datasets.sevenscenes"):
        ds = open_dataset(root, config=DataConfig(intrinsics=[100.0, 100.0, 16.0, 12.0]))
        assert ds.K[0, 0] == 100.0
        np.savetxt(root / "camera-intrinsics.txt", K3)
        assert open_dataset(root).K[0, 0] == 100.0
    assert not _k_warnings(caplog)


def test_labelfusion_intrinsics_in_a_sequence_folder(tmp_path, caplog):
    """camera-intrinsics.color.txt is found (and marks the label-fusion layout) where the reader reads it:
    the scene folder or its first sequence."""
    root = tmp_path / "shelf"
    _sevenscenes(root / "seq-01")
    np.savetxt(root / "seq-01" / "camera-intrinsics.color.txt", K3)
    np.savetxt(root / "seq-01" / "camera-intrinsics.txt", 2 * K3)
    ds = open_dataset(root)
    assert ds.kind == "labelfusion" and ds.K[0, 0] == 100.0  # the colour camera's file is preferred
    # label-fusion known only by its label images: the default warns naming both files
    (root / "seq-01" / "camera-intrinsics.color.txt").unlink()
    (root / "seq-01" / "camera-intrinsics.txt").unlink()
    _png(root / "seq-01" / "frame-000000.segm.png", np.zeros((24, 32), np.uint8))
    with caplog.at_level(logging.WARNING, logger="ogscene3d.datasets.sevenscenes"):
        assert open_dataset(root).kind == "labelfusion"
    (msg,) = _k_warnings(caplog)
    assert "camera-intrinsics.color.txt or camera-intrinsics.txt" in msg


# --------------------------------------------------------------------------------------- data.kind given


def test_explicit_kind_enters_a_single_scene(tmp_path):
    parent = tmp_path / "Replica"
    scene = make_replica(parent)
    ds = open_dataset(parent, kind="replica")
    assert ds.root == scene and len(ds) == 3
    assert open_dataset(config=DataConfig(path=str(parent), kind="replica")).root == scene
    with pytest.raises(DataError, match="does not look like a tum dataset"):
        open_dataset(parent, kind="tum")
    shutil.copytree(scene, parent / "office0")
    with pytest.raises(DataError, match=r"holds several scenes \(office0, scene\)"):
        open_dataset(parent, kind="replica")


def test_explicit_kind_on_the_replica_sample(shared_data):
    ds = open_dataset(shared_data / "replica_room0_nice_slam", kind="replica", max_frames=2)
    assert ds.kind == "replica" and ds.root.name == "room0" and len(ds) == 2


# --------------------------------------------------------------------------------------- partial segments


def test_frames_without_segments_files_get_none(tmp_path, caplog):
    scene = make_replica(tmp_path)
    seg = tmp_path / "seg"
    ids = np.zeros((24, 32), np.int32)
    ids[:, 16:] = 7
    write_segments(seg, "frame000001", ids, {7: 0.9})
    with caplog.at_level(logging.WARNING, logger="ogscene3d.datasets.base"):
        frames = list(open_dataset(scene, segments_dir=seg))
    assert [f.segments is None for f in frames] == [True, False, True]
    assert frames[0].segment_scores == {} and np.array_equal(frames[1].segments, ids)
    (msg,) = [r.getMessage() for r in caplog.records]  # once, not per frame
    assert "frame000000.png" in msg and "segmentation.backend" in msg
    # a file that is there must be right
    write_segments(seg, "frame000002", np.zeros((12, 16), np.int32))
    with pytest.raises(DataError, match=r"frame000002\.png.*16x12"):
        open_dataset(scene, segments_dir=seg)[2]
