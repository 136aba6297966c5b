"""Fusion M_f of grid (M_s) and detector (M_d) segments, paper Sec. III-B.1, with hand-checkable maps."""

from __future__ import annotations

import numpy as np
import pytest
from onnx_models import make_detector, make_sam_decoder, make_sam_encoder

from ogscene3d.segmentation.base import Segmentation
from ogscene3d.segmentation.detector_onnx import DetectorOnnx
from ogscene3d.segmentation.fusion import SamDetectorSegmenter, fuse_segmentations, overlap_ratios
from ogscene3d.segmentation.sam_onnx import MaskFilters, SamOnnx


def hand_made() -> tuple[Segmentation, Segmentation]:
    """M_d: d=3 'cup' on columns 0..9 and d=5 'bowl' on columns 20..29 (rows 0..9 of a 10x40 map).

    M_s: s=1 inside d3 (ratio 1), s=2 half over d3 (0.5), s=4 exactly 70% over d5 (0.7 -> dropped),
    s=6 in free space (0), s=7 over both d3 and d5, 40% each (ratio 0.4: kept, only its free 20% shows).
    """
    md = np.zeros((10, 40), np.int32)
    md[:, 0:10] = 3
    md[:, 20:30] = 5
    ms = np.zeros((10, 40), np.int32)
    ms[0:2, 0:10] = 1  # 20 px in d3
    ms[2:4, 5:15] = 2  # 10 in d3, 10 free
    ms[4:5, 20:30] = 4  # 10 px, 7 of them in d5 after the next line
    ms[4:5, 27:30] = 0
    ms[4:5, 30:33] = 4
    ms[6:7, 32:40] = 6  # 8 px free
    ms[8:9, 6:10] = 7  # 4 in d3
    ms[8:9, 10:12] = 7  # 2 free
    ms[8:9, 20:24] = 7  # 4 in d5
    return (
        Segmentation(ms, {1: 0.90, 2: 0.91, 4: 0.92, 6: 0.93, 7: 0.94}),
        Segmentation(md, {3: 0.97, 5: 0.98}, {3: "cup", 5: "bowl"}),
    )


def test_overlap_ratios():
    ms, md = hand_made()
    r = overlap_ratios(ms, md)
    assert r == pytest.approx({1: 1.0, 2: 0.5, 4: 0.7, 6: 0.0, 7: 0.4})


def test_fusion_keeps_md_and_low_overlap_ms():
    ms, md = hand_made()
    mf = fuse_segmentations(ms, md, tau_m=0.7)
    # M_d first (3 -> 1, 5 -> 2), then the kept M_s segments 2, 6, 7 in id order -> 3, 4, 5
    assert mf.scores == {1: 0.97, 2: 0.98, 3: 0.91, 4: 0.93, 5: 0.94}
    assert mf.names == {1: "cup", 2: "bowl"}
    want = np.zeros((10, 40), np.int32)
    want[:, 0:10] = 1
    want[:, 20:30] = 2
    want[2:4, 10:15] = 3
    want[6:7, 32:40] = 4
    want[8:9, 10:12] = 5
    np.testing.assert_array_equal(mf.ids, want)
    sm = mf.score_map()
    assert sm[0, 0] == pytest.approx(0.97) and sm[3, 12] == pytest.approx(0.91) and sm[5, 35] == 0.0
    # a looser threshold also admits s=4 (ratio 0.7); tau 0 keeps only the segments free of M_d
    assert len(fuse_segmentations(ms, md, tau_m=0.71).scores) == 6
    assert len(fuse_segmentations(ms, md, tau_m=0.0).scores) == 2
    # min_area drops kept M_s segments that M_d leaves nearly invisible (s=7 shows 2 px)
    assert len(fuse_segmentations(ms, md, tau_m=0.7, min_area=3).scores) == 4


def test_fusion_edge_cases():
    ms, md = hand_made()
    empty = Segmentation(np.zeros_like(ms.ids))
    only_s = fuse_segmentations(ms, empty)
    assert len(only_s.scores) == 5 and only_s.names == {}
    only_d = fuse_segmentations(empty, md)
    assert only_d.names == {1: "cup", 2: "bowl"}
    with pytest.raises(ValueError, match="shape"):
        fuse_segmentations(ms, Segmentation(np.zeros((3, 3), np.int32)))
    with pytest.raises(ValueError, match="tau_m"):
        fuse_segmentations(ms, md, tau_m=1.5)


