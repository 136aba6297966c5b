"""Tiny ONNX models with the input/output signatures of real segmentation exports, built with onnx.helper.

They let the tests run ogscene3d's real pre/post-processing, prompting, filtering, NMS, painting and
fusion code against models whose answers are known in closed form:

- SAM encoder: average-pools the (preprocessed) image into a [1, 256, 64, 64] embedding.
- SAM decoder: for a point prompt, output c is a disc of radius ``radii[c]`` around the first prompt point
  (logit = slopes[c] * (radii[c] - distance)); for a box prompt (first label 2) every output is the box
  (logit = 10 * signed distance to the nearest box edge). Predicted IoUs are constants per output
  (``ious`` for points, ``box_iou`` for boxes). The geometry is evaluated in original pixels (scale from
  ``orig_im_size``, so the prompt transform is exercised) at the centres of the 256 x 256 low-resolution
  mask grid (``low_res_masks``); ``masks`` is made from those as segment-anything's ``SamOnnxModel``
  makes it (bilinear to 1024 x 1024, crop the padding, bilinear to ``orig_im_size``), optionally with
  the crop frozen at the export's dummy aspect ratio as segment-anything 1.0 (PyPI) exports it.
- Detector: returns fixed detections (in the letterboxed input frame) in one of the common layouts.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 17


def _save(graph: onnx.GraphProto, path: str | Path, metadata: dict[str, str] | None = None) -> Path:
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = 8
    if metadata:
        helper.set_model_props(model, metadata)
    onnx.checker.check_model(model)
    path = Path(path)
    onnx.save(model, str(path))
    return path


def _const(name: str, value: np.ndarray) -> onnx.TensorProto:
    return numpy_helper.from_array(np.asarray(value), name)


def make_sam_encoder(
    path: str | Path,
    size: int = 1024,
    layout: str = "nchw",
    dtype: str = "float",
    symbolic: bool = False,
    emb_size: int = 64,
) -> Path:
    """Encoder ``image``[1,3,S,S] (nchw), ``input_image``[S,S,3] (hwc) or [1,S,S,3] (nhwc) -> embeddings.

    The embedding is the (S/emb_size)-pixel average pool of the input ([1, 256, emb_size, emb_size], 64
    as SAM's), spread over 256 channels by a 1x1 convolution (channel c = pooled input channel c % 3).
    """
    elem = TensorProto.FLOAT if dtype == "float" else TensorProto.UINT8
    s: int | str = "S" if symbolic else size
    nodes = []
    inits = []
    if layout == "nchw":
        inp = helper.make_tensor_value_info("image", elem, [1, 3, s, s])
        x = "image"
    else:
        shape = [s, s, 3] if layout == "hwc" else [1, s, s, 3]
        inp = helper.make_tensor_value_info("input_image", elem, shape)
        nodes.append(helper.make_node("Cast", ["input_image"], ["xf"], to=TensorProto.FLOAT))
        if layout == "hwc":
            nodes.append(helper.make_node("Transpose", ["xf"], ["xt"], perm=[2, 0, 1]))
            inits.append(_const("ax0", np.array([0], dtype=np.int64)))
            nodes.append(helper.make_node("Unsqueeze", ["xt", "ax0"], ["x4"]))
        else:
            nodes.append(helper.make_node("Transpose", ["xf"], ["x4"], perm=[0, 3, 1, 2]))
        x = "x4"
    if symbolic and layout != "nchw":
        # like samexporter's --use-preprocess exports: the graph pads the resized image to S x S itself
        inits.append(_const("full", np.array([size, size], dtype=np.int64)))
        inits.append(_const("zeros6", np.zeros(6, dtype=np.int64)))  # begins, then N and C ends
        inits.append(_const("hw_idx", np.array([2, 3], dtype=np.int64)))
        nodes += [
            helper.make_node("Shape", [x], ["xshape"]),
            helper.make_node("Gather", ["xshape", "hw_idx"], ["xhw"], axis=0),
            helper.make_node("Sub", ["full", "xhw"], ["padhw"]),
            helper.make_node("Concat", ["zeros6", "padhw"], ["pads"], axis=0),
            helper.make_node("Pad", [x, "pads"], ["xpad"]),
        ]
        x = "xpad"
    k = size // emb_size
    nodes.append(helper.make_node("AveragePool", [x], ["pooled"], kernel_shape=[k, k], strides=[k, k]))
    w = np.zeros((256, 3, 1, 1), dtype=np.float32)
    w[np.arange(256), np.arange(256) % 3] = 1.0
    inits.append(_const("w", w))
    nodes.append(helper.make_node("Conv", ["pooled", "w"], ["image_embeddings"]))
    out = helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, emb_size, emb_size])
    graph = helper.make_graph(nodes, "sam_encoder", [inp], [out], initializer=inits)
    return _save(graph, path)


def make_sam_decoder(
    path: str | Path,
    radii: Sequence[float] = (6.0, 10.0, 16.0, 20.0),
    slopes: Sequence[float] = (10.0, 10.0, 10.0, 0.3),
    ious: Sequence[float] = (0.99, 0.80, 0.95, 0.97),
    box_iou: float = 0.96,
    batch: int | None = None,
    input_size: int = 1024,
    drop_input: str | None = None,
    baked_crop: tuple[int, int] | None = None,
    low_res_output: bool = True,
) -> Path:
    """Decoder with segment-anything's interface; ``batch`` None = dynamic prompt batch, else fixed.

    ``drop_input`` leaves one input out (to test the error for a wrong model). ``baked_crop`` (h', w'):
    ``masks`` crops the upscaled logits to this fixed size instead of the one ``orig_im_size`` gives, as
    segment-anything 1.0's export does ((683, 1024), from its 1500 x 2250 dummy ``orig_im_size``).
    ``low_res_output`` False: no ``low_res_masks`` output (exports that give only masks and IoUs).
    """
    c = len(radii)
    low = input_size // 4  # the low-resolution mask grid (256 for SAM's 1024)
    b: int | str = "B" if batch is None else batch
    f = TensorProto.FLOAT
    ins = {
        "image_embeddings": helper.make_tensor_value_info("image_embeddings", f, [1, 256, 64, 64]),
        "point_coords": helper.make_tensor_value_info("point_coords", f, [b, "N", 2]),
        "point_labels": helper.make_tensor_value_info("point_labels", f, [b, "N"]),
        "mask_input": helper.make_tensor_value_info("mask_input", f, [1, 1, 256, 256]),
        "has_mask_input": helper.make_tensor_value_info("has_mask_input", f, [1]),
        "orig_im_size": helper.make_tensor_value_info("orig_im_size", f, [2]),
    }
    inits = []
    if drop_input:
        # the graph still reads the tensor: make it a constant so that the model stays valid
        del ins[drop_input]
        inits.append(_const(drop_input, np.ones((1, 2), dtype=np.float32)))
    inits += [
        _const("i0", np.array(0, dtype=np.int64)),
        _const("i1", np.array(1, dtype=np.int64)),
        _const("half", np.array(0.5, dtype=np.float32)),
        _const("zero_f", np.array(0.0, dtype=np.float32)),
        _const("ten", np.array(10.0, dtype=np.float32)),
        _const("two", np.array(2.0, dtype=np.float32)),
        _const("inv_size", np.array(1.0 / input_size, dtype=np.float32)),
        _const("shape_b1", np.array([-1, 1], dtype=np.int64)),
        _const("shape_b111", np.array([-1, 1, 1, 1], dtype=np.int64)),
        _const("radii", np.asarray(radii, dtype=np.float32).reshape(1, c, 1, 1)),
        _const("slopes", np.asarray(slopes, dtype=np.float32).reshape(1, c, 1, 1)),
        _const("ious_pt", np.asarray(ious, dtype=np.float32).reshape(1, c)),
        _const("ious_box", np.full((1, c), box_iou, dtype=np.float32)),
        _const("zeros_c", np.zeros((1, c, 1, 1), dtype=np.float32)),
        _const("full_hw", np.array([input_size, input_size], dtype=np.int64)),
        _const("axes23", np.array([2, 3], dtype=np.int64)),
        _const("zeros2", np.zeros(2, dtype=np.int64)),
        _const("s0", np.array([0], dtype=np.int64)),
        _const("s2", np.array([2], dtype=np.int64)),
        _const("size_f", np.array(float(input_size), dtype=np.float32)),
        # centres of the low-resolution grid's cells in the model frame (one cell = 4 model pixels)
        _const("low_y", (4.0 * np.arange(low, dtype=np.float32) + 2.0).reshape(1, 1, low, 1)),
        _const("low_x", (4.0 * np.arange(low, dtype=np.float32) + 2.0).reshape(1, 1, 1, low)),
    ]
    ends = "prepadded"
    if baked_crop is not None:
        inits.append(_const("crop_ends", np.asarray(baked_crop, dtype=np.int64)))
        ends = "crop_ends"
    n = helper.make_node
    nodes = [
        # original-pixel scale of the model frame: longest side / encoder size
        n("ReduceMax", ["orig_im_size"], ["long_side"], keepdims=0),
        n("Mul", ["long_side", "inv_size"], ["scale"]),
        n("Mul", ["point_coords", "scale"], ["pts"]),  # [B, N, 2] original pixels
        n("Gather", ["pts", "i0"], ["p0"], axis=1),  # [B, 2]
        n("Gather", ["pts", "i1"], ["p1"], axis=1),
        n("Gather", ["p0", "i0"], ["x0v"], axis=1),  # [B]
        n("Gather", ["p0", "i1"], ["y0v"], axis=1),
        n("Gather", ["p1", "i0"], ["x1v"], axis=1),
        n("Gather", ["p1", "i1"], ["y1v"], axis=1),
        n("Reshape", ["x0v", "shape_b111"], ["x0"]),
        n("Reshape", ["y0v", "shape_b111"], ["y0"]),
        n("Reshape", ["x1v", "shape_b111"], ["x1"]),
        n("Reshape", ["y1v", "shape_b111"], ["y1"]),
        # the low-resolution grid's cell centres in original pixels
        n("Mul", ["low_y", "scale"], ["Y"]),
        n("Mul", ["low_x", "scale"], ["X"]),
        # discs around the first point
        n("Sub", ["X", "x0"], ["dx"]),
        n("Sub", ["Y", "y0"], ["dy"]),
        n("Mul", ["dx", "dx"], ["dx2"]),
        n("Mul", ["dy", "dy"], ["dy2"]),
        n("Add", ["dx2", "dy2"], ["d2"]),
        n("Sqrt", ["d2"], ["dist"]),  # [B, 1, H, W]
        n("Sub", ["radii", "dist"], ["rad_minus"]),  # [B, C, H, W]
        n("Mul", ["rad_minus", "slopes"], ["disc_logits"]),
        # boxes between the first two points
        n("Sub", ["X", "x0"], ["bl"]),
        n("Sub", ["x1", "X"], ["br"]),
        n("Sub", ["Y", "y0"], ["bt"]),
        n("Sub", ["y1", "Y"], ["bb"]),
        n("Min", ["bl", "br", "bt", "bb"], ["inside"]),
        n("Mul", ["inside", "ten"], ["box1"]),
        n("Add", ["box1", "zeros_c"], ["box_logits"]),  # broadcast to [B, C, H, W]
        # which prompt kind: first label == 2
        n("Gather", ["point_labels", "i0"], ["lab0"], axis=1),  # [B]
        n("Equal", ["lab0", "two"], ["is_box_v"]),
        n("Reshape", ["is_box_v", "shape_b111"], ["is_box"]),
        n("Where", ["is_box", "box_logits", "disc_logits"], ["low_res_masks"]),
        n("Reshape", ["is_box_v", "shape_b1"], ["is_box2"]),
        n("Mul", ["x0v", "zero_f"], ["zb"]),
        n("Reshape", ["zb", "shape_b1"], ["zb2"]),  # [B, 1] zeros: gives the IoUs their batch size
        n("Add", ["ious_pt", "zb2"], ["ious_pt_b"]),
        n("Add", ["ious_box", "zb2"], ["ious_box_b"]),
        n("Where", ["is_box2", "ious_box_b", "ious_pt_b"], ["iou_predictions"]),
        # SamOnnxModel.mask_postprocessing: bilinear to S x S, crop to the resized image, bilinear to H x W
        n("Shape", ["low_res_masks"], ["lr_shape"]),
        n("Slice", ["lr_shape", "s0", "s2"], ["bc"]),
        n("Concat", ["bc", "full_hw"], ["up_sizes"], axis=0),
        n("Resize", ["low_res_masks", "", "", "up_sizes"], ["up"], mode="linear"),
        n("Div", ["size_f", "long_side"], ["pre_scale"]),
        n("Mul", ["orig_im_size", "pre_scale"], ["pre_f"]),
        n("Add", ["pre_f", "half"], ["pre_h"]),
        n("Floor", ["pre_h"], ["pre_fl"]),
        n("Cast", ["pre_fl"], ["prepadded"], to=TensorProto.INT64),
        n("Slice", ["up", "zeros2", ends, "axes23"], ["crop"]),
        n("Cast", ["orig_im_size"], ["hw_int"], to=TensorProto.INT64),
        n("Concat", ["bc", "hw_int"], ["out_sizes"], axis=0),
        n("Resize", ["crop", "", "", "out_sizes"], ["masks"], mode="linear"),
    ]
    outs = [
        helper.make_tensor_value_info("masks", f, [b, c, "H", "W"]),
        helper.make_tensor_value_info("iou_predictions", f, [b, c]),
        helper.make_tensor_value_info("low_res_masks", f, [b, c, low, low]),
    ][: 3 if low_res_output else 2]
    graph = helper.make_graph(nodes, "sam_decoder", list(ins.values()), outs, initializer=inits)
    return _save(graph, path)


def make_detector(
    path: str | Path,
    boxes_xyxy: np.ndarray,
    class_scores: np.ndarray,
    layout: str = "yolo_head",
    size: int = 640,
    head_transposed: bool = False,
    metadata: dict[str, str] | None = None,
) -> Path:
    """Detector returning fixed detections given in the letterboxed input frame.

    ``boxes_xyxy`` [A, 4], ``class_scores`` [A, K]. Layouts: "yolo_head" one output [1, 4+K, A]
    (``head_transposed``: [1, A, 4+K]), "dense" boxes [1, A, 4] + scores [1, A, K], "nms" num_dets +
    boxes [1, A, 4] + scores [1, A] + labels [1, A] (argmax of class_scores), "ultralytics_nms" one
    output0 [1, 300, 6] of rows x0, y0, x1, y1, score, class (zero rows after the detections) with the
    metadata Ultralytics writes for ``export(format="onnx", nms=True)``. ``metadata``: extra model
    metadata (ONNX metadata_props).
    """
    boxes_xyxy = np.asarray(boxes_xyxy, dtype=np.float32)
    class_scores = np.asarray(class_scores, dtype=np.float32)
    a, k = class_scores.shape
    f = TensorProto.FLOAT
    inp = helper.make_tensor_value_info("images", f, [1, 3, size, size])
    n = helper.make_node
    # 0 * mean(image): the outputs formally depend on the input, as a real detector's do
    nodes = [n("ReduceMean", ["images"], ["m"], keepdims=0), n("Mul", ["m", "zero"], ["z"])]
    inits = [_const("zero", np.array(0.0, dtype=np.float32))]
    outs = []

    def emit(name: str, value: np.ndarray, elem: int = f) -> None:
        inits.append(_const(name + "_c", value))
        if elem == f:
            nodes.append(n("Add", [name + "_c", "z"], [name]))
        else:
            nodes.append(n("Identity", [name + "_c"], [name]))
        outs.append(helper.make_tensor_value_info(name, elem, list(value.shape)))

    if layout == "yolo_head":
        cx = (boxes_xyxy[:, 0] + boxes_xyxy[:, 2]) / 2
        cy = (boxes_xyxy[:, 1] + boxes_xyxy[:, 3]) / 2
        w = boxes_xyxy[:, 2] - boxes_xyxy[:, 0]
        h = boxes_xyxy[:, 3] - boxes_xyxy[:, 1]
        head = np.concatenate([np.stack([cx, cy, w, h], axis=1), class_scores], axis=1)  # [A, 4+K]
        emit("output0", (head if head_transposed else head.T)[None].astype(np.float32))
    elif layout == "dense":
        emit("boxes", boxes_xyxy[None])
        emit("scores", class_scores[None])
    elif layout == "ultralytics_nms":
        rows = np.zeros((300, 6), np.float32)
        rows[:a, :4] = boxes_xyxy
        rows[:a, 4] = class_scores.max(axis=1)
        rows[:a, 5] = class_scores.argmax(axis=1)
        emit("output0", rows[None])
        metadata = {
            "author": "Ultralytics",
            "task": "detect",
            "names": str(dict(enumerate(f"class{i}" for i in range(k)))),
            "args": "{'batch': 1, 'half': False, 'dynamic': False, 'simplify': True, 'nms': True}",
            **(metadata or {}),
        }
    elif layout == "nms":
        labels = class_scores.argmax(axis=1).astype(np.int64)
        scores = class_scores.max(axis=1).astype(np.float32)
        emit("num_dets", np.array([[a]], dtype=np.int64), TensorProto.INT64)
        emit("boxes", boxes_xyxy[None])
        emit("scores", scores[None])
        emit("labels", labels[None], TensorProto.INT64)
    else:
        raise ValueError(layout)
    graph = helper.make_graph(nodes, "detector", [inp], outs, initializer=inits)
    return _save(graph, path, metadata)
