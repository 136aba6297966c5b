"""Which frames a run read, as recorded in its checkpoint and ``config.yaml``: the names and bytes that tell a
sequence's frames apart, and the intrinsics they were mapped with. Used by a resume (``mapping``) and by
evaluation (``eval``), which both import from here."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError
from ..runs.map_npz import read_map_npz
from .loader import open_dataset


def frame_names(ds: Any) -> list[str]:
    """The selected frames of ``ds`` in order, each as its rgb file below the dataset folder (a moved
    dataset keeps them; a stem alone can repeat across the sequences of one folder)."""
    root = Path(ds.root)
    names = []
    for rec in ds.records:
        path = Path(rec.rgb_path)
        names.append(path.relative_to(root).as_posix() if path.is_relative_to(root) else path.name)
    return names


def file_digest(path: Path) -> str | None:
    """SHA-256 of a file's bytes (None when it cannot be read): what a moved sequence is recognised by, as
    the frame names are relative to the dataset folder and the same in every sequence of a layout."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def sequence_change(recorded: list[str], current: list[str], count: int) -> str | None:
    """How the frames at the first ``count`` positions of a selection (``current``, by
    :func:`frame_names`) differ from those a map recorded reading there (``recorded``), in words; None
    when they are the same frames, as far as ``current`` goes (a shorter selection is the caller's to
    judge)."""
    for i, (was, now) in enumerate(zip(recorded[:count], current[:count], strict=False)):
        if was != now:
            return f"frame {i} of the run's selection was {was!r} and is now {now!r}"
    if len(recorded) < min(count, len(current)):
        return f"the map names {len(recorded)} frames, but has read {count}"
    return None


def matching_pixel_centers(ds: Any, K: Any) -> str | None:
    """The ``data.pixel_centers`` setting (``"integer"`` or ``"half"``) under which the frames of ``ds`` (an
    opened dataset, read under the other) have the intrinsics ``K`` (9 values): a map made before
    ``data.pixel_centers`` (``"half"``: every layout's K was read as it is; ScanNet's colour K rescaled to
    the depth size then differs from today's by less than half a pixel), or under the other setting. None
    when neither reading gives ``K`` (another camera or image size), or the layout's K ignores the setting
    (Semantic-NeRF's field of view)."""
    config, read = getattr(ds, "config", None), getattr(ds, "pixel_centers", None)
    if config is None or read not in ("integer", "half"):
        return None
    other = "half" if read == "integer" else "integer"
    try:
        ds_other = open_dataset(
            ds.root, kind=ds.kind, max_frames=1,
            config=dataclasses.replace(config, pixel_centers=other, segments_dir=None),
        )  # fmt: skip
    except DataError:
        return None
    return (
        other
        if np.allclose(np.asarray(ds_other.K).reshape(-1), np.asarray(K).reshape(-1), atol=1e-3)
        else None
    )


def mapped_intrinsics(ckpt: Path) -> list[float] | None:
    """The 9 values of the K a checkpoint's frames were mapped with (None: not recorded or unreadable)."""
    try:
        arrays = read_map_npz(ckpt, ("mapper_source",))
        if "mapper_source" not in arrays:
            return None
        K = json.loads(str(arrays["mapper_source"])).get("K")
    except (DataError, AttributeError, ValueError):
        return None
    return K if isinstance(K, list) and len(K) == 9 else None
