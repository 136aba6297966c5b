"""Segment Anything through onnxruntime: the common split export (image encoder + prompt decoder).

The decoder is the interface of segment-anything's ``scripts/export_onnx_model.py`` (also MobileSAM's copy
of that script, and samexporter's decoder export, as AnyLabeling uses). Other interfaces are refused with an
error naming the inputs expected: EfficientSAM's official export (``batched_point_coords``,
``batched_point_labels``, int64 ``orig_im_size``), SAM-HQ's (an extra ``interm_embeddings`` input), SAM 2's.

    inputs   image_embeddings [1, 256, 64, 64], point_coords [B, N, 2], point_labels [B, N],
             mask_input [1, 1, 256, 256], has_mask_input [1], orig_im_size [2] (= H, W)
    outputs  masks [B, C, H, W] (logits at the original size), iou_predictions [B, C], low_res_masks

``point_coords`` are in the frame of the encoder's input: the image resized so that its longest side
is the encoder size (1024), i.e. original pixel coordinates times the resize factor. Point labels:
1 foreground, 0 background, -1 padding, 2/3 the top-left/bottom-right corners of a box prompt.

The masks are made here from ``low_res_masks`` (when the decoder has it, as every export of that script
does) with the decoder's own post-processing (bilinear to the encoder size, crop the padding, bilinear to
the original size), not taken from ``masks``: segment-anything 1.0 as released on PyPI traces that crop
as a constant, so its exports cut every frame's masks at the aspect ratio of the export's dummy
``orig_im_size`` (1500 x 2250; fixed in segment-anything PR #58), which misplaces them on a 4:3 frame.

The encoder comes in two flavours, told apart from its input signature:
- ``[1, 3, S, S]`` float: the bare image encoder; we resize the longest side to S, normalise with SAM's
  pixel mean/std and zero-pad bottom/right (segment-anything's ``preprocess``).
- ``[S, S, 3]`` or ``[1, S, S, 3]`` (uint8 or float): exports with the normalisation and layout change
  inside the graph; we only resize and zero-pad, feeding raw 0..255 RGB pixels. With symbolic
  spatial dims (``[H, W, 3]``, samexporter's ``--use-preprocess``) the graph pads too, so the resized
  image goes in unpadded.

Automatic mask generation follows segment-anything's ``SamAutomaticMaskGenerator`` on a single crop
(no ``crop_n_layers``): a ``points_per_side``² grid of single-point prompts, the three multimask outputs
of each, filtering by predicted IoU (a NaN or inf one fails) and stability score, box NMS, removal of
small islands and holes (``min_region_area``), then painting into one id map where the mask with the
higher predicted IoU wins each pixel; segments left with fewer than ``min_region_area`` visible pixels
are dropped.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields
from pathlib import Path

import cv2
import numpy as np

from ..config import SegmentationConfig, section_values
from ..errors import ConfigError
from .base import Segmentation
from .masks import MaskRecord, mask_nms, masks_to_records, paint_masks, remove_small_regions
from .onnx_session import OnnxModel

log = logging.getLogger(__name__)

PIXEL_MEAN = np.array([123.675, 116.28, 103.53], dtype=np.float32)
PIXEL_STD = np.array([58.395, 57.12, 57.375], dtype=np.float32)

DECODER_INPUTS = (
    "image_embeddings",
    "point_coords",
    "point_labels",
    "mask_input",
    "has_mask_input",
    "orig_im_size",
)
DECODER_OUTPUTS = ("masks", "iou_predictions")
_DECODER_EXPECTED = (
    "inputs image_embeddings[1,256,64,64], point_coords[B,N,2], point_labels[B,N], mask_input[1,1,256,256], "
    "has_mask_input[1], orig_im_size[2] and outputs masks[B,C,H,W], iou_predictions[B,C] "
    "(segment-anything's export_onnx_model.py interface)"
)
_ENCODER_EXPECTED = (
    "one image input, either [1,3,S,S] float (normalised NCHW) or [S,S,3] / [1,S,S,3] uint8 or float "
    "(raw RGB pixels), and an image_embeddings[1,256,64,64] output"
)


def check_rgb(rgb: np.ndarray) -> np.ndarray:
    """Validate an RGB frame (uint8 [H, W, 3]); raise ValueError naming the problem."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be a uint8 [H, W, 3] image, got {rgb.dtype} {rgb.shape}")
    if rgb.shape[0] < 1 or rgb.shape[1] < 1:
        raise ValueError(f"rgb image is empty: shape {rgb.shape}")
    return rgb


