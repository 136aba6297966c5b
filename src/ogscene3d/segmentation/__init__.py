"""Open-set 2D segmentation: precomputed segments, SAM/detector ONNX front-ends, fusion, fallbacks."""

from __future__ import annotations

from .._lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        ".base": ["Segmentation", "Segmenter"],
        ".classical": ["ClassicalSegmenter"],
        ".depth_edges": ["snap_to_depth_edges"],
        ".detector_onnx": ["DetectorOnnx"],
        ".factory": ["make_segmenter"],
        ".fusion": ["SamDetectorSegmenter", "fuse_segmentations"],
        ".precomputed": ["read_segmentation", "read_segments", "write_segments"],
        ".sam_onnx": ["SamOnnx"],
    },
)

__all__ = [
    "ClassicalSegmenter",
    "DetectorOnnx",
    "SamDetectorSegmenter",
    "SamOnnx",
    "Segmentation",
    "Segmenter",
    "fuse_segmentations",
    "make_segmenter",
    "snap_to_depth_edges",
    "read_segmentation",
    "read_segments",
    "write_segments",
]
