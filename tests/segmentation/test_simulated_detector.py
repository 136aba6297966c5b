"""The simulated open-vocabulary detector: named segments fused with the simulated SAM's, with errors."""

import numpy as np
import pytest

from ogscene3d.segmentation.base import Segmentation
from ogscene3d.segmentation.simulated_detector import (
    DETECTOR_NOISE_LEVELS,
    DetectorNoise,
    SimulatedDetector,
)

CLASSES = {1: "floor", 2: "wall", 3: "chair", 4: "table", 5: "lamp", 6: "sofa"}


def _scene(h: int = 60, w: int = 80) -> np.ndarray:
    inst = np.full((h, w), 2, np.int64)  # wall
    inst[40:, :] = 1  # floor
    inst[25:50, 5:20] = 3  # chair
    inst[30:45, 30:60] = 4  # table
    inst[5:15, 65:75] = 5  # lamp
    inst[20:40, 62:78] = 6  # sofa
    return inst


def test_perfect_detector_names_every_vocabulary_object_and_fuses_like_sam_detector():
    inst = _scene()
    det = SimulatedDetector(CLASSES, noise="none", seed=0)
    assert det.vocabulary == ["chair", "lamp", "sofa", "table"]  # stuff classes left out
    dets, records = det.detect(inst, 0)
    assert sorted(dets.names) == ["chair", "lamp", "sofa", "table"] and len(records) == 4
    assert np.all(dets.scores >= det.score_thresh)
    # grid segments: the wall and floor plus the chair split in two (SAM over-segments)
    ids = np.zeros_like(inst, dtype=np.int32)
    ids[inst == 2], ids[inst == 1] = 1, 2
    ids[25:50, 5:12], ids[25:50, 12:20] = 3, 4
    ms = Segmentation(ids, {1: 0.97, 2: 0.96, 3: 0.9, 4: 0.91})
    res = det.segment(ms, inst, 0)
    mf = res.mf
    named = {name: mf.ids == k for k, name in mf.names.items()}
    assert sorted(named) == ["chair", "lamp", "sofa", "table"]
    for iid, name in ((3, "chair"), (4, "table"), (5, "lamp"), (6, "sofa")):
        np.testing.assert_array_equal(named[name], inst == iid)  # M_d wins its pixels
    # the chair's two grid pieces lie inside the detected chair: dropped; wall and floor kept unnamed
    assert len(np.unique(mf.ids[mf.ids > 0])) == 4 + 2
    assert all(mf.scores[k] == 1.0 for k in mf.names)  # level "none": exact masks, score 1


def test_detector_errors_miss_confuse_and_score_low_at_the_set_rates():
    inst = _scene()
    noise = DetectorNoise(miss_prob=0.3, confuse_prob=0.3, low_score_prob=0.3)
    det = SimulatedDetector(CLASSES, noise=noise, seed=3)
    n_frames, found = 300, 0
    for f in range(n_frames):
        dets, _ = det.detect(inst, f)
        found += len(dets)
        assert np.all(dets.scores >= det.score_thresh) and np.all(np.diff(dets.scores) <= 0)
    rate = found / (4 * n_frames)
    # kept: not missed (0.7) x (confused: all kept, since its scores reach the threshold, 0.3 + correct
    # and not low-scored 0.7 x 0.7 + low-scored above the threshold 0.7 x 0.3 x 1/3)
    expected = 0.7 * (0.3 + 0.7 * 0.7 + 0.7 * 0.3 / 3)
    assert rate == pytest.approx(expected, abs=0.05)
    # confusions stay plausible: a chair is taken for a sofa (in the vocabulary), never for a lamp
    names = [n for f in range(200) for n, b in zip(*_names_boxes(det, inst, f)) if b[0] < 20 and b[2] < 25]
    assert set(names) <= {"chair", "sofa"} and "sofa" in names


def _names_boxes(det, inst, f):
    dets, _ = det.detect(inst, f)
    return dets.names, dets.boxes


def test_output_is_seeded_per_frame_and_false_positives_take_a_surface():
    inst = _scene()
    det = SimulatedDetector(CLASSES, noise=DETECTOR_NOISE_LEVELS["high"], seed=7)
    a, ra = det.detect(inst, 5)
    b, rb = det.detect(inst, 5)
    assert a.names == b.names and np.array_equal(a.boxes, b.boxes)
    for f in range(50):
        _, recs = det.detect(inst, f)
        for r in recs:
            x0, y0, x1, y1 = r.box
            assert 0 <= x0 < x1 <= inst.shape[1] and 0 <= y0 < y1 <= inst.shape[0]
            assert r.crop.shape == (y1 - y0, x1 - x0) and np.all(inst[y0:y1, x0:x1][r.crop] > 0)
    with pytest.raises(ValueError, match="unknown detector noise level"):
        SimulatedDetector(CLASSES, noise="extreme")
    with pytest.raises(ValueError, match="vocabulary is empty"):
        SimulatedDetector({1: "floor"})


def test_synthetic_scene_segments_carry_detector_names_and_the_graph_finds_them(tmp_path, capsys):
    """The offline demo path: named simulated segments -> mapping -> graph nodes tagged with detector
    classes -> `graph -q`."""
    import json

    from ogscene3d.cli import main
    from ogscene3d.datasets.synthetic import make_synthetic_scene
    from ogscene3d.segmentation.precomputed import read_segmentation

    scene = make_synthetic_scene(tmp_path / "scene", seed=0, frames=4, width=80, height=60)
    gt = json.loads((scene / "gt" / "instances.json").read_text())["instances"]
    named: set[str] = set()
    for i in range(4):
        named |= set(read_segmentation(scene / "segments", f"frame{i:06d}").names.values())
    classes = {v["class"] for v in gt.values()}
    assert named and named <= classes - {"floor", "wall", "ceiling"}  # the scene's object classes only
    out = tmp_path / "run"
    args = ["run", "--data", str(scene), "--out", str(out), "--device", "cpu", "--no-progress",
            "--set", "mapping.optimize.iters=1", "--set", "mapping.association.knn_radius=0.06"]  # fmt: skip
    assert main(args) == 0
    nodes = json.loads((out / "graph.json").read_text())["nodes"]
    tags = {n["tag"] for n in nodes if n["caption_source"] == "detector"}
    assert tags and tags <= named
    tag = sorted(tags)[0]
    capsys.readouterr()
    assert main(["graph", str(out), "-q", tag]) == 0
    assert f"'{tag}' score" in capsys.readouterr().out