def resize_longest_side(h: int, w: int, target: int) -> tuple[int, int]:
    """segment-anything's ``ResizeLongestSide.get_preprocess_shape``: (new_h, new_w)."""
    scale = target / max(h, w)
    return int(h * scale + 0.5), int(w * scale + 0.5)


def build_point_grid(n: int, h: int, w: int) -> np.ndarray:
    """The n x n grid of prompt points [n*n, 2] (x, y) in pixels, cell centres as in segment-anything."""
    if n < 1:
        raise ValueError(f"points_per_side must be >= 1, got {n}")
    offset = 1.0 / (2 * n)
    t = np.linspace(offset, 1 - offset, n)
    xs, ys = np.meshgrid(t * w, t * h)
    return np.stack([xs.ravel(), ys.ravel()], axis=-1).astype(np.float32)


def stability_score(logits: np.ndarray, threshold: float, offset: float) -> np.ndarray:
    """segment-anything's stability score per mask [K]: IoU of the masks thresholded at t +/- offset."""
    flat = logits.reshape(logits.shape[0], -1)
    inter = np.count_nonzero(flat > threshold + offset, axis=1)
    union = np.count_nonzero(flat > threshold - offset, axis=1)
    return np.where(union > 0, inter / np.maximum(union, 1), 0.0)


@dataclass
class SamImage:
    """An encoded frame: embeddings [1, 256, h', w'], the original (H, W) and the resized (H', W') sizes."""

    embeddings: np.ndarray
    orig_size: tuple[int, int]
    resized_size: tuple[int, int]

    def to_model_coords(self, xy: np.ndarray) -> np.ndarray:
        """Original pixel coordinates (..., 2) -> the encoder input frame the decoder expects."""
        h, w = self.orig_size
        nh, nw = self.resized_size
        return (np.asarray(xy, dtype=np.float32) * np.array([nw / w, nh / h], dtype=np.float32)).astype(
            np.float32
        )


@dataclass(frozen=True)
class MaskFilters:
    """Which of SAM's masks an automatic pass keeps (SAM's automatic mask generator's settings of the same
    names; the ``segmentation`` config section holds them).

    Args:
        pred_iou_thresh: a mask's predicted IoU must exceed this.
        stability_score_thresh: its stability score (IoU of the mask at two thresholds) must reach this.
        stability_score_offset: the offset of those two thresholds around ``mask_threshold``.
        box_nms_thresh: box IoU above which the lower-scored of two masks is dropped.
        min_region_area: pixels; smaller holes and islands are removed, smaller masks dropped.
        mask_threshold: the logit at which a pixel is in the mask.
    """

    pred_iou_thresh: float = 0.88
    stability_score_thresh: float = 0.92
    stability_score_offset: float = 1.0
    box_nms_thresh: float = 0.7
    min_region_area: int = 100
    mask_threshold: float = 0.0

    @classmethod
    def from_section(cls, config: SegmentationConfig) -> MaskFilters:
        """The filters that a ``segmentation`` config section sets (its settings of the same names)."""
        return cls(**section_values(config, [f.name for f in fields(cls)]))


