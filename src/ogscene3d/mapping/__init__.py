"""Semantic mapping core (paper Sec. III-A to III-C): keyframes, Gaussian initialization, local 3D
optimization, geometry/appearance optimization, global refinement, long-term optimization, the Mapper."""

from __future__ import annotations

from .._lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        ".keyframes": ["KeyframeSelector"],
        ".local": ["associate_segments", "eq5_update", "rescale_sam_scores", "update_confidences"],
        ".longterm": ["MemoryBuffer", "eq16_update"],
        ".mapper": ["ABLATIONS", "Mapper"],
        ".neighbors": ["any_within", "count_within", "knn"],
        ".refine": ["connected_clusters", "global_refinement"],
    },
)

__all__ = [
    "ABLATIONS",
    "KeyframeSelector",
    "Mapper",
    "MemoryBuffer",
    "any_within",
    "associate_segments",
    "connected_clusters",
    "count_within",
    "eq16_update",
    "eq5_update",
    "global_refinement",
    "knn",
    "rescale_sam_scores",
    "update_confidences",
]
