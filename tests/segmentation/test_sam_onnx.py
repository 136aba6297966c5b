"""SamOnnx against tiny ONNX models with SAM's interface (tests/helpers/onnx_models.py): closed-form
answers."""

from __future__ import annotations

import numpy as np
import pytest
from onnx_models import make_sam_decoder, make_sam_encoder

from ogscene3d.errors import ConfigError, ModelError
from ogscene3d.segmentation.masks import MaskRecord, mask_nms, nms, paint_masks, remove_small_regions
from ogscene3d.segmentation.sam_onnx import MaskFilters, SamOnnx, build_point_grid, stability_score

H, W = 96, 128  # longest side 128 -> x8 to the 1024 model frame (exact in float)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("sam")
    return {
        "enc": make_sam_encoder(d / "enc.onnx"),
        "enc_hwc": make_sam_encoder(d / "enc_hwc.onnx", layout="hwc", dtype="uint8"),
        "enc_nhwc_sym": make_sam_encoder(d / "enc_nhwc.onnx", layout="nhwc", dtype="float", symbolic=True),
        "dec": make_sam_decoder(d / "dec.onnx"),
        "dec_b1": make_sam_decoder(d / "dec_b1.onnx", batch=1),
        "dec_single": make_sam_decoder(d / "dec_single.onnx", radii=(16.0,), slopes=(10.0,), ious=(0.95,)),
        "dec_nolabels": make_sam_decoder(d / "dec_bad.onnx", drop_input="point_labels"),
        # segment-anything 1.0 (PyPI) export: masks cropped at its dummy 1500 x 2250 aspect ratio
        "dec_baked": make_sam_decoder(d / "dec_baked.onnx", baked_crop=(683, 1024)),
        "dec_no_low_res": make_sam_decoder(d / "dec_no_low_res.onnx", low_res_output=False),
        "dir": d,
    }


def disc(cx: float, cy: float, r: float, h: int = H, w: int = W) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    return (xx - cx) ** 2 + (yy - cy) ** 2 < r * r


def expected_discs(r: float, n: int = 2) -> list[np.ndarray]:
    return [disc(x, y, r) for x, y in build_point_grid(n, H, W)]


def assert_segments_are(seg, masks: list[np.ndarray], score: float) -> None:
    assert seg.ids.dtype == np.int32 and seg.ids.shape == (H, W)
    ids = [i for i in np.unique(seg.ids) if i != 0]
    assert len(ids) == len(masks)
    got = sorted((seg.ids == i).tobytes() for i in ids)
    want = sorted(m.tobytes() for m in masks)
    assert got == want
    for i in ids:
        assert seg.scores[int(i)] == pytest.approx(score, abs=1e-6)
    assert seg.names == {}


def test_point_grid_is_cell_centres():
    g = build_point_grid(2, H, W)
    np.testing.assert_allclose(g, [[32, 24], [96, 24], [32, 72], [96, 72]])


def test_grid_masks_match_closed_form(models):
    # outputs: 0 = single-mask token (must be ignored), 1 fails pred IoU, 3 fails stability -> discs r=16
    sam = SamOnnx(models["enc"], models["dec"], points_per_side=2, filters=MaskFilters(min_region_area=10))
    seg = sam(np.full((H, W, 3), 90, np.uint8))
    assert_segments_are(seg, expected_discs(16.0), 0.95)
    sm = seg.score_map()
    assert sm[24, 32] == pytest.approx(0.95) and sm[0, 0] == 0.0


def test_fixed_batch_and_chunking_give_the_same_answer(models):
    rgb = np.zeros((H, W, 3), np.uint8)
    ref = SamOnnx(models["enc"], models["dec"], points_per_side=3, filters=MaskFilters(min_region_area=10))(
        rgb
    )
    b1 = SamOnnx(models["enc"], models["dec_b1"], points_per_side=3, filters=MaskFilters(min_region_area=10))(
        rgb
    )
    odd = SamOnnx(
        models["enc"],
        models["dec"],
        points_per_side=3,
        points_per_batch=4,
        filters=MaskFilters(min_region_area=10),
    )(rgb)
    for other in (b1, odd):
        np.testing.assert_array_equal(other.ids, ref.ids)
        assert other.scores == ref.scores
    assert len(ref.scores) > 0