class SamOnnx:
    """Automatic SAM segmentation (paper Sec. III-B.1, M_s) with the split ONNX export.

    Implements the Segmenter protocol: ``seg = SamOnnx(enc, dec); s = seg(rgb)`` gives an int32 id map with
    ``s.scores[id]`` = SAM's predicted IoU of the winning mask. ``embed``, ``generate`` and ``segment_boxes``
    are public so that the detector front-end reuses one encoder pass per frame.
    """

    def __init__(
        self,
        encoder: str | Path,
        decoder: str | Path,
        *,
        points_per_side: int = 32,
        points_per_batch: int = 16,
        filters: MaskFilters | None = None,
        input_size: int = 1024,
        provider: str = "auto",
    ) -> None:
        if points_per_side < 1 or points_per_batch < 1:
            raise ValueError("points_per_side and points_per_batch must be >= 1")
        self.points_per_side = int(points_per_side)
        self.points_per_batch = int(points_per_batch)
        self.filters = filters if filters is not None else MaskFilters()
        self.encoder = OnnxModel(encoder, "SAM image encoder", provider)
        self.decoder = OnnxModel(decoder, "SAM mask decoder", provider)
        self._inspect_encoder(int(input_size))
        self._inspect_decoder()

    @classmethod
    def from_config(cls, config: SegmentationConfig) -> SamOnnx:
        """The SAM front-end that a ``segmentation`` config section describes.

        Args:
            config: the section; read are ``sam_encoder`` and ``sam_decoder`` (the split export's files),
                the prompt grid (``points_per_side``, ``points_per_batch``), the mask filters
                (``pred_iou_thresh``, ``stability_score_thresh``, ``stability_score_offset``,
                ``box_nms_thresh``, ``min_region_area``, ``mask_threshold``), ``sam_input_size`` and
                ``execution_provider``.

        Returns:
            The segmenter, its model files opened. A missing file setting or a grid that is not a whole
            number >= 1 raises ConfigError naming the setting.
        """
        if not config.sam_encoder or not config.sam_decoder:
            raise ConfigError(
                f"segmentation backend {config.backend!r} needs the ONNX files of the split SAM export: set "
                "segmentation.sam_encoder and segmentation.sam_decoder (config or --set; `ogscene3d segment` "
                "also takes --sam-encoder/--sam-decoder)"
            )
        # the constructor checks its grid too, but as a plain ValueError; name the setting here
        for key in ("points_per_side", "points_per_batch"):
            value = getattr(config, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"segmentation.{key} must be an integer >= 1, got {value!r}")
        return cls(
            config.sam_encoder,
            config.sam_decoder,
            points_per_side=config.points_per_side,
            points_per_batch=config.points_per_batch,
            filters=MaskFilters.from_section(config),
            input_size=config.sam_input_size,
            provider=config.execution_provider,
        )

    # ------------------------------------------------------------------ model signatures
    def _inspect_encoder(self, default_size: int) -> None:
        enc = self.encoder
        if len(enc.inputs) != 1:
            raise enc.error(f"{len(enc.inputs)} inputs", _ENCODER_EXPECTED)
        info = next(iter(enc.inputs.values()))
        self._enc_input = info.name
        shape, dtype = info.shape, np.dtype(info.dtype)
        if len(shape) == 4 and shape[1] == 3:
            self._layout = "nchw"
            hw = shape[2:4]
        elif len(shape) == 4 and shape[3] == 3 and shape[0] in (1, None):
            self._layout = "nhwc"
            hw = shape[1:3]
        elif len(shape) == 3 and shape[2] == 3:
            self._layout = "hwc"
            hw = shape[0:2]
        else:
            raise enc.error(f"unsupported input shape {shape}", _ENCODER_EXPECTED)
        if self._layout == "nchw" and dtype.kind != "f":
            raise enc.error(f"NCHW input of type {dtype.name}", _ENCODER_EXPECTED)
        if dtype.kind not in "fu":
            raise enc.error(f"input of type {dtype.name}", _ENCODER_EXPECTED)
        # symbolic spatial dims: the export resizes nothing itself, so resize to SAM's input size; HWC
        # exports with symbolic dims (samexporter's --use-preprocess) also pad inside the graph, after
        # normalising, so they get the resized image unpadded
        self._enc_hw = tuple(int(d) if d is not None else default_size for d in hw)
        self._pad_inside = self._layout != "nchw" and any(d is None for d in hw)
        self._enc_output = (
            "image_embeddings" if "image_embeddings" in enc.outputs else next(iter(enc.outputs))
        )
        out_shape = enc.outputs[self._enc_output].shape
        if len(out_shape) != 4:
            raise enc.error(f"output {self._enc_output} has rank {len(out_shape)}", _ENCODER_EXPECTED)

    def _inspect_decoder(self) -> None:
        dec = self.decoder
        dec.require(DECODER_INPUTS, DECODER_OUTPUTS, _DECODER_EXPECTED)
        extra = sorted(set(dec.inputs) - set(DECODER_INPUTS))
        if extra:
            raise dec.error(f"unexpected input(s) {extra}", _DECODER_EXPECTED)
        pc = dec.inputs["point_coords"].shape
        if len(pc) != 3 or pc[2] not in (2, None):
            raise dec.error(f"point_coords has shape {pc}", _DECODER_EXPECTED)
        # exports fix the prompt batch to 1 unless made with a dynamic batch axis
        self._dec_batch = pc[0]  # None: any batch size
        mi = dec.inputs["mask_input"].shape
        if len(mi) != 4:
            raise dec.error(f"mask_input has shape {mi}", _DECODER_EXPECTED)
        enc_out = self.encoder.outputs[self._enc_output].shape
        emb_in = dec.inputs["image_embeddings"].shape
        if len(emb_in) != 4 or any(
            a is not None and b is not None and a != b for a, b in zip(enc_out, emb_in)
        ):
            raise dec.error(
                f"image_embeddings input {list(emb_in)} does not match the encoder's output "
                f"{self._enc_output}{list(enc_out)} ({self.encoder.path})",
                _DECODER_EXPECTED,
            )
        self._mask_hw = tuple(
            int(d) if d is not None else 4 * (int(e) if e is not None else 64)
            for d, e in zip(mi[2:4], enc_out[2:4])
        )
        # low_res_masks [B, C, h, w] (the mask_input grid); with --return-extra-metrics that name is given
        # to the stability scores [B, C], so only a rank-4 output is taken for the low-resolution logits
        lr = dec.outputs.get("low_res_masks")
        self._low_res = lr is not None and len(lr.shape) == 4

    # ------------------------------------------------------------------ encoder
    def preprocess(self, rgb: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
        """The encoder input for ``rgb`` and the resized (H', W') size inside the padded square."""
        rgb = check_rgb(rgb)
        h, w = rgb.shape[:2]
        th, tw = self._enc_hw
        scale = min(th / h, tw / w)  # == longest side -> S for SAM's square input
        nh, nw = min(th, int(h * scale + 0.5)), min(tw, int(w * scale + 0.5))
        interp = cv2.INTER_AREA if scale < 1.0 else cv2.INTER_LINEAR
        resized = cv2.resize(rgb, (nw, nh), interpolation=interp) if (nh, nw) != (h, w) else rgb
        if self._layout == "nchw":
            x = (resized.astype(np.float32) - PIXEL_MEAN) / PIXEL_STD
            padded = np.zeros((th, tw, 3), dtype=np.float32)  # SAM pads after normalising: zeros
            padded[:nh, :nw] = x
            return padded.transpose(2, 0, 1)[None], (nh, nw)
        if self._pad_inside:
            padded = np.ascontiguousarray(resized)
        else:
            padded = np.zeros((th, tw, 3), dtype=np.uint8)
            padded[:nh, :nw] = resized
        out = padded[None] if self._layout == "nhwc" else padded
        return out, (nh, nw)

    def embed(self, rgb: np.ndarray) -> SamImage:
        """Run the image encoder once for a frame."""
        x, resized = self.preprocess(rgb)
        (emb,) = self.encoder.run({self._enc_input: x}, [self._enc_output])
        if not np.all(np.isfinite(emb)):
            raise self.encoder.error("non-finite image embeddings", _ENCODER_EXPECTED)
        return SamImage(np.asarray(emb, dtype=np.float32), (int(rgb.shape[0]), int(rgb.shape[1])), resized)

    # ------------------------------------------------------------------ decoder
    def postprocess_masks(self, image: SamImage, low_res: np.ndarray) -> np.ndarray:
        """Low-resolution mask logits [..., h, w] -> [..., H, W] at the original size, as the decoder's
        ``SamOnnxModel.mask_postprocessing`` does: bilinear to the encoder's input size, crop to the
        resized image (the padding off), bilinear to the original size."""
        th, tw = self._enc_hw
        nh, nw = image.resized_size
        h, w = image.orig_size
        flat = np.asarray(low_res, dtype=np.float32).reshape(-1, *low_res.shape[-2:])
        out = np.empty((flat.shape[0], h, w), dtype=np.float32)
        for i, m in enumerate(flat):
            up = cv2.resize(m, (tw, th), interpolation=cv2.INTER_LINEAR)[:nh, :nw]
            out[i] = cv2.resize(up, (w, h), interpolation=cv2.INTER_LINEAR)
        return out.reshape(*low_res.shape[:-2], h, w)

    def predict(
        self, image: SamImage, coords: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Decode a batch of prompts.

        ``coords`` [B, N, 2] in original pixels (x, y), ``labels`` [B, N]. Returns mask logits
        [B, C, H, W] at the original size and predicted IoUs [B, C].
        """
        logits, ious = self._decode(image, coords, labels)
        return (self.postprocess_masks(image, logits) if self._low_res else logits), ious

    def _decode(
        self, image: SamImage, coords: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``predict`` without the post-processing: the logits are low-resolution [B, C, h, w] when the
        decoder has ``low_res_masks`` (``postprocess_masks`` brings them to the original size), else the
        decoder's ``masks`` [B, C, H, W]."""
        coords = np.asarray(coords, dtype=np.float32)
        labels = np.asarray(labels, dtype=np.float32)
        if coords.ndim != 3 or coords.shape[2] != 2 or labels.shape != coords.shape[:2]:
            raise ValueError(
                f"prompts: coords must be [B, N, 2] and labels [B, N], got {coords.shape}, {labels.shape}"
            )
        b_total = coords.shape[0]
        h, w = image.orig_size
        chunk = self._dec_batch or self.points_per_batch
        model_coords = image.to_model_coords(coords)
        mh, mw = self._mask_hw
        masks_out, ious_out = [], []
        for s in range(0, b_total, chunk):
            pc, pl = model_coords[s : s + chunk], labels[s : s + chunk]
            b = pc.shape[0]
            if self._dec_batch is not None and b < self._dec_batch:  # fixed batch: pad with copies
                reps = self._dec_batch - b
                pc = np.concatenate([pc, np.repeat(pc[-1:], reps, axis=0)])
                pl = np.concatenate([pl, np.repeat(pl[-1:], reps, axis=0)])
            mi_b = self.decoder.inputs["mask_input"].shape[0]
            feeds = {
                "image_embeddings": image.embeddings,
                "point_coords": pc,
                "point_labels": pl,
                "mask_input": np.zeros((pc.shape[0] if mi_b is None else mi_b, 1, mh, mw), dtype=np.float32),
                "has_mask_input": np.zeros(self._dim_or(self.decoder.inputs["has_mask_input"].shape, 1)),
                "orig_im_size": np.array([h, w], dtype=np.float32),
            }
            if self._low_res:
                masks, ious = self.decoder.run(feeds, ("low_res_masks", "iou_predictions"))
                if masks.ndim != 4 or masks.shape[0] != pc.shape[0]:
                    raise self.decoder.error(
                        f"low_res_masks output of shape {list(masks.shape)} for {pc.shape[0]} prompts",
                        f"low_res_masks[{pc.shape[0]}, C, {mh}, {mw}] ({_DECODER_EXPECTED})",
                    )
            else:
                masks, ious = self.decoder.run(feeds, DECODER_OUTPUTS)
                if masks.ndim != 4 or masks.shape[0] != pc.shape[0] or masks.shape[2:] != (h, w):
                    raise self.decoder.error(
                        f"masks output of shape {list(masks.shape)} for {pc.shape[0]} prompts on a {h}x{w} "
                        "image",
                        f"masks[{pc.shape[0]}, C, {h}, {w}] ({_DECODER_EXPECTED})",
                    )
            ious = ious.reshape(masks.shape[0], -1)
            if ious.shape[1] != masks.shape[1]:
                raise self.decoder.error(
                    f"iou_predictions of shape {list(ious.shape)} for masks {list(masks.shape)}",
                    _DECODER_EXPECTED,
                )
            masks_out.append(masks[:b].astype(np.float32, copy=False))
            ious_out.append(ious[:b].astype(np.float32, copy=False))
        if not masks_out:
            hw = (mh, mw) if self._low_res else (h, w)
            return np.zeros((0, 1, *hw), np.float32), np.zeros((0, 1), np.float32)
        if len(masks_out) == 1:  # the usual case in ``generate``: no copy of the (large) mask logits
            return masks_out[0], ious_out[0]
        return np.concatenate(masks_out), np.concatenate(ious_out)

    @staticmethod
    def _dim_or(shape: tuple[int | None, ...], default: int) -> tuple[int, ...]:
        return tuple(default if d is None else d for d in shape) if shape else ()

    # ------------------------------------------------------------------ automatic masks (M_s)
    def generate(self, image: SamImage) -> list[MaskRecord]:
        """Grid-prompted masks that pass the predicted-IoU and stability filters, after NMS and cleanup."""
        h, w = image.orig_size
        grid = build_point_grid(self.points_per_side, h, w)
        kept: list[MaskRecord] = []
        step = self._dec_batch or self.points_per_batch
        for s in range(0, grid.shape[0], step):
            pts = grid[s : s + step]
            b = pts.shape[0]
            # a single point prompt plus segment-anything's padding point (0, 0) with label -1
            coords = np.stack([pts, np.zeros_like(pts)], axis=1)
            labels = np.tile(np.array([[1.0, -1.0]], dtype=np.float32), (b, 1))
            logits, ious = self._decode(image, coords, labels)
            c = logits.shape[1]
            # 4 outputs = [single-mask token, 3 multimask tokens]; the generator uses the multimask ones
            chans = np.arange(1, 4) if c == 4 else np.arange(c)
            sub = ious[:, chans]
            # a NaN or inf predicted IoU is a failed prediction, never a confident one (inf would win
            # every pixel when painting): such masks are dropped like those below the threshold
            bi, ci = np.nonzero(np.isfinite(sub) & (sub > self.filters.pred_iou_thresh))
            if bi.size == 0:
                continue
            sel = logits[bi, chans[ci]]  # copies only the masks that passed: [K, H, W]
            if self._low_res:  # upscaled only for the masks that passed
                sel = self.postprocess_masks(image, sel)
            sel_iou = sub[bi, ci]
            stab = stability_score(sel, self.filters.mask_threshold, self.filters.stability_score_offset)
            ok = stab >= self.filters.stability_score_thresh
            if not ok.any():
                continue
            kept.extend(masks_to_records(sel[ok] > self.filters.mask_threshold, sel_iou[ok], stab[ok]))
        # NMS first (it removes most masks, so the clean-up runs on few), clean-up, NMS again on the
        # cleaned boxes; segment-anything's second NMS prefers unchanged masks, ours the predicted IoU
        kept = mask_nms(kept, self.filters.box_nms_thresh)
        cleaned = [remove_small_regions(r, self.filters.min_region_area)[0] for r in kept]
        return mask_nms([r for r in cleaned if r is not None], self.filters.box_nms_thresh)

    # ------------------------------------------------------------------ box prompts (M_d)
    def segment_boxes(
        self, image: SamImage, boxes: np.ndarray, names: list[str | None] | None = None
    ) -> list[MaskRecord]:
        """One mask per box prompt [M, 4] (x0, y0, x1, y1 in original pixels), keeping ``names``.

        Box prompts are the two corners with labels 2 and 3; with a 4-output decoder the single-mask
        token (output 0) is used, as segment-anything's predictor does for ``multimask_output=False``,
        otherwise the output with the highest predicted IoU. Score = that predicted IoU; a mask whose
        predicted IoU is NaN or inf is dropped (with a warning).
        """
        boxes = np.asarray(boxes, dtype=np.float32).reshape(-1, 4)
        if names is not None and len(names) != boxes.shape[0]:
            raise ValueError(f"{len(names)} names for {boxes.shape[0]} boxes")
        if boxes.shape[0] == 0:
            return []
        h, w = image.orig_size
        coords = boxes.reshape(-1, 2, 2)
        labels = np.tile(np.array([[2.0, 3.0]], dtype=np.float32), (boxes.shape[0], 1))
        logits, ious = self._decode(image, coords, labels)
        best = np.where(np.isfinite(ious), ious, -np.inf).argmax(axis=1)  # argmax alone would pick a NaN
        idx = np.zeros(len(boxes), dtype=np.int64) if logits.shape[1] == 4 else best
        ar = np.arange(len(boxes))
        sel_logits, sel_ious = logits[ar, idx], ious[ar, idx]
        # a NaN/inf predicted IoU would become the segment's score, then a NaN Gaussian confidence
        # (or an inf one that wins every pixel when painting): such masks are dropped
        finite = np.isfinite(sel_ious)
        if not finite.all():
            log.warning(
                "SAM decoder gave a non-finite predicted IoU for %d of %d box prompts: their masks are "
                "dropped",
                int((~finite).sum()),
                len(boxes),
            )
            sel_logits, sel_ious = sel_logits[finite], sel_ious[finite]
            if names is not None:
                names = [n for n, f in zip(names, finite) if f]
            if not finite.any():
                return []
        if self._low_res:
            sel_logits = self.postprocess_masks(image, sel_logits)
        stab = stability_score(sel_logits, self.filters.mask_threshold, self.filters.stability_score_offset)
        recs = masks_to_records(sel_logits > self.filters.mask_threshold, sel_ious, stab, names)
        cleaned = [remove_small_regions(r, self.filters.min_region_area)[0] for r in recs]
        return [r for r in cleaned if r is not None]

    def __call__(self, rgb: np.ndarray, depth: np.ndarray | None = None) -> Segmentation:
        """M_s for one frame: SAM's automatic masks painted into an int32 id map (depth is unused)."""
        image = self.embed(rgb)
        return paint_masks(self.generate(image), image.orig_size, self.filters.min_region_area)
