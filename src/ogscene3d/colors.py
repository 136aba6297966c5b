"""Colour schemes shared by the viewer and the evaluation pictures: stable per-label colours, colormaps.

Every function maps arrays to float32 RGB in [0, 1] with shape ``[..., 3]``.
"""

from __future__ import annotations

import numpy as np

UNLABELED_RGB = np.array([0.62, 0.62, 0.62], dtype=np.float32)

# Turbo colormap, polynomial fit by its author (A. Mikhailov, Google, 2019; Apache-2.0):
# channel(t) = c0 + c1 t + ... + c5 t^5 for t in [0, 1].
_TURBO_COEFFS = np.array(
    [
        [0.13572138, 4.61539260, -42.66032258, 132.13108234, -152.94239396, 59.28637943],
        [0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604],
        [0.10667330, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973],
    ],
    dtype=np.float64,
)


def _hash32(x: np.ndarray) -> np.ndarray:
    """A 32-bit integer mix (lowbias32) so that neighbouring labels get unrelated colours."""
    h = x.astype(np.uint32, copy=True)
    h ^= h >> np.uint32(16)
    h *= np.uint32(0x7FEB352D)
    h ^= h >> np.uint32(15)
    h *= np.uint32(0x846CA68B)
    h ^= h >> np.uint32(16)
    return h


def _hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectorised HSV -> RGB, all inputs in [0, 1]; returns [..., 3]."""
    i = np.floor(h * 6.0).astype(np.int64) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    table = np.stack(
        [
            np.stack([v, t, p], -1),
            np.stack([q, v, p], -1),
            np.stack([p, v, t], -1),
            np.stack([p, q, v], -1),
            np.stack([t, p, v], -1),
            np.stack([v, p, q], -1),
        ],
        0,
    )
    return np.take_along_axis(table, i[None, ..., None].repeat(3, -1), 0)[0]


def label_colors(labels: np.ndarray) -> np.ndarray:
    """Stable colour per scene label: [N] int -> [N, 3] float32; label < 0 (unlabeled) -> grey.

    The colour depends only on the label id (a hash), so a label keeps its colour across updates,
    runs and browsers.
    """
    labels = np.asarray(labels)
    if labels.size and not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"label_colors: labels must be integers, got {labels.dtype}")
    h = _hash32(np.maximum(labels, 0).astype(np.int64) & 0xFFFFFFFF)
    hue = (h & np.uint32(0xFFFF)).astype(np.float64) / 65536.0
    sat = 0.55 + 0.4 * ((h >> np.uint32(16)) & np.uint32(0xFF)).astype(np.float64) / 255.0
    val = 0.7 + 0.3 * ((h >> np.uint32(24)) & np.uint32(0xFF)).astype(np.float64) / 255.0
    rgb = _hsv_to_rgb(hue, sat, val).astype(np.float32)
    rgb[labels < 0] = UNLABELED_RGB
    return rgb


def label_color_uint8(label: int) -> tuple[int, int, int]:
    """The colour of one label as an 8-bit RGB tuple (for scene primitives)."""
    c = label_colors(np.array([label], dtype=np.int64))[0]
    return tuple(int(round(float(v) * 255)) for v in c)  # type: ignore[return-value]


def turbo(t: np.ndarray) -> np.ndarray:
    """Turbo colormap: values in [0, 1] (clipped; NaN -> 0) -> [..., 3] float32 RGB."""
    t = np.clip(np.nan_to_num(np.asarray(t, dtype=np.float64), nan=0.0), 0.0, 1.0)
    powers = np.stack([t**k for k in range(6)], -1)  # [..., 6]
    return np.clip(powers @ _TURBO_COEFFS.T, 0.0, 1.0).astype(np.float32)


def confidence_colors(confidences: np.ndarray, labels: np.ndarray | None = None) -> np.ndarray:
    """Confidence in [0, 1] -> turbo colour (blue = 0, red = 1); unlabeled Gaussians (label < 0) grey."""
    rgb = turbo(confidences)
    if labels is not None:
        rgb[np.asarray(labels) < 0] = UNLABELED_RGB
    return rgb


def dim(rgb: np.ndarray, amount: float = 0.75) -> np.ndarray:
    """Blend colours toward light grey (``amount`` 0 = unchanged, 1 = grey), to de-emphasise them."""
    return (1.0 - amount) * np.asarray(rgb, dtype=np.float32) + amount * np.float32(0.85)


__all__ = ["UNLABELED_RGB", "confidence_colors", "dim", "label_color_uint8", "label_colors", "turbo"]


# Rooms are few and lie side by side: a qualitative palette keeps neighbours apart (Tableau 10's hues).
_ROOM_PALETTE = np.array(
    [[78, 121, 167], [242, 142, 43], [225, 87, 89], [118, 183, 178], [89, 161, 79], [237, 201, 72],
     [176, 122, 161], [255, 157, 167], [156, 117, 95], [186, 176, 172]],
    dtype=np.float32,
) / 255.0  # fmt: skip


def room_colors(room_ids: np.ndarray) -> np.ndarray:
    """Colour per room id (from 1): [N] int -> [N, 3] float32; id < 1 (no room) -> grey."""
    ids = np.asarray(room_ids).astype(np.int64)
    rgb = _ROOM_PALETTE[(np.maximum(ids, 1) - 1) % len(_ROOM_PALETTE)].copy()
    rgb[ids < 1] = UNLABELED_RGB
    return rgb