def test_thresholds_select_outputs(models):
    rgb = np.zeros((H, W, 3), np.uint8)
    # a lower stability threshold admits the r=20 output (IoU 0.97, stability ~0.51), which wins the pixels
    sam = SamOnnx(
        models["enc"],
        models["dec"],
        points_per_side=2,
        filters=MaskFilters(stability_score_thresh=0.4, min_region_area=10),
    )
    assert_segments_are(sam(rgb), expected_discs(20.0), 0.97)
    # a higher IoU threshold leaves only the unstable output -> nothing
    sam = SamOnnx(
        models["enc"],
        models["dec"],
        points_per_side=2,
        filters=MaskFilters(pred_iou_thresh=0.96, min_region_area=10),
    )
    assert not sam(rgb).ids.any()
    # regions smaller than min_region_area are removed (a r=16 disc has ~812 pixels)
    sam = SamOnnx(models["enc"], models["dec"], points_per_side=2, filters=MaskFilters(min_region_area=900))
    assert not sam(rgb).ids.any()


def test_single_output_decoder(models):
    sam = SamOnnx(
        models["enc"], models["dec_single"], points_per_side=2, filters=MaskFilters(min_region_area=10)
    )
    assert_segments_are(sam(np.zeros((H, W, 3), np.uint8)), expected_discs(16.0), 0.95)


def test_decoder_with_baked_aspect_ratio(models):
    # segment-anything 1.0's export freezes the crop of its masks output at the dummy orig_im_size's aspect
    # ratio (fixed in segment-anything PR #58, after the PyPI release; samexporter's inference works around
    # it the same way): masks come from low_res_masks, postprocessed here, so a 3:4 frame still fits
    sam = SamOnnx(
        models["enc"], models["dec_baked"], points_per_side=2, filters=MaskFilters(min_region_area=10)
    )
    assert_segments_are(sam(np.full((H, W, 3), 90, np.uint8)), expected_discs(16.0), 0.95)
    image = sam.embed(np.zeros((H, W, 3), np.uint8))
    recs = sam.segment_boxes(image, np.array([[20, 10, 60, 40]]), ["chair"])
    assert [r.box for r in recs] == [(20, 10, 60, 40)] and recs[0].crop.all()
    logits, ious = sam.predict(image, np.array([[[32.0, 24.0], [0.0, 0.0]]]), np.array([[1.0, -1.0]]))
    assert logits.shape == (1, 4, H, W) and ious.shape == (1, 4)
    np.testing.assert_array_equal(logits[0, 2] > 0, disc(32, 24, 16.0))


def test_decoder_without_low_res_output_uses_masks(models):
    sam = SamOnnx(
        models["enc"], models["dec_no_low_res"], points_per_side=2, filters=MaskFilters(min_region_area=10)
    )
    assert_segments_are(sam(np.full((H, W, 3), 90, np.uint8)), expected_discs(16.0), 0.95)


def test_box_prompts_give_box_masks_with_names(models):
    sam = SamOnnx(models["enc"], models["dec"], filters=MaskFilters(min_region_area=10))
    image = sam.embed(np.zeros((H, W, 3), np.uint8))
    recs = sam.segment_boxes(image, np.array([[20, 10, 60, 40], [70, 50, 120, 90]]), ["chair", "table"])
    assert [r.name for r in recs] == ["chair", "table"]
    assert [r.box for r in recs] == [(20, 10, 60, 40), (70, 50, 120, 90)]
    assert all(r.crop.all() for r in recs)
    assert all(r.score == pytest.approx(0.96) for r in recs)
    assert sam.segment_boxes(image, np.zeros((0, 4))) == []


