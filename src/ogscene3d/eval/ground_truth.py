"""The ground truth an evaluation scores against (:class:`GroundTruth`), built by the readers
(:mod:`.readers`, :mod:`.replica_gt`), and the re-indexing of dataset class ids they share."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import DataError


def reindex_class_ids(raw: np.ndarray, table: dict[int, str]) -> tuple[np.ndarray, list[str]]:
    """Raw class ids -> compact indices in table order (ids sorted); unknown ids -> -1."""
    ids = np.array(sorted(table), dtype=np.int64)
    names = [table[int(i)] for i in ids]
    if ids.size == 0:
        return np.full(raw.shape, -1, np.int64), names
    pos = np.clip(np.searchsorted(ids, raw), 0, ids.size - 1)
    out = np.where(ids[pos] == raw, pos, -1).astype(np.int64)
    return out, names


@dataclass
class GroundTruth:
    """A labelled ground-truth point cloud with class names, instances and relation triplets."""

    points: np.ndarray  # [M, 3] float64
    classes: np.ndarray  # [M] int64 index into class_names, -1 = void
    class_names: list[str]
    instances: np.ndarray | None = None  # [M] int64 instance ids, -1 = none
    instance_classes: dict[int, int] = field(default_factory=dict)  # instance id -> class index
    relations: list[tuple[int, str, int]] = field(default_factory=list)
    symmetric_relations: list[str] | None = None  # None = the evaluator's defaults
    inverse_relations: list[tuple[str, str]] | None = None
    class_ids: list[int] | None = None  # the dataset's own id of each class (for its 2D label maps)
    source: str = ""
    observed: np.ndarray | None = None  # [M] bool, seen by some frame (synthetic scenes); None = unknown
    has_3d: bool = True  # False: per-frame class maps only (points is empty), 2D scores only
    instance_rooms: dict[int, int] = field(default_factory=dict)  # instance id -> room id (apartments)
    rooms: dict[int, dict[str, Any]] = field(
        default_factory=dict
    )  # room id -> {"type", "floor", "first_frame"}

    def class_index_of_ids(self, ids: Any) -> np.ndarray:
        """Dataset class ids (e.g. a GT class image) -> indices into ``class_names``, -1 if unknown."""
        raw = np.asarray(ids).astype(np.int64)
        if self.class_ids is None:
            raise DataError(f"{self.source}: the ground truth has no class-id table for 2D label maps")
        out, _ = reindex_class_ids(raw, dict(zip(self.class_ids, self.class_names)))
        return out
