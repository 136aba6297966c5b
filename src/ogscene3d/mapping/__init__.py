"""Semantic mapping core (paper Sec. III-A to III-C): keyframes, Gaussian initialization, local 3D
optimization, geometry/appearance optimization, global refinement, long-term optimization, the Mapper."""

from .keyframes import KeyframeSelector
from .local import associate_segments, eq5_update, rescale_sam_scores, update_confidences
from .longterm import MemoryBuffer, eq16_update
from .mapper import ABLATIONS, Mapper
from .neighbors import any_within, count_within, knn
from .refine import connected_clusters, global_refinement

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