def test_non_finite_predicted_ious_are_dropped(models, caplog):
    # a decoder that gives NaN / inf predicted IoUs (e.g. an fp16 export overflowing): such a mask must not
    # carry its NaN into the segment's score (-> a NaN Gaussian confidence) nor win pixels with inf
    d = models["dir"]
    rgb = np.zeros((H, W, 3), np.uint8)
    nan_box = make_sam_decoder(d / "dec_nan_box.onnx", box_iou=float("nan"))
    sam = SamOnnx(models["enc"], nan_box, filters=MaskFilters(min_region_area=10))
    image = sam.embed(rgb)
    with caplog.at_level("WARNING"):
        assert sam.segment_boxes(image, np.array([[20, 10, 60, 40]]), ["chair"]) == []
    assert "non-finite predicted IoU" in caplog.text
    # grid prompts: the inf output (r=10) and the NaN one (r=16) fail the predicted-IoU filter, so the
    # r=20 output (IoU 0.97) is left, with a stability threshold that admits it
    bad_pts = make_sam_decoder(d / "dec_inf_pts.onnx", ious=(0.99, float("inf"), float("nan"), 0.97))
    sam = SamOnnx(
        models["enc"],
        bad_pts,
        points_per_side=2,
        filters=MaskFilters(stability_score_thresh=0.4, min_region_area=10),
    )
    assert_segments_are(sam(rgb), expected_discs(20.0), 0.97)
    # a single-output-per-token decoder without the 4-token layout picks the best finite output
    two = make_sam_decoder(
        d / "dec_two.onnx", radii=(16.0, 20.0), slopes=(10.0, 10.0), ious=(0.9, 0.9), box_iou=float("nan")
    )
    sam = SamOnnx(models["enc"], two, filters=MaskFilters(min_region_area=10))
    assert sam.segment_boxes(sam.embed(rgb), np.array([[20, 10, 60, 40]]), ["chair"]) == []


def test_encoder_preprocessing_nchw(models):
    sam = SamOnnx(models["enc"], models["dec"])
    rgb = np.full((H, W, 3), [200, 100, 50], np.uint8)
    x, resized = sam.preprocess(rgb)
    assert x.shape == (1, 3, 1024, 1024) and x.dtype == np.float32 and resized == (768, 1024)
    want = (np.array([200, 100, 50], np.float32) - [123.675, 116.28, 103.53]) / [58.395, 57.12, 57.375]
    np.testing.assert_allclose(x[0, :, 0, 0], want, rtol=1e-5)
    assert not x[0, :, 768:].any()  # zero padding below the resized image
    emb = sam.embed(rgb).embeddings
    assert emb.shape == (1, 256, 64, 64)
    np.testing.assert_allclose(emb[0, :3, 10, 10], want, rtol=1e-4)
    assert not emb[0, :, 48:].any()


@pytest.mark.parametrize("key", ["enc_hwc", "enc_nhwc_sym"])
def test_encoder_preprocessing_hwc_variants(models, key):
    sam = SamOnnx(models[key], models["dec"], points_per_side=2, filters=MaskFilters(min_region_area=10))
    rgb = np.full((H, W, 3), [200, 100, 50], np.uint8)
    x, resized = sam.preprocess(rgb)
    assert resized == (768, 1024)
    # fixed 1024x1024 input: we pad; symbolic H x W (the graph pads): the resized image as is
    assert x.dtype == np.uint8 and x.shape[-3:] == (
        (768, 1024, 3) if key == "enc_nhwc_sym" else (1024, 1024, 3)
    )
    emb = sam.embed(rgb).embeddings
    np.testing.assert_allclose(emb[0, :3, 5, 5], [200, 100, 50], rtol=1e-5)  # raw pixels, no normalisation
    assert not emb[0, :, 48:].any()
    assert_segments_are(sam(rgb), expected_discs(16.0), 0.95)


def test_missing_and_wrong_model_files(models):
    d = models["dir"]
    with pytest.raises(ModelError, match="enc_missing.onnx.*does not exist"):
        SamOnnx(d / "enc_missing.onnx", models["dec"])
    bad = d / "garbage.onnx"
    bad.write_bytes(b"this is not a protobuf")
    with pytest.raises(ModelError, match="garbage.onnx.*cannot load"):
        SamOnnx(models["enc"], bad)
    with pytest.raises(ModelError) as e:
        SamOnnx(models["enc"], models["dec_nolabels"])
    msg = str(e.value)
    assert "dec_bad.onnx" in msg and "point_labels" in msg and "found inputs" in msg and "point_coords" in msg
    # an encoder whose embeddings do not fit the decoder (e.g. files of two different SAM variants)
    small = make_sam_encoder(d / "enc32.onnx", emb_size=32)
    with pytest.raises(ModelError, match=r"image_embeddings input \[1, 256, 64, 64\] does not match"):
        SamOnnx(small, models["dec"])
    # an encoder passed as decoder: wrong interface, named as such
    with pytest.raises(ModelError, match="missing input"):
        SamOnnx(models["enc"], models["enc"])
    with pytest.raises(ConfigError):
        SamOnnx(None, models["dec"])  # type: ignore[arg-type]