def test_sparse_large_ids_and_negative_ids():
    # ids are per-frame labels, not counts: maps numbered up to 65535 (precomputed PNGs) must fuse without
    # a histogram over max id x max id (that took 24 GB here); the answer is that of the renumbered maps
    ms, md = hand_made()
    big_s = np.array([0, 60001, 60002, 0, 65535, 0, 40000, 50000], np.int32)
    big_d = np.array([0, 0, 0, 65000, 0, 64000], np.int32)
    ms_big = Segmentation(big_s[ms.ids], {int(big_s[k]): v for k, v in ms.scores.items()})
    md_big = Segmentation(
        big_d[md.ids], {int(big_d[k]): v for k, v in md.scores.items()}, {65000: "cup", 64000: "bowl"}
    )
    import tracemalloc

    tracemalloc.start()
    try:
        r = overlap_ratios(ms_big, md_big)
        mf = fuse_segmentations(ms_big, md_big)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50e6
    assert r == pytest.approx({60001: 1.0, 60002: 0.5, 65535: 0.7, 40000: 0.0, 50000: 0.4})
    ref = fuse_segmentations(ms, md)
    # ids are taken in id order: 64000 ("bowl") now comes before 65000 ("cup"), and the kept M_s segments
    # come as 40000 (s=6), 50000 (s=7), 60002 (s=2)
    assert mf.names == {1: "bowl", 2: "cup"} and len(mf.scores) == len(ref.scores) == 5
    swap = np.array([0, 2, 1, 4, 5, 3], np.int32)
    assert {int(swap[k]): v for k, v in mf.scores.items()} == ref.scores
    np.testing.assert_array_equal(swap[mf.ids], ref.ids)
    # negative ids are "no segment" (Segmentation's docstring): score 0, not the last id's score
    seg = Segmentation(np.array([[-1, 0, 1, 2]], np.int32), {1: 0.9, 2: 0.95})
    np.testing.assert_allclose(seg.score_map(), [[0.0, 0.0, 0.9, 0.95]])


def test_sam_plus_detector_end_to_end(tmp_path):
    h, w = 96, 128
    enc = make_sam_encoder(tmp_path / "enc.onnx")
    dec = make_sam_decoder(tmp_path / "dec.onnx")
    # letterbox ratio 5, top pad 80: chair -> [20, 10, 60, 40], table -> [70, 50, 120, 90]
    boxes = np.array([[100, 130, 300, 280], [350, 330, 600, 530], [0, 0, 50, 50]], np.float32)
    scores = np.array([[0.9, 0.0], [0.0, 0.7], [0.1, 0.1]], np.float32)
    det = make_detector(tmp_path / "det.onnx", boxes, scores)
    seg = SamDetectorSegmenter(
        SamOnnx(enc, dec, points_per_side=2, filters=MaskFilters(min_region_area=10)),
        DetectorOnnx(det, ["chair", "table"]),
        tau_m=0.7,
    )
    res = seg.segment(np.zeros((h, w, 3), np.uint8))
    assert res.detections.names == ["chair", "table"]
    assert len(res.ms.scores) == 4 and res.md.names == {1: "chair", 2: "table"}
    # grid discs (r=16) at (32,24) [~90% inside the chair box] and (96,72) [inside the table box] are
    # dropped; those at (96,24) and (32,72) are kept
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    want = np.zeros((h, w), np.int32)
    want[10:40, 20:60] = 1
    want[50:90, 70:120] = 2
    want[((xx - 96) ** 2 + (yy - 24) ** 2 < 256) & (want == 0)] = 3
    want[((xx - 32) ** 2 + (yy - 72) ** 2 < 256) & (want == 0)] = 4
    np.testing.assert_array_equal(res.mf.ids, want)
    assert res.mf.names == {1: "chair", 2: "table"}
    assert res.mf.scores == pytest.approx({1: 0.96, 2: 0.96, 3: 0.95, 4: 0.95})
    np.testing.assert_array_equal(seg(np.zeros((h, w, 3), np.uint8)).ids, want)


def test_no_detections_gives_the_grid_segments(tmp_path):
    enc = make_sam_encoder(tmp_path / "enc.onnx")
    dec = make_sam_decoder(tmp_path / "dec.onnx")
    det = make_detector(
        tmp_path / "det.onnx", np.array([[0, 0, 50, 50]], np.float32), np.array([[0.1]], np.float32)
    )
    sam = SamOnnx(enc, dec, points_per_side=2, filters=MaskFilters(min_region_area=10))
    res = SamDetectorSegmenter(sam, DetectorOnnx(det, ["cup"])).segment(np.zeros((96, 128, 3), np.uint8))
    assert len(res.detections) == 0 and not res.md.ids.any()
    np.testing.assert_array_equal(res.mf.ids, res.ms.ids)
    assert res.mf.scores == res.ms.scores and res.mf.names == {}
