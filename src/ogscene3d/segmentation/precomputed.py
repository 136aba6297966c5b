"""The precomputed segments format (docs/formats.md, "Precomputed segments").

``DIR/<rgb stem>.png``: uint16 segment ids, 0 = no segment, same size as the RGB image;
``DIR/<rgb stem>.json``: optional ``{"scores": {"<id>": float}, "names": {"<id>": str}}`` (SAM predicted
IoU, finite: a NaN or inf score is refused; ``names``, optional, the detector class of segments that
came with a detector label).

A frame without a PNG has no precomputed segments: datasets give it ``segments=None`` and the
mapper's ``segmentation.backend`` segments it live. :func:`read_segments` itself reads one file that
must be there.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np

from ..atomic import atomic_write_bytes
from ..errors import DataError
from .base import Segmentation


def segments_paths(directory: str | Path, stem: str) -> tuple[Path, Path]:
    d = Path(directory)
    return d / f"{stem}.png", d / f"{stem}.json"


def has_segments(directory: str | Path, stem: str) -> bool:
    """Whether the frame ``stem`` has a segments PNG in ``directory`` (a stat; nothing is read)."""
    return segments_paths(directory, stem)[0].is_file()


def _not_finite(scores: dict) -> list[int]:
    """The ids whose score is NaN or inf (json reads and writes both), sorted."""
    return sorted(int(k) for k, v in scores.items() if not math.isfinite(float(v)))


def write_segments(
    directory: str | Path,
    stem: str,
    ids: np.ndarray,
    scores: dict[int, float] | None = None,
    names: dict[int, str] | None = None,
) -> Path:
    """Write one frame's segment map (atomically: a partial file never looks like a finished frame).

    The JSON (``scores``, and ``names`` when given) is written before the PNG, the 'done' marker of
    resumable runs. ``names`` without ``scores`` writes an empty ``scores`` (every segment then reads 1.0).
    """
    ids = np.asarray(ids)
    if ids.ndim != 2:
        raise ValueError(f"segment ids must be a 2D map, got shape {ids.shape}")
    d = Path(directory)
    png, js = segments_paths(d, stem)
    if ids.min(initial=0) < 0 or ids.max(initial=0) > 65535:
        # a DataError (the CLI prints it without a traceback): a frame with more than 65535 segments
        raise DataError(
            f"{png}: segment ids must lie in [0, 65535] to be stored as uint16 PNG, got "
            f"[{int(ids.min(initial=0))}, {int(ids.max(initial=0))}] (fewer segments: raise "
            "segmentation.min_region_area / classical_min_size)"
        )
    bad = _not_finite(scores or {})
    if bad:
        raise ValueError(f"{png}: the scores of segment(s) {bad[:8]} are not finite (NaN or inf)")
    d.mkdir(parents=True, exist_ok=True)
    if scores is not None or names:
        payload: dict = {"scores": {str(int(k)): float(v) for k, v in sorted((scores or {}).items())}}
        if names:
            payload["names"] = {str(int(k)): str(v) for k, v in sorted(names.items())}
        atomic_write_bytes(js, json.dumps(payload).encode())
    ok, buf = cv2.imencode(".png", ids.astype(np.uint16))
    if not ok:
        raise DataError(f"{png}: could not encode segment map")
    atomic_write_bytes(png, buf.tobytes())
    return png


def _read_ids(png: Path, shape: tuple[int, int] | None) -> np.ndarray:
    if not png.is_file():
        raise DataError(f"{png}: segments file is missing")
    ids = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    if ids is None:
        raise DataError(f"{png}: cannot decode segments PNG (corrupt or truncated)")
    if ids.ndim != 2:
        raise DataError(f"{png}: segments PNG must be single-channel uint16, got shape {ids.shape}")
    if shape is not None and tuple(ids.shape) != tuple(shape):
        raise DataError(
            f"{png}: segments are {ids.shape[1]}x{ids.shape[0]}, the RGB image is {shape[1]}x{shape[0]}"
        )
    return ids.astype(np.int32)


def _read_sidecar(js: Path) -> tuple[dict[int, float], dict[int, str]]:
    """The JSON's (scores, names); a missing file has neither."""
    if not js.is_file():
        return {}, {}
    try:
        payload = json.loads(js.read_text())
        scores = {int(k): float(v) for k, v in payload["scores"].items()}
        names = {int(k): str(v) for k, v in payload.get("names", {}).items()}
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as e:
        raise DataError(
            f'{js}: malformed segments JSON ({e}); expected {{"scores": {{"<id>": float}}}} and optionally '
            '"names": {"<id>": "class"}'
        ) from e
    # json reads NaN / Infinity: a NaN score would become a NaN Gaussian confidence
    bad = _not_finite(scores)
    if bad:
        raise DataError(f"{js}: the scores of segment(s) {bad[:8]} are not finite (NaN or inf)")
    return scores, names


def read_segmentation(directory: str | Path, stem: str, shape: tuple[int, int] | None = None) -> Segmentation:
    """Read one frame's segments with their scores and detector class names (``names``: only the
    segments that came with a detector label, as ``ogscene3d segment --backend sam+detector`` writes them).
    Missing scores default to 1.0; scores and names of ids absent from the PNG are dropped.

    A missing, corrupt or wrong-size (``shape``) PNG raises :class:`DataError`; callers for which
    segments are optional check :func:`has_segments` first.
    """
    png, js = segments_paths(directory, stem)
    ids = _read_ids(png, shape)
    present = [int(i) for i in np.unique(ids) if i != 0]
    scores, names = _read_sidecar(js)
    return Segmentation(
        ids=ids,
        scores={i: scores.get(i, 1.0) for i in present},
        names={i: names[i] for i in present if i in names},
    )


def read_segments(
    directory: str | Path, stem: str, shape: tuple[int, int] | None = None
) -> tuple[np.ndarray, dict[int, float]]:
    """Read one frame's segments: (int32 id map, {id: score}); see :func:`read_segmentation`, which also
    returns the detector class names."""
    seg = read_segmentation(directory, stem, shape)
    return seg.ids, seg.scores