def test_bad_rgb_is_rejected(models):
    sam = SamOnnx(models["enc"], models["dec"])
    with pytest.raises(ValueError, match="uint8"):
        sam(np.zeros((H, W, 3), np.float32))
    with pytest.raises(ValueError, match="uint8"):
        sam(np.zeros((H, W), np.uint8))


# ---------------------------------------------------------------------------- mask helpers


def test_stability_score():
    logits = np.stack([np.array([[3.0, 0.5, -0.5, -3.0]]), np.array([[-3.0, -3.0, -3.0, -3.0]])])
    np.testing.assert_allclose(stability_score(logits, 0.0, 1.0), [1 / 3, 0.0])


def test_remove_small_regions_fills_holes_and_drops_islands():
    m = np.zeros((20, 30), bool)
    m[2:12, 2:12] = True
    m[5:7, 5:7] = False  # 4-pixel hole
    m[15:17, 25:27] = True  # 4-pixel island
    rec = MaskRecord((0, 0, 30, 20), m, 0.9)
    out, changed = remove_small_regions(rec, 10)
    assert changed and out.box == (2, 2, 12, 12) and out.crop.all()
    # background touching the crop border is not a hole, however small
    m2 = np.ones((6, 6), bool)
    m2[0, 2] = False
    out2, changed2 = remove_small_regions(MaskRecord((0, 0, 6, 6), m2, 0.9), 10)
    assert not changed2 and out2.crop.sum() == 35
    # every island small: the largest survives (segment-anything's rule)
    m3 = np.zeros((10, 10), bool)
    m3[0:2, 0:2] = True
    m3[5:8, 5:8] = True
    out3, changed3 = remove_small_regions(MaskRecord((0, 0, 10, 10), m3, 0.9), 50)
    assert changed3 and out3.box == (5, 5, 8, 8) and out3.area == 9


def test_nms_greedy_and_classwise():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [20, 20, 30, 30]], float)
    scores = np.array([0.8, 0.9, 0.5])
    np.testing.assert_array_equal(nms(boxes, scores, 0.5), [1, 2])
    np.testing.assert_array_equal(nms(boxes, scores, 0.5, classes=np.array([0, 1, 0])), [1, 0, 2])
    recs = [MaskRecord(tuple(int(v) for v in b), np.ones((10, 10), bool), s) for b, s in zip(boxes, scores)]
    assert [r.score for r in mask_nms(recs, 0.5)] == [0.9, 0.5]


def test_paint_masks_higher_score_wins_and_drops_hidden():
    a = MaskRecord((0, 0, 10, 10), np.ones((10, 10), bool), 0.90, name="a")
    b = MaskRecord((5, 0, 15, 10), np.ones((10, 10), bool), 0.95)
    hidden = MaskRecord((6, 2, 8, 4), np.ones((2, 2), bool), 0.91)
    seg = paint_masks([a, b, hidden], (10, 20), min_area=1)
    assert seg.ids[0, 4] == 1 and seg.ids[0, 5] == 2 and seg.ids[0, 16] == 0
    assert seg.scores == {1: 0.90, 2: 0.95} and seg.names == {1: "a"}
    # ties: the mask listed first wins
    tie = paint_masks([b, MaskRecord((0, 0, 10, 10), np.ones((10, 10), bool), 0.95)], (10, 20))
    assert tie.ids[0, 7] == 1


def test_execution_provider_choice(caplog):
    import onnxruntime as ort

    from ogscene3d.segmentation.onnx_session import choose_providers

    assert choose_providers("cpu") == ["CPUExecutionProvider"]
    has_cuda = "CUDAExecutionProvider" in ort.get_available_providers()
    with caplog.at_level("WARNING"):
        got = choose_providers("cuda")
    if has_cuda:
        assert got[0] == "CUDAExecutionProvider"
    else:  # asked for CUDA without it: CPU, with a logged note
        assert got == ["CPUExecutionProvider"] and "CUDA execution provider requested" in caplog.text
    with pytest.raises(ConfigError, match="execution_provider"):
        choose_providers("tpu")


def test_front_ends_implement_the_segmenter_protocol(models):
    from ogscene3d.segmentation.base import Segmenter

    assert isinstance(SamOnnx(models["enc"], models["dec"]), Segmenter)
