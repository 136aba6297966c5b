"""Open-vocabulary detection (YOLO-World style ONNX exports) with onnxruntime.

The exported detector has its vocabulary baked in (``model.set_classes([...])`` before export), so the
class names come from the config (``segmentation.detector_classes``, in the export's order).

Input: one image tensor ``[1, 3, S, S]`` float, RGB scaled to [0, 1], letterboxed (aspect kept, padded
with grey 114 and centred) as Ultralytics and YOLO-World preprocess.

Output layouts understood (batch 1):
- a single YOLO head ``[1, 4 + K, A]`` (or ``[1, A, 4 + K]``): per anchor cx, cy, w, h in input pixels and
  K class scores; we threshold, run class-wise NMS and keep the best ``max_detections``;
- separate ``boxes [1, A, 4]`` and ``scores [1, A, K]`` (YOLO-World's export without NMS): the same;
- separate ``boxes [1, N, 4]``, ``scores [1, N]``, ``labels [1, N]`` and optionally ``num_dets`` (exports
  with NMS inside): only thresholded. Box format ``xyxy`` unless ``box_format="cxcywh"``;
- Ultralytics' ``export(format="onnx", nms=True)`` (or an end-to-end model): one output ``[1, N, 6]`` of
  rows x0, y0, x1, y1, score, class in input pixels, NMS done: only thresholded. It has the shape of a
  transposed head with K = 2, so it is recognised by the metadata Ultralytics writes into the file
  (``args`` with ``nms: True``, or ``end2end: True``), whose ``names`` must then count the configured
  class names.
"""

from __future__ import annotations

import ast
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..config import SegmentationConfig, section_values
from ..errors import ConfigError
from .masks import nms
from .onnx_session import OnnxModel
from .sam_onnx import check_rgb

log = logging.getLogger(__name__)

BOX_NAMES = ("boxes", "bboxes", "det_boxes", "box", "pred_boxes")
SCORE_NAMES = ("scores", "det_scores", "confidences", "pred_scores")
LABEL_NAMES = ("labels", "det_classes", "classes", "class_ids", "label", "pred_labels")
NUM_NAMES = ("num_dets", "num_detections", "num")
_EXPECTED = (
    "one image input [1,3,S,S] float and either one output [1,4+K,A] (YOLO head, K = number of class names) "
    "or outputs boxes[1,A,4] + scores[1,A,K], or boxes[1,N,4] + scores[1,N] + labels[1,N] (+ num_dets), "
    "or Ultralytics' nms=True output [1,N,6] (x0,y0,x1,y1,score,class) with its metadata"
)


@dataclass
class Detections:
    """Detections in original image pixels: ``boxes`` float32 [M, 4] (x0, y0, x1, y1), ``scores`` [M],
    ``labels`` int64 [M] (indices into the class list) and ``names`` (their class names), best first."""

    boxes: np.ndarray
    scores: np.ndarray
    labels: np.ndarray
    names: list[str]

    def __len__(self) -> int:
        return int(self.boxes.shape[0])


def cxcywh_to_xyxy(b: np.ndarray) -> np.ndarray:
    out = np.empty_like(b)
    out[..., 0] = b[..., 0] - b[..., 2] / 2
    out[..., 1] = b[..., 1] - b[..., 3] / 2
    out[..., 2] = b[..., 0] + b[..., 2] / 2
    out[..., 3] = b[..., 1] + b[..., 3] / 2
    return out


def require_detector(config: SegmentationConfig) -> None:
    """ConfigError unless the section names a detector file (``segmentation.detector``)."""
    if not config.detector:
        raise ConfigError(
            "segmentation backend 'sam+detector' needs a detector ONNX file: set segmentation.detector "
            "(config or --set; `ogscene3d segment` also takes --detector)"
        )


