"""Open-set 2D segmentation: precomputed segments, SAM/detector ONNX front-ends, fusion, fallbacks."""

from .base import Segmentation, Segmenter
from .classical import ClassicalSegmenter
from .detector_onnx import DetectorOnnx
from .factory import make_segmenter
from .fusion import SamDetectorSegmenter, fuse_segmentations
from .precomputed import read_segmentation, read_segments, write_segments
from .sam_onnx import SamOnnx

__all__ = [
    "ClassicalSegmenter",
    "DetectorOnnx",
    "SamDetectorSegmenter",
    "SamOnnx",
    "Segmentation",
    "Segmenter",
    "fuse_segmentations",
    "make_segmenter",
    "read_segmentation",
    "read_segments",
    "write_segments",
]
