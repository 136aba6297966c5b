"""Open-set 2D segmentation: precomputed segments, SAM/detector ONNX front-ends, fusion, fallbacks."""

from .precomputed import read_segments, write_segments

__all__ = ["read_segments", "write_segments"]