class DetectorOnnx:
    """A YOLO-World style detector ONNX: ``det = DetectorOnnx(path, ["chair", ...]); d = det(rgb)``."""

    def __init__(
        self,
        path: str | Path,
        class_names: Sequence[str],
        *,
        score_thresh: float = 0.25,
        nms_thresh: float = 0.5,
        max_detections: int = 100,
        input_size: int = 640,
        box_format: str = "xyxy",
        provider: str = "auto",
    ) -> None:
        self.class_names = [str(c) for c in class_names]
        if not self.class_names:
            raise ConfigError(
                "segmentation.detector_classes is empty: list the class names the detector was "
                "exported with, in the export's order"
            )
        if box_format not in ("xyxy", "cxcywh"):
            raise ConfigError(f"segmentation.detector_box_format must be xyxy or cxcywh, got {box_format!r}")
        self.score_thresh = float(score_thresh)
        self.nms_thresh = float(nms_thresh)
        self.max_detections = int(max_detections)
        self.box_format = box_format
        self.model = OnnxModel(path, "open-vocabulary detector", provider)
        m = self.model
        if len(m.inputs) != 1:
            raise m.error(
                f"{len(m.inputs)} inputs (exports that take text embeddings at run time are not supported; "
                "export with the vocabulary set)",
                _EXPECTED,
            )
        info = next(iter(m.inputs.values()))
        if len(info.shape) != 4 or info.shape[1] not in (3, None) or np.dtype(info.dtype).kind != "f":
            raise m.error(f"input {info.describe()}", _EXPECTED)
        self._input = info.name
        self._hw = tuple(int(d) if d is not None else int(input_size) for d in info.shape[2:4])
        self._nms_rows = self._ultralytics_nms_rows()

    @classmethod
    def from_config(cls, config: SegmentationConfig) -> DetectorOnnx:
        """The detector that a ``segmentation`` config section describes.

        Args:
            config: the section; read are ``detector`` (the ONNX file), ``detector_classes`` (the
                vocabulary, in the export's order), ``detector_score_thresh``, ``detector_nms_thresh``,
                ``detector_max_detections``, ``detector_input_size``, ``detector_box_format`` and
                ``execution_provider``.

        Returns:
            The detector, its model file opened (ConfigError when ``detector`` is not set).
        """
        require_detector(config)
        names = ("score_thresh", "nms_thresh", "max_detections", "input_size", "box_format")
        return cls(
            config.detector,
            config.detector_classes,
            **section_values(config, names, "detector_"),
            provider=config.execution_provider,
        )

    def _ultralytics_nms_rows(self) -> bool:
        """Whether the file is an Ultralytics export with NMS inside (output [1, N, 6] of x0, y0, x1, y1,
        score, class), told by its metadata; checks the metadata's class names against the configured."""
        meta = self.model.session.get_modelmeta().custom_metadata_map or {}
        nms = re.search(r"['\"]nms['\"]\s*:\s*True", meta.get("args", "")) is not None
        if not (nms or meta.get("end2end") == "True"):
            return False
        try:
            names = ast.literal_eval(meta.get("names", ""))
        except (ValueError, SyntaxError):
            names = None
        if isinstance(names, dict) and names:
            exported = [str(names[i]) for i in sorted(names)]
            if len(exported) != len(self.class_names):
                raise self.model.error(
                    f"the export's metadata names {len(exported)} classes {exported[:8]}"
                    f"{'...' if len(exported) > 8 else ''} but {len(self.class_names)} class names are "
                    "configured",
                    "segmentation.detector_classes listing the export's classes in its order",
                )
            if exported != self.class_names:
                log.warning(
                    "%s: the configured detector classes %s differ from those in the export's metadata %s; "
                    "class k of the model is named by the k-th configured name",
                    self.model.path,
                    self.class_names,
                    exported,
                )
        return True

    def preprocess(self, rgb: np.ndarray) -> tuple[np.ndarray, float, tuple[int, int]]:
        """Letterboxed input [1, 3, S, S] in [0, 1], the resize ratio and the (left, top) padding."""
        rgb = check_rgb(rgb)
        h, w = rgb.shape[:2]
        th, tw = self._hw
        r = min(th / h, tw / w)
        nw, nh = min(tw, int(round(w * r))), min(th, int(round(h * r)))
        left, top = int(round((tw - nw) / 2 - 0.1)), int(round((th - nh) / 2 - 0.1))
        canvas = np.full((th, tw, 3), 114, dtype=np.uint8)
        interp = cv2.INTER_AREA if r < 1.0 else cv2.INTER_LINEAR
        canvas[top : top + nh, left : left + nw] = cv2.resize(rgb, (nw, nh), interpolation=interp)
        x = canvas.astype(np.float32).transpose(2, 0, 1)[None] / 255.0
        return x, r, (left, top)

    def _check_k(self, k: int, what: str) -> None:
        if k != len(self.class_names):
            raise self.model.error(
                f"{what} has {k} classes but {len(self.class_names)} class names are configured "
                f"({self.class_names[:8]}{'...' if len(self.class_names) > 8 else ''})",
                _EXPECTED,
            )

    def _decode(self, outs: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """(boxes xyxy [A,4] in input pixels, scores [A], labels [A], whether NMS is still to be done)."""
        k = len(self.class_names)
        named = {n.lower(): a for n, a in outs.items()}

        def pick(names: tuple[str, ...]) -> np.ndarray | None:
            for n in names:
                if n in named:
                    return named[n]
            return None

        boxes, scores, labels, num = pick(BOX_NAMES), pick(SCORE_NAMES), pick(LABEL_NAMES), pick(NUM_NAMES)
        if boxes is None and scores is None:
            heads = [a for a in outs.values() if a.ndim == 3 and a.shape[0] == 1]
            if len(heads) != 1:
                raise self.model.error("no recognisable detection outputs", _EXPECTED)
            head = heads[0][0]
            if self._nms_rows:  # Ultralytics nms=True: [N, 6] rows x0, y0, x1, y1, score, class
                if head.shape[1] != 6:
                    raise self.model.error(
                        f"output {list(heads[0].shape)} in an export with NMS inside (its metadata says so)",
                        "[1,N,6] rows of x0,y0,x1,y1,score,class",
                    )
                rows = head.astype(np.float32)
                return rows[:, :4], rows[:, 4], np.rint(rows[:, 5]).astype(np.int64), False
            if head.shape[0] == 4 + k:
                head = head.T
            elif head.shape[1] != 4 + k:
                raise self.model.error(
                    f"YOLO head output {list(heads[0].shape)} has no axis of size 4 + {k} "
                    f"(4 box values + one score per configured class name)",
                    _EXPECTED,
                )
            cls = head[:, 4:]
            lab = cls.argmax(axis=1)
            return cxcywh_to_xyxy(head[:, :4]), cls[np.arange(len(lab)), lab], lab, True
        if boxes is None or scores is None:
            raise self.model.error("a boxes output without scores, or scores without boxes", _EXPECTED)
        boxes = boxes.reshape(-1, 4).astype(np.float32)
        if self.box_format == "cxcywh":
            boxes = cxcywh_to_xyxy(boxes)
        if scores.ndim == 3 or (scores.ndim == 2 and labels is None and scores.shape[0] == boxes.shape[0]):
            cls = scores.reshape(boxes.shape[0], -1)
            self._check_k(cls.shape[1], f"scores output {list(scores.shape)}")
            lab = cls.argmax(axis=1)
            return boxes, cls[np.arange(len(lab)), lab], lab, True
        if labels is None:
            raise self.model.error("scores [1,N] without a labels output", _EXPECTED)
        scores = scores.reshape(-1).astype(np.float32)
        labels = labels.reshape(-1).astype(np.int64)
        if not (boxes.shape[0] == scores.shape[0] == labels.shape[0]):
            raise self.model.error(
                f"inconsistent detection counts boxes {boxes.shape[0]}, scores {scores.shape[0]}, "
                f"labels {labels.shape[0]}",
                _EXPECTED,
            )
        if num is not None:
            n = int(np.asarray(num).reshape(-1)[0])
            boxes, scores, labels = boxes[:n], scores[:n], labels[:n]
        return boxes, scores, labels, False

    def __call__(self, rgb: np.ndarray) -> Detections:
        """Detect objects in one uint8 RGB frame [H, W, 3]."""
        x, r, (left, top) = self.preprocess(rgb)
        names = [o for o in self.model.outputs]
        outs = dict(zip(names, self.model.run({self._input: x}, names)))
        boxes, scores, labels, need_nms = self._decode(outs)
        finite = np.all(np.isfinite(boxes), axis=1) & np.isfinite(scores)
        valid = finite & (scores >= self.score_thresh) & (labels >= 0)
        boxes, scores, labels = boxes[valid], scores[valid], labels[valid]
        if labels.size and labels.max() >= len(self.class_names):
            raise self.model.error(
                f"class index {int(labels.max())} returned but only {len(self.class_names)} class names are "
                "configured",
                _EXPECTED,
            )
        if need_nms:
            keep = nms(boxes, scores, self.nms_thresh, classes=labels)
        else:
            keep = np.argsort(-scores, kind="stable")
        keep = keep[: self.max_detections]
        boxes, scores, labels = boxes[keep], scores[keep], labels[keep]
        # undo the letterbox and clip to the image
        h, w = rgb.shape[:2]
        boxes = (boxes - np.array([left, top, left, top], dtype=np.float32)) / r
        boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(0, w)
        boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0, h)
        ok = (boxes[:, 2] - boxes[:, 0] >= 1.0) & (boxes[:, 3] - boxes[:, 1] >= 1.0)
        boxes, scores, labels = boxes[ok], scores[ok], labels[ok]
        return Detections(
            boxes.astype(np.float32),
            scores.astype(np.float32),
            labels.astype(np.int64),
            [self.class_names[int(i)] for i in labels],
        )
