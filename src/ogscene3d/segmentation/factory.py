"""``make_segmenter``: the 2D front-end named by ``segmentation.backend``, built from the config."""

from __future__ import annotations

import numpy as np

from ..config import SegmentationConfig
from ..errors import ConfigError
from .base import Segmenter
from .classical import ClassicalSegmenter
from .fusion import SamDetectorSegmenter
from .sam_onnx import SamOnnx
from .simulated import NOISE_LEVELS, SimulatedSegmenter

BACKENDS = ("sam", "sam+detector", "classical", "simulated")


def make_segmenter(config: SegmentationConfig, K: np.ndarray | None = None) -> Segmenter:
    """The segmenter for ``config.backend``: sam | sam+detector | classical | simulated.

    Each front-end reads its own settings from the section (``from_config``).

    Args:
        config: the ``segmentation`` config section.
        K: 3x3 intrinsics (optional): the classical segmenter's focal lengths for normals.

    Returns:
        The segmenter. Model files are opened here, so a missing or wrong file fails before any frame is
        processed. The simulated segmenter needs ground truth: call its ``segment_frame(frame)`` on
        synthetic frames.
    """
    backend = config.backend
    if backend == "sam":
        return SamOnnx.from_config(config)
    if backend == "sam+detector":
        return SamDetectorSegmenter.from_config(config)
    if backend == "classical":
        return ClassicalSegmenter.from_config(config, K)
    if backend == "simulated":
        if config.simulated_noise not in NOISE_LEVELS:
            raise ConfigError(
                f"segmentation.simulated_noise must be one of {sorted(NOISE_LEVELS)}, "
                f"got {config.simulated_noise!r}"
            )
        return SimulatedSegmenter(noise=config.simulated_noise, seed=config.simulated_seed)
    if backend == "precomputed":
        raise ConfigError(
            "segmentation backend 'precomputed' reads segments (data.segments_dir) and computes none; "
            f"choose one of {list(BACKENDS)} to compute segments"
        )
    raise ConfigError(
        f"unknown segmentation.backend {backend!r}; expected precomputed or one of {list(BACKENDS)}"
    )
