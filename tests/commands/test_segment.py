"""``ogscene3d segment`` and ``make_segmenter`` on a tiny 7-Scenes-layout dataset with tiny ONNX models."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from onnx_models import make_detector, make_sam_decoder, make_sam_encoder

from ogscene3d.cli import main
from ogscene3d.config import SegmentationConfig
from ogscene3d.errors import ConfigError, DataError
from ogscene3d.segmentation.classical import ClassicalSegmenter
from ogscene3d.segmentation.factory import make_segmenter
from ogscene3d.segmentation.fusion import SamDetectorSegmenter
from ogscene3d.segmentation.precomputed import read_segmentation, read_segments, write_segments
from ogscene3d.segmentation.sam_onnx import SamOnnx

H, W = 96, 128


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("seg_cli")
    data = root / "data"
    data.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
        cv2.imwrite(str(data / f"frame-{i:06d}.color.png"), rgb)
        cv2.imwrite(str(data / f"frame-{i:06d}.depth.png"), np.full((H, W), 1500, np.uint16))
        np.savetxt(data / f"frame-{i:06d}.pose.txt", np.eye(4))
    np.savetxt(data / "camera-intrinsics.txt", np.array([[100.0, 0, 64], [0, 100.0, 48], [0, 0, 1]]))
    boxes = np.array([[100, 130, 300, 280], [350, 330, 600, 530], [0, 0, 10, 10]], np.float32)
    scores = np.array([[0.9, 0.0], [0.0, 0.7], [0.0, 0.0]], np.float32)
    return {
        "data": data,
        "root": root,
        "enc": make_sam_encoder(root / "enc.onnx"),
        "dec": make_sam_decoder(root / "dec.onnx"),
        "det": make_detector(root / "det.onnx", boxes, scores),
    }


def sam_args(scene, out, *extra):
    return [
        "segment",
        "--data",
        str(scene["data"]),
        "--out",
        str(out),
        "--sam-encoder",
        str(scene["enc"]),
        "--sam-decoder",
        str(scene["dec"]),
        "--points-per-side",
        "2",
        "--set",
        "segmentation.min_region_area=10",
        "--no-progress",
        *extra,
    ]


def test_sam_backend_writes_resumable_segments(scene, tmp_path):
    out = tmp_path / "segs"
    assert main(sam_args(scene, out, "--backend", "sam")) == 0
    stems = [f"frame-{i:06d}.color" for i in range(3)]
    for stem in stems:
        ids, scores = read_segments(out, stem, (H, W))
        assert len(scores) == 4 and all(s == pytest.approx(0.95) for s in scores.values())
        assert json.loads((out / f"{stem}.json").read_text()).keys() == {"scores"}
    # resume: a finished frame is not recomputed, a missing one is
    marker = {"scores": {"1": 0.5}}
    (out / f"{stems[0]}.json").write_text(json.dumps(marker))
    (out / f"{stems[1]}.png").unlink()
    assert main(sam_args(scene, out, "--backend", "sam")) == 0
    assert json.loads((out / f"{stems[0]}.json").read_text()) == marker
    assert len(read_segments(out, stems[1])[1]) == 4
    # --overwrite redoes everything
    assert main(sam_args(scene, out, "--backend", "sam", "--overwrite")) == 0
    assert json.loads((out / f"{stems[0]}.json").read_text()) != marker


def test_sam_detector_backend_keeps_names(scene, tmp_path):
    out = tmp_path / "fused"
    classes = tmp_path / "classes.txt"
    classes.write_text("chair\n\ntable\n")
    args = sam_args(scene, out, "--backend", "sam+detector", "--detector", str(scene["det"]))
    assert main([*args, "--classes", str(classes), "--max-frames", "1"]) == 0
    payload = json.loads((out / "frame-000000.color.json").read_text())
    assert payload["names"] == {"1": "chair", "2": "table"}
    assert len(payload["scores"]) == 4  # two boxes + the two grid discs off the boxes
    assert not (out / "frame-000001.color.png").exists()
    seg = read_segmentation(out, "frame-000000.color", (H, W))  # the reader returns the names too
    assert seg.names == {1: "chair", 2: "table"} and len(seg.scores) == 4


def test_precomputed_names_round_trip(tmp_path):
    ids = np.zeros((4, 5), np.int32)
    ids[0, :2], ids[1, :2], ids[2] = 1, 2, 3
    write_segments(tmp_path, "f", ids, {1: 0.5, 2: 0.7}, {1: "chair", 9: "gone"})
    seg = read_segmentation(tmp_path, "f", (4, 5))
    assert seg.scores == {1: 0.5, 2: 0.7, 3: 1.0}  # missing scores default to 1.0
    assert seg.names == {1: "chair"}  # names of ids absent from the map are dropped
    ids_only, scores = read_segments(tmp_path, "f")
    assert np.array_equal(ids_only, ids) and scores == seg.scores
    write_segments(tmp_path, "g", ids, None, {3: "table"})  # names alone: scores default to 1.0
    assert read_segmentation(tmp_path, "g").names == {3: "table"}
    write_segments(tmp_path, "h", ids)  # no JSON at all
    assert not (tmp_path / "h.json").exists() and read_segmentation(tmp_path, "h").names == {}
    (tmp_path / "f.json").write_text('{"scores": {}, "names": ["chair"]}')
    with pytest.raises(DataError, match="f.json: malformed segments JSON"):
        read_segmentation(tmp_path, "f")


def test_precomputed_scores_must_be_finite_and_ids_fit_uint16(tmp_path):
    ids = np.zeros((4, 5), np.int32)
    ids[0, :2] = 1
    write_segments(tmp_path, "f", ids, {1: 0.9})
    # json.loads reads NaN and Infinity: such a score would become a NaN (or clamped) Gaussian confidence
    for bad in ("NaN", "Infinity", "-Infinity"):
        (tmp_path / "f.json").write_text('{"scores": {"1": ' + bad + "}}")
        with pytest.raises(DataError, match=r"f.json: the scores of segment\(s\) \[1\] are not finite"):
            read_segmentation(tmp_path, "f")
    with pytest.raises(ValueError, match="not finite"):
        write_segments(tmp_path, "g", ids, {1: float("nan")})
    assert not (tmp_path / "g.png").exists() and not (tmp_path / "g.json").exists()
    # more than 65535 segments: a DataError (printed by the CLI without a traceback) naming the file
    big = np.zeros((300, 300), np.int32)
    big.flat[:70000] = np.arange(1, 70001)
    with pytest.raises(DataError, match=r"h.png: segment ids must lie in \[0, 65535\].*\[0, 70000\]"):
        write_segments(tmp_path, "h", big)
    assert not (tmp_path / "h.png").exists()


def _classical(data, out) -> list[str]:
    return ["segment", "--data", str(data), "--out", str(out), "--backend", "classical", "--no-progress"]


def test_classical_backend(scene, tmp_path):
    out = tmp_path / "classical"
    args = _classical(scene["data"], out)
    assert main([*args, "--stride", "2"]) == 0
    ids, scores = read_segments(out, "frame-000002.color", (H, W))
    assert ids.min() >= 1 and all(0.88 <= s <= 1.0 for s in scores.values())
    assert not (out / "frame-000001.color.png").exists()


def test_bad_frames_are_skipped_when_asked(scene, tmp_path, caplog):
    import shutil

    data = tmp_path / "data"
    shutil.copytree(scene["data"], data)
    (data / "frame-000001.depth.png").write_bytes(b"not a png")
    out = tmp_path / "out"
    args = _classical(data, out)
    assert main(args) == 2  # the default: a bad frame is an error
    with caplog.at_level("INFO", logger="ogscene3d.commands.segment"):
        assert main([*args, "--set", "data.on_bad_frame=skip"]) == 0
        assert sorted(p.name for p in out.glob("*.png")) == [
            "frame-000000.color.png",
            "frame-000002.color.png",
        ]
        caplog.clear()
        assert main([*args, "--set", "data.on_bad_frame=skip"]) == 0  # only the bad frame is left to do
    messages = [r.message for r in caplog.records]
    assert any("no frame segmented: the 1 left to do were bad" in m for m in messages)
    assert not any("nothing to do" in m for m in messages)


def test_partial_segments_dir_in_the_config(scene, tmp_path):
    """data.segments_dir (e.g. from a config) naming the folder being filled: frames not segmented yet are
    read without segments (not an error) and segmented; finished ones are left alone."""
    out = tmp_path / "segs"
    args = _classical(scene["data"], out)
    assert main([*args, "--max-frames", "1"]) == 0
    done = (out / "frame-000000.color.png").stat().st_mtime_ns
    assert main([*args, "--set", f"data.segments_dir={out}"]) == 0
    assert sorted(p.name for p in out.glob("*.png")) == [f"frame-{i:06d}.color.png" for i in range(3)]
    assert (out / "frame-000000.color.png").stat().st_mtime_ns == done


def test_cli_errors(scene, tmp_path, capsys):
    base = ["segment", "--data", str(scene["data"]), "--out", str(tmp_path / "x"), "--no-progress"]
    assert main(base) == 2  # the default backend (precomputed) computes nothing
    assert "--backend" in capsys.readouterr().err
    assert main([*base, "--backend", "sam", "--sam-encoder", str(tmp_path / "none.onnx")]) == 2
    assert "sam_decoder" in capsys.readouterr().err
    bad = [*base, "--backend", "sam", "--sam-encoder", str(tmp_path / "none.onnx"), "--sam-decoder", "d.onnx"]
    assert main(bad) == 2
    assert "none.onnx: SAM image encoder ONNX file does not exist" in capsys.readouterr().err
    no_classes = sam_args(scene, tmp_path / "y", "--backend", "sam+detector", "--detector", str(scene["det"]))
    assert main(no_classes) == 2
    assert "detector_classes" in capsys.readouterr().err
    assert main(["segment", "--data", str(tmp_path / "missing"), "--out", "o", "--backend", "classical"]) == 2
    assert main([*base, "--backend", "simulated"]) == 2  # no ground truth in a 7-Scenes folder
    assert "ground-truth instance maps" in capsys.readouterr().err
    # a zero SAM grid: argparse names the option, --set gets a ConfigError naming the setting
    with pytest.raises(SystemExit) as e:
        main(sam_args(scene, tmp_path / "z", "--backend", "sam", "--points-per-side", "0"))  # the last wins
    assert e.value.code == 2 and "--points-per-side: expected an integer >= 1" in capsys.readouterr().err
    zero = [*base, "--backend", "sam", "--sam-encoder", str(scene["enc"]), "--sam-decoder", str(scene["dec"])]
    assert main([*zero, "--set", "segmentation.points_per_side=0"]) == 2
    assert "segmentation.points_per_side must be an integer >= 1, got 0" in capsys.readouterr().err


def test_each_front_end_reads_its_settings_from_the_section(scene):
    sam = {
        "points_per_side": 3,
        "points_per_batch": 5,
        "pred_iou_thresh": 0.5,
        "stability_score_thresh": 0.6,
        "stability_score_offset": 0.7,
        "box_nms_thresh": 0.4,
        "min_region_area": 7,
        "mask_threshold": 0.1,
    }
    det = {"score_thresh": 0.3, "nms_thresh": 0.2, "max_detections": 9}
    classical = {"k": 50.0, "min_size": 11, "max_side": 64, "depth_weight": 2.0, "normal_weight": 3.0}
    cfg = SegmentationConfig(
        sam_encoder=str(scene["enc"]), sam_decoder=str(scene["dec"]), **sam, detector=str(scene["det"]),
        detector_classes=["chair", "table"], tau_m=0.6, **{f"detector_{k}": v for k, v in det.items()},
        **{f"classical_{k}": v for k, v in classical.items()},
    )  # fmt: skip

    def settings(obj, names):
        return {k: getattr(obj, k) for k in names}

    def sam_settings(obj):  # the prompt grid on the segmenter, the mask filters in its MaskFilters
        return {k: getattr(obj if k.startswith("points_") else obj.filters, k) for k in sam}

    assert sam_settings(SamOnnx.from_config(cfg)) == sam
    fused = SamDetectorSegmenter.from_config(cfg)
    assert fused.tau_m == 0.6 and fused.detector.class_names == ["chair", "table"]
    assert settings(fused.detector, det) == det and sam_settings(fused.sam) == sam
    seg = ClassicalSegmenter.from_config(cfg, np.diag([200.0, 210.0, 1.0]))
    assert settings(seg, classical) == classical and (seg.fx, seg.fy) == (200.0, 210.0)


def test_make_segmenter(scene):
    cfg = SegmentationConfig(backend="sam", sam_encoder=str(scene["enc"]), sam_decoder=str(scene["dec"]))
    assert isinstance(make_segmenter(cfg), SamOnnx)
    cfg.backend = "sam+detector"
    cfg.detector = str(scene["det"])
    cfg.detector_classes = ["chair", "table"]
    assert isinstance(make_segmenter(cfg), SamDetectorSegmenter)
    cfg.backend = "classical"
    seg = make_segmenter(cfg, np.array([[200.0, 0, 64], [0, 210.0, 48], [0, 0, 1]]))
    assert isinstance(seg, ClassicalSegmenter) and (seg.fx, seg.fy) == (200.0, 210.0)
    for backend, msg in (("precomputed", "computes none"), ("magic", "unknown")):
        with pytest.raises(ConfigError, match=msg):
            make_segmenter(SegmentationConfig(backend=backend))
    with pytest.raises(ConfigError, match="simulated_noise"):
        make_segmenter(SegmentationConfig(backend="simulated", simulated_noise="extreme"))
    # the hint fits `run` (config / --set) as well as `segment` (its own options)
    with pytest.raises(
        ConfigError, match=r"segmentation\.sam_encoder and segmentation\.sam_decoder \(config or --set"
    ):
        make_segmenter(SegmentationConfig(backend="sam"))
    with pytest.raises(
        ConfigError, match=r"set segmentation\.detector \(config or --set; `ogscene3d segment`"
    ):
        make_segmenter(SegmentationConfig(backend="sam+detector"))
