"""DetectorOnnx on tiny detector exports in the common output layouts (tests/helpers/onnx_models.py)."""

from __future__ import annotations

import numpy as np
import pytest
from onnx_models import make_detector, make_sam_decoder

from ogscene3d.errors import ConfigError, ModelError
from ogscene3d.segmentation.detector_onnx import DetectorOnnx

H, W = 96, 128  # letterboxed to 640: ratio 5, 640x480 placed at top = 80, left = 0
CLASSES = ["chair", "table"]

# boxes in the 640x640 letterboxed input frame, class scores [chair, table]
BOXES = np.array(
    [
        [100, 130, 300, 280],  # A chair 0.9 -> [20, 10, 60, 40] in the image
        [105, 130, 300, 285],  # B chair 0.8, duplicate of A (suppressed by NMS)
        [350, 330, 600, 530],  # C table 0.7 -> [70, 50, 120, 90]
        [0, 0, 50, 50],  # D table 0.1, below the score threshold
        [102, 131, 300, 281],  # E table 0.6 overlapping A: another class, kept by class-wise NMS
        [600, 500, 700, 600],  # F chair 0.5, beyond the image: clipped to [120, 84, 128, 96]
        [10, 10, 20, 20],  # G, H: empty anchors (a real head has thousands; also makes A != 4 + K)
        [30, 30, 40, 40],
    ],
    np.float32,
)
SCORES = np.array(
    [[0.9, 0.05], [0.8, 0.1], [0.1, 0.7], [0.05, 0.1], [0.2, 0.6], [0.5, 0.0], [0.0, 0.0], [0.0, 0.0]],
    np.float32,
)
IMAGE_BOXES = {
    "A": [20, 10, 60, 40],
    "B": [21, 10, 60, 41],
    "C": [70, 50, 120, 90],
    "E": [20.4, 10.2, 60, 40.2],
    "F": [120, 84, 128, 96],
}


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    return tmp_path_factory.mktemp("det")


def check(dets, keys: str, scores: list[float], names: list[str]) -> None:
    np.testing.assert_allclose(dets.boxes, [IMAGE_BOXES[k] for k in keys], atol=1e-4)
    np.testing.assert_allclose(dets.scores, scores, atol=1e-6)
    assert dets.names == names
    assert [CLASSES[i] for i in dets.labels] == names


@pytest.mark.parametrize("layout,transposed", [("yolo_head", False), ("yolo_head", True), ("dense", False)])
def test_raw_layouts_are_thresholded_and_nms_filtered(tmp, layout, transposed):
    path = make_detector(
        tmp / f"{layout}{transposed}.onnx", BOXES, SCORES, layout, head_transposed=transposed
    )
    det = DetectorOnnx(path, CLASSES)
    dets = det(np.zeros((H, W, 3), np.uint8))
    check(dets, "ACEF", [0.9, 0.7, 0.6, 0.5], ["chair", "table", "table", "chair"])
    assert len(DetectorOnnx(path, CLASSES, max_detections=2)(np.zeros((H, W, 3), np.uint8))) == 2


def test_nms_layout_is_taken_as_is(tmp):
    path = make_detector(tmp / "nms.onnx", BOXES, SCORES, "nms")
    dets = DetectorOnnx(path, CLASSES)(np.zeros((H, W, 3), np.uint8))
    check(dets, "ABCEF", [0.9, 0.8, 0.7, 0.6, 0.5], ["chair", "chair", "table", "table", "chair"])


def test_ultralytics_nms_export(tmp):
    # export(format="onnx", nms=True): output0 [1, 300, 6] of x0, y0, x1, y1, score, class rows, told from a
    # transposed head [1, A, 4 + K] (same shape with K = 2) by the metadata Ultralytics writes
    nms_boxes, nms_scores = BOXES[[0, 2, 4, 5, 3]], SCORES[[0, 2, 4, 5, 3]]  # NMS done, best first
    path = make_detector(tmp / "ultra_nms.onnx", nms_boxes, nms_scores, "ultralytics_nms")
    dets = DetectorOnnx(path, CLASSES)(np.zeros((H, W, 3), np.uint8))
    check(dets, "ACEF", [0.9, 0.7, 0.6, 0.5], ["chair", "table", "table", "chair"])
    # no axis tells K here: the class names Ultralytics writes into the metadata do
    with pytest.raises(ModelError, match="2 classes .*class0.*class1.* but 3 class names"):
        DetectorOnnx(path, CLASSES + ["lamp"])


def test_letterbox_preprocessing(tmp):
    path = make_detector(tmp / "pre.onnx", BOXES, SCORES)
    det = DetectorOnnx(path, CLASSES)
    x, r, (left, top) = det.preprocess(np.full((H, W, 3), 255, np.uint8))
    assert x.shape == (1, 3, 640, 640) and r == 5.0 and (left, top) == (0, 80)
    assert np.all(x[0, :, 80:560] == 1.0) and np.allclose(x[0, :, :80], 114 / 255)


def test_wrong_vocabulary_and_models(tmp):
    path = make_detector(tmp / "k.onnx", BOXES, SCORES)
    with pytest.raises(ModelError, match="no axis of size 4 \\+ 3"):
        DetectorOnnx(path, ["a", "b", "c"])(np.zeros((H, W, 3), np.uint8))
    dense = make_detector(tmp / "kd.onnx", BOXES, SCORES, "dense")
    with pytest.raises(ModelError, match="2 classes but 3 class names"):
        DetectorOnnx(dense, ["a", "b", "c"])(np.zeros((H, W, 3), np.uint8))
    nms_path = make_detector(tmp / "kn.onnx", BOXES, SCORES, "nms")
    with pytest.raises(ModelError, match="class index 1 returned but only 1 class"):
        DetectorOnnx(nms_path, ["a"])(np.zeros((H, W, 3), np.uint8))
    with pytest.raises(ConfigError, match="detector_classes"):
        DetectorOnnx(path, [])
    with pytest.raises(ModelError, match="6 inputs"):
        DetectorOnnx(make_sam_decoder(tmp / "dec.onnx"), CLASSES)
    with pytest.raises(ModelError, match="does not exist"):
        DetectorOnnx(tmp / "nope.onnx", CLASSES)
