"""Promises of the design (docs/design.md and the file formats it points to, docs/formats.md) that no other
test pinned down."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from dataset_files import _png, _pose, _rgb

from ogscene3d.datasets import open_dataset
from ogscene3d.errors import DataError

K3 = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])


def _scannet_colour_larger(root: Path) -> Path:
    """A ScanNet export whose colour (64x48) is larger than its depth (32x24), as ScanNet's 1296x968 and
    640x480: frames are read at the depth size."""
    for i in range(2):
        _png(root / "color" / f"{i}.png", _rgb(48, 64, i))
        _png(root / "depth" / f"{i}.png", np.full((24, 32), 1500, np.uint16))
        (root / "pose").mkdir(exist_ok=True)
        np.savetxt(root / "pose" / f"{i}.txt", _pose(0.1 * i))
    (root / "intrinsic").mkdir()
    K = np.eye(4)
    K[:3, :3] = K3
    np.savetxt(root / "intrinsic" / "intrinsic_color.txt", K)
    return root


def _write_segments(seg_dir: Path, stem: str, ids: np.ndarray, scores: dict[int, float]) -> None:
    """docs/formats.md "Precomputed segments": DIR/<rgb stem>.png uint16, DIR/<rgb stem>.json
    {"scores": {"<id>": float}}."""
    _png(seg_dir / f"{stem}.png", ids.astype(np.uint16))
    (seg_dir / f"{stem}.json").write_text(json.dumps({"scores": {str(k): v for k, v in scores.items()}}))


def test_segments_at_the_rgb_files_size_are_read_where_colour_is_resampled(tmp_path):
    """docs/formats.md: precomputed segments are at the RGB image's size. ScanNet frames resample colour to
    the depth size; segments a SAM run wrote at the colour file's size are resampled with it (nearest), and
    segments at the frame's size (what ``ogscene3d segment`` writes) are read as they are."""
    root = _scannet_colour_larger(tmp_path / "scan")
    seg = tmp_path / "segs"
    ids = np.zeros((48, 64), np.uint16)
    ids[:24, :32] = 7  # top-left quarter
    ids[30:, 40:] = 300
    _write_segments(seg, "0", ids, {7: 0.9, 300: 0.95})
    small = np.zeros((24, 32), np.uint16)
    small[:, 16:] = 5
    _write_segments(seg, "1", small, {5: 0.92})

    ds = open_dataset(root, segments_dir=seg)
    f0 = ds[0]
    assert f0.rgb.shape[:2] == f0.depth.shape == (24, 32)
    assert f0.segments.shape == (24, 32)
    assert (f0.segments[:12, :16] == 7).all() and (f0.segments[15:, 20:] == 300).all()
    assert set(np.unique(f0.segments)) == {0, 7, 300}
    assert f0.segment_scores == {7: pytest.approx(0.9), 300: pytest.approx(0.95)}
    f1 = ds[1]
    np.testing.assert_array_equal(f1.segments, small.astype(np.int32))
    assert f1.segment_scores == {5: pytest.approx(0.92)}


def test_segments_of_another_size_are_refused_naming_both_sizes(tmp_path):
    root = _scannet_colour_larger(tmp_path / "scan")
    seg = tmp_path / "segs"
    _write_segments(seg, "0", np.ones((40, 40), np.uint16), {1: 0.9})
    with pytest.raises(DataError, match=r"40x40.*64x48.*32x24"):
        open_dataset(root, segments_dir=seg)[0]
