"""Label palette, side-by-side panels and the IoU bar chart (OpenCV only)."""

import cv2
import numpy as np
import pytest

from ogscene3d.eval.metrics import segmentation_metrics
from ogscene3d.eval.plots import (
    colorize_confidence,
    colorize_labels,
    iou_bar_chart,
    label_colors,
    side_by_side,
    write_iou_chart,
    write_png,
)


def test_palette_is_stable_and_distinct():
    a = label_colors(np.arange(-1, 40))
    b = label_colors(np.arange(-1, 40)[::-1])[::-1]
    np.testing.assert_array_equal(a, b)  # a colour depends only on the label value
    assert a[0].tolist() == [0, 0, 0]  # -1 is black
    assert len({tuple(c) for c in a[1:]}) == 40
    lab = np.array([[3, 3], [-1, 7]])
    img = colorize_labels(lab)
    assert img.shape == (2, 2, 3) and img.dtype == np.uint8
    np.testing.assert_array_equal(img[0, 0], label_colors([3])[0])


def test_confidence_colormap_marks_missing_values_black():
    c = np.array([[0.0, 1.0], [np.nan, -1.0]])
    img = colorize_confidence(c)
    assert img[1, 0].tolist() == [0, 0, 0] and img[1, 1].tolist() == [0, 0, 0]
    assert not np.array_equal(img[0, 0], img[0, 1])


def test_side_by_side_layout(tmp_path):
    h, w = 24, 32
    rgb = np.full((h, w, 3), 128, np.uint8)
    lab = np.zeros((h, w), np.int64)
    out = side_by_side(rgb, lab, lab + 1, np.random.default_rng(0).random((h, w)))
    assert out.shape == (h + 22, 4 * w + 3 * 4, 3)
    # the rendered-label panel shows label 0's colour below the title strip
    np.testing.assert_array_equal(out[22 + h // 2, w + 4 + w // 2], label_colors([0])[0])
    assert side_by_side(rgb, lab, lab).shape == (h + 22, 3 * w + 2 * 4, 3)
    with pytest.raises(ValueError, match="expected"):
        side_by_side(rgb, lab[:5], lab)
    path = write_png(tmp_path / "p.png", out)
    back = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(back, out)


def test_bar_lengths_follow_iou():
    img = iou_bar_chart(["a", "b", "c"], [0.25, float("nan"), 1.0], width=600)
    colors = label_colors([0, 1, 2])

    def bar_pixels(i):
        return int(np.all(img == colors[i], axis=2).sum())

    assert bar_pixels(1) == 0  # NaN draws no bar
    assert bar_pixels(2) == pytest.approx(4 * bar_pixels(0), rel=0.05)
    with pytest.raises(ValueError, match="3 class names"):
        iou_bar_chart(["a", "b", "c"], [0.1])


def test_the_iou_chart_of_a_protocol_is_written_beside_the_run(tmp_path):
    confusion = np.array([[3, 1, 0], [0, 2, 0], [0, 0, 0]])  # wall: ignored; a class with no points: n/a
    m = segmentation_metrics(confusion, ["chair", "table", "wall"], ignore=["wall"])
    path = write_iou_chart(tmp_path, "hovsg", m)
    assert path == tmp_path / "iou_hovsg.png"
    img = cv2.imread(str(path))
    assert img is not None and img.shape[1] == 720
