"""Pictures for people: label colourings, RGB | labels | GT | confidence panels, per-class IoU bars.

Everything is drawn with OpenCV into uint8 RGB arrays (H x W x 3); :func:`write_png` stores them.
Label colours are a fixed function of the label value (a hash to hue/saturation/value), so the same
label has the same colour in every picture, run and process; -1 (unlabeled / void) is black.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from ..atomic import atomic_write_bytes
from ..colors import label_colors as _palette

if TYPE_CHECKING:
    from .metrics import SegmentationMetrics

_FONT = cv2.FONT_HERSHEY_SIMPLEX


def label_colors(labels: Any) -> np.ndarray:
    """Stable RGB per label, as in the viewer: [N] ints -> [N, 3] uint8 (label < 0 -> black)."""
    lab = np.asarray(labels, dtype=np.int64).reshape(-1)
    rgb = np.round(_palette(lab) * 255).astype(np.uint8)
    rgb[lab < 0] = 0
    return rgb


def colorize_labels(label_map: Any) -> np.ndarray:
    """[H, W] int label map (numpy or torch) -> [H, W, 3] uint8 RGB with :func:`label_colors`."""
    lab = _to_numpy(label_map)
    if lab.ndim != 2 or not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"label_map: expected an [H, W] integer array, got {lab.shape} {lab.dtype}")
    uniq, inv = np.unique(lab, return_inverse=True)
    return label_colors(uniq)[inv.reshape(lab.shape)]


def colorize_confidence(conf: Any) -> np.ndarray:
    """[H, W] float confidence in [0, 1] -> viridis RGB; NaN or < 0 (no value) is black."""
    c = _to_numpy(conf).astype(np.float64)
    if c.ndim != 2:
        raise ValueError(f"confidence: expected an [H, W] array, got shape {c.shape}")
    bad = ~np.isfinite(c) | (c < 0)
    u8 = (np.clip(np.nan_to_num(c, nan=0.0), 0.0, 1.0) * 255).round().astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(u8, cv2.COLORMAP_VIRIDIS), cv2.COLOR_BGR2RGB)
    rgb[bad] = 0
    return rgb


def _to_numpy(x: Any) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def _title_strip(width: int, text: str, height: int = 22) -> np.ndarray:
    strip = np.full((height, width, 3), 255, dtype=np.uint8)
    scale = 0.45
    (tw, _), _ = cv2.getTextSize(text, _FONT, scale, 1)
    while tw > width - 4 and scale > 0.25:
        scale -= 0.05
        (tw, _), _ = cv2.getTextSize(text, _FONT, scale, 1)
    cv2.putText(strip, text, (max(2, (width - tw) // 2), height - 7), _FONT, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return strip


def side_by_side(
    rgb: Any,
    rendered_labels: Any,
    gt_labels: Any,
    confidence: Any | None = None,
    titles: Sequence[str] = ("RGB", "rendered labels", "ground truth", "confidence"),
    gap: int = 4,
) -> np.ndarray:
    """One row of panels: RGB | rendered labels | GT labels | confidence, each with a title.

    Args:
        rgb: [H, W, 3] uint8 (or float in [0, 1]) image.
        rendered_labels: [H, W] int labels; map scene labels to GT classes first
            (``protocols.label_lookup``) so that equal classes share a colour with ``gt_labels``.
        gt_labels: [H, W] int GT classes, -1 = void.
        confidence: [H, W] float in [0, 1] (e.g. ``render_semantics(...).weights``) or None to omit.

    Returns:
        [H + 22, n * W + (n - 1) * gap, 3] uint8 RGB.
    """
    img = _to_numpy(rgb)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"rgb: expected [H, W, 3], got shape {img.shape}")
    if img.dtype != np.uint8:
        img = (np.clip(img.astype(np.float64), 0.0, 1.0) * 255).round().astype(np.uint8)
    h, w = img.shape[:2]
    panels = [img, colorize_labels(rendered_labels), colorize_labels(gt_labels)]
    if confidence is not None:
        panels.append(colorize_confidence(confidence))
    for i, p in enumerate(panels):
        if p.shape[:2] != (h, w):
            raise ValueError(f"panel {titles[i]!r} is {p.shape[:2]}, expected {(h, w)} like the RGB image")
    cols = []
    for i, p in enumerate(panels):
        cols.append(np.concatenate([_title_strip(w, titles[i] if i < len(titles) else ""), p], axis=0))
        if i + 1 < len(panels):
            cols.append(np.full((h + 22, gap, 3), 255, dtype=np.uint8))
    return np.concatenate(cols, axis=1)


def iou_bar_chart(
    class_names: Sequence[str],
    ious: Sequence[float] | np.ndarray,
    title: str = "per-class IoU",
    width: int = 720,
    row_height: int = 20,
    class_ids: Sequence[int] | None = None,
    nan_text: Sequence[str] | None = None,
) -> np.ndarray:
    """Horizontal bar chart of per-class IoU in [0, 1] (NaN = not evaluated, no bar).

    Bars use :func:`label_colors` of the class index (or ``class_ids``), matching the label pictures.
    ``nan_text`` gives per class the text shown instead of a value for NaN (default "n/a").
    Returns a uint8 RGB image.
    """
    names = [str(n) for n in class_names]
    vals = np.asarray(ious, dtype=np.float64).reshape(-1)
    if vals.shape[0] != len(names):
        raise ValueError(f"{len(names)} class names but {vals.shape[0]} IoU values")
    if nan_text is not None and len(nan_text) != len(names):
        raise ValueError(f"{len(names)} class names but {len(nan_text)} nan_text entries")
    ids = np.arange(len(names)) if class_ids is None else np.asarray(class_ids, dtype=np.int64)
    colors = label_colors(ids)
    scale = 0.42
    name_w = max([cv2.getTextSize(n, _FONT, scale, 1)[0][0] for n in names] + [40]) + 10
    name_w = min(name_w, width // 2)
    value_w = 80
    bar_w = max(50, width - name_w - value_w - 10)
    top = 34
    height = top + row_height * max(1, len(names)) + 26
    img = np.full((height, width, 3), 255, dtype=np.uint8)
    cv2.putText(img, title, (8, 22), _FONT, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    x0 = name_w
    for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
        x = x0 + int(round(frac * bar_w))
        cv2.line(img, (x, top - 4), (x, height - 22), (225, 225, 225), 1)
        label = f"{int(frac * 100)}"
        cv2.putText(img, label, (x - 8, height - 8), _FONT, 0.38, (90, 90, 90), 1, cv2.LINE_AA)
    for i, (n, v) in enumerate(zip(names, vals)):
        y = top + i * row_height
        (tw, _), _ = cv2.getTextSize(n, _FONT, scale, 1)
        cv2.putText(
            img, n, (max(2, x0 - 6 - tw), y + row_height - 6), _FONT, scale, (0, 0, 0), 1, cv2.LINE_AA
        )
        if math.isnan(v):
            text = nan_text[i] if nan_text is not None else "n/a"
        else:
            bw = int(round(np.clip(v, 0.0, 1.0) * bar_w))
            if bw > 0:
                c = tuple(int(k) for k in colors[i])
                cv2.rectangle(img, (x0, y + 3), (x0 + bw, y + row_height - 3), c, -1)
            text = f"{100 * v:.1f}"
        cv2.putText(img, text, (x0 + bar_w + 10, y + row_height - 6), _FONT, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def write_iou_chart(folder: str | Path, protocol: str, metrics: SegmentationMetrics) -> Path:
    """Write ``iou_<protocol>.png`` in ``folder``: the :func:`iou_bar_chart` of one protocol's scores, its
    title giving the mIoU, a class without a value marked "ignored" or "not in GT".

    Args:
        folder: where the picture goes (the run folder, or ``eval --out``).
        protocol: the protocol's name (``hovsg``, ``conceptgraphs``).
        metrics: its :class:`~ogscene3d.eval.metrics.SegmentationMetrics`.

    Returns:
        The PNG's path.
    """
    chart = iou_bar_chart(
        metrics.class_names,
        metrics.iou,
        title=f"per-class IoU, {protocol} protocol (mIoU {100 * metrics.miou:.1f})",
        nan_text=["ignored" if n in metrics.ignored else "not in GT" for n in metrics.class_names],
    )
    return write_png(Path(folder) / f"iou_{protocol}.png", chart)


def write_png(path: str | Path, rgb: np.ndarray) -> Path:
    """Write a uint8 RGB (or single-channel) image as PNG, atomically. Returns the path."""
    a = np.asarray(rgb)
    if a.dtype != np.uint8 or a.ndim not in (2, 3):
        raise ValueError(f"write_png: expected a uint8 [H, W] or [H, W, 3] image, got {a.dtype} {a.shape}")
    bgr = cv2.cvtColor(a, cv2.COLOR_RGB2BGR) if a.ndim == 3 else a
    ok, buf = cv2.imencode(".png", bgr)
    if not ok:
        raise ValueError(f"could not encode PNG for {path}")
    atomic_write_bytes(path, buf.tobytes())
    return Path(path)
