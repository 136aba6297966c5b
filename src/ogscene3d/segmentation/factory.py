"""``make_segmenter``: the 2D front-end named by ``segmentation.backend``, built from the config."""

from __future__ import annotations

import numpy as np

from ..config import SegmentationConfig
from ..errors import ConfigError
from .base import Segmenter

BACKENDS = ("sam", "sam+detector", "classical", "simulated")


def _sam(config: SegmentationConfig):
    from .sam_onnx import SamOnnx

    if not config.sam_encoder or not config.sam_decoder:
        raise ConfigError(
            f"segmentation backend {config.backend!r} needs the ONNX files of the split SAM export: set "
            "segmentation.sam_encoder and segmentation.sam_decoder (config or --set; `ogscene3d segment` "
            "also takes --sam-encoder/--sam-decoder)"
        )
    # SamOnnx checks its grid too, but as a plain ValueError; name the setting here
    for key in ("points_per_side", "points_per_batch"):
        value = getattr(config, key)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ConfigError(f"segmentation.{key} must be an integer >= 1, got {value!r}")
    return SamOnnx(
        config.sam_encoder,
        config.sam_decoder,
        points_per_side=config.points_per_side,
        points_per_batch=config.points_per_batch,
        pred_iou_thresh=config.pred_iou_thresh,
        stability_score_thresh=config.stability_score_thresh,
        stability_score_offset=config.stability_score_offset,
        box_nms_thresh=config.box_nms_thresh,
        min_region_area=config.min_region_area,
        mask_threshold=config.mask_threshold,
        input_size=config.sam_input_size,
        provider=config.execution_provider,
    )


def make_segmenter(config: SegmentationConfig, K: np.ndarray | None = None) -> Segmenter:
    """The segmenter for ``config.backend``: sam | sam+detector | classical | simulated.

    ``K`` (3x3 intrinsics, optional) gives the classical segmenter its focal lengths for normals.
    The simulated segmenter needs ground truth: call its ``segment_frame(frame)`` on synthetic frames.
    Model files are opened here, so a missing or wrong file fails before any frame is processed.
    """
    backend = config.backend
    if backend == "sam":
        return _sam(config)
    if backend == "sam+detector":
        from .detector_onnx import DetectorOnnx
        from .fusion import SamDetectorSegmenter

        if not config.detector:
            raise ConfigError(
                "segmentation backend 'sam+detector' needs a detector ONNX file: set segmentation.detector "
                "(config or --set; `ogscene3d segment` also takes --detector)"
            )
        sam = _sam(config)
        det = DetectorOnnx(
            config.detector,
            config.detector_classes,
            score_thresh=config.detector_score_thresh,
            nms_thresh=config.detector_nms_thresh,
            max_detections=config.detector_max_detections,
            input_size=config.detector_input_size,
            box_format=config.detector_box_format,
            provider=config.execution_provider,
        )
        return SamDetectorSegmenter(sam, det, tau_m=config.tau_m)
    if backend == "classical":
        from .classical import ClassicalSegmenter

        fx = fy = None
        if K is not None:
            K = np.asarray(K, dtype=np.float64)
            if K.shape != (3, 3):
                raise ValueError(f"K must be 3x3, got shape {K.shape}")
            fx, fy = float(K[0, 0]), float(K[1, 1])
        return ClassicalSegmenter(
            k=config.classical_k,
            min_size=config.classical_min_size,
            max_side=config.classical_max_side,
            depth_weight=config.classical_depth_weight,
            normal_weight=config.classical_normal_weight,
            fx=fx,
            fy=fy,
        )
    if backend == "simulated":
        from .simulated import NOISE_LEVELS, SimulatedSegmenter

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
