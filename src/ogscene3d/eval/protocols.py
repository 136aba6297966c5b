"""Evaluation protocols: how predicted points/pixels are put against the ground truth.

Two 3D protocols from the literature are implemented; they count different things, so their
numbers are not interchangeable and every result names the protocol that produced it.

* ``"hovsg"`` (HOV-SG, ``application/eval/evaluate_sem_seg.py``): every ground-truth point takes the
  majority class of its k = 5 nearest *labelled* predicted points (ties go to the smallest class
  index, like ``np.bincount(...).argmax()``); predicted points with no class do not vote. Metrics
  are counted on ground-truth points. Background classes (default wall/floor/ceiling) are left out
  of the means, but their points stay in the count, so predicting ``table`` on a wall point is a
  false positive of ``table`` (``ignored_gt_points="false_positive"``), as in HOV-SG's metric code.
* ``"conceptgraphs"`` (ConceptGraphs, ``scripts/eval_replica_semseg.py``): every predicted point takes
  the class of its nearest ground-truth point as its reference; metrics are counted on predicted
  points. Predicted points whose reference is an ignored class are dropped. Predicted points with
  no class count as misses of their reference class.

Nearest neighbours come from a KD-tree (``scipy.spatial.cKDTree``), queried in chunks, so memory is
O(N + M), never O(N * M).

The 2D novel-view protocol (paper Table I, following OpenGS-SLAM) accumulates one confusion matrix
over all held-out views: pixels with ground truth < 0 are void, rendered pixels with no label
(-1) or a label the mapping does not name are misses.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Literal

import numpy as np

from .metrics import IgnoredGtPoints, SegmentationMetrics, confusion_matrix, segmentation_metrics

Protocol3D = Literal["hovsg", "conceptgraphs"]
PROTOCOLS: tuple[str, ...] = ("hovsg", "conceptgraphs")

#: HOV-SG's background classes (its Replica evaluation also drops door/window; pass them explicitly).
HOVSG_DEFAULT_IGNORE: tuple[str, ...] = ("wall", "floor", "ceiling")
#: ConceptGraphs' default run ignores only its catch-all "other" class.
CONCEPTGRAPHS_DEFAULT_IGNORE: tuple[str, ...] = ("other",)

_CHUNK = 1 << 16


def _points(x: Any, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name}: expected an [N, 3] array of points, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or inf coordinates")
    return a


def _labels(x: Any, n: int, name: str) -> np.ndarray:
    a = np.asarray(x)
    if a.ndim != 1 or a.shape[0] != n:
        raise ValueError(f"{name}: expected [{n}] labels, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"{name}: expected integer labels, got dtype {a.dtype}")
    return a.astype(np.int64, copy=False)


def nearest_neighbors(
    ref_points: Any, query_points: Any, k: int = 1, max_distance: float | None = None, workers: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """k nearest reference points of every query point (KD-tree, chunked queries).

    Args:
        ref_points: [M, 3] points to search in (M >= 1).
        query_points: [N, 3] points to search for.
        k: neighbours per query; clipped to M.
        max_distance: neighbours farther than this (metres) are reported as index -1, distance inf.
        workers: threads for the KD-tree query (-1 = all cores).

    Returns:
        (distances [N, k] float64, indices [N, k] int64), nearest first.
    """
    from scipy.spatial import cKDTree

    ref = _points(ref_points, "ref_points")
    qry = _points(query_points, "query_points")
    if ref.shape[0] == 0:
        raise ValueError("ref_points is empty: nothing to search in")
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    k = min(k, ref.shape[0])
    tree = cKDTree(ref)
    dist = np.empty((qry.shape[0], k), dtype=np.float64)
    idx = np.empty((qry.shape[0], k), dtype=np.int64)
    bound = np.inf if max_distance is None else float(max_distance)
    for s in range(0, qry.shape[0], _CHUNK):
        d, i = tree.query(qry[s : s + _CHUNK], k=k, distance_upper_bound=bound, workers=workers)
        dist[s : s + _CHUNK] = np.asarray(d).reshape(-1, k)
        idx[s : s + _CHUNK] = np.asarray(i).reshape(-1, k)
    # cKDTree marks "nothing within the bound" with index M.
    idx[idx >= ref.shape[0]] = -1
    return dist, idx


def majority_vote(votes: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Row-wise most frequent value of an [N, k] int array; ties go to the smallest value.

    Entries where ``valid`` is False do not vote; a row without any valid vote yields -1.
    """
    v = np.asarray(votes, dtype=np.int64)
    if v.ndim != 2:
        raise ValueError(f"votes must be [N, k], got shape {v.shape}")
    if valid is None:
        valid = np.ones(v.shape, dtype=bool)
    out = np.full(v.shape[0], -1, dtype=np.int64)
    big = np.iinfo(np.int64).max
    for s in range(0, v.shape[0], _CHUNK):
        vv = np.where(valid[s : s + _CHUNK], v[s : s + _CHUNK], big)
        vv.sort(axis=1)
        # count[i, j] = how many valid votes of row i equal vv[i, j]; invalid entries get count 0.
        count = (vv[:, :, None] == vv[:, None, :]).sum(axis=2)
        count[vv == big] = 0
        # Rows are sorted ascending, so argmax picks the smallest value among the most frequent.
        best = np.argmax(count, axis=1)
        win = vv[np.arange(vv.shape[0]), best]
        out[s : s + _CHUNK] = np.where(win == big, -1, win)
    return out


def hovsg_protocol(
    pred_points: Any,
    pred_classes: Any,
    gt_points: Any,
    gt_classes: Any,
    class_names: Sequence[str],
    ignore: Iterable[str | int] | None = HOVSG_DEFAULT_IGNORE,
    k: int = 5,
    ignored_gt_points: IgnoredGtPoints = "false_positive",
    workers: int = 1,
) -> SegmentationMetrics:
    """HOV-SG 3D semantic segmentation protocol (see the module docstring).

    Args:
        pred_points: [N, 3] predicted points (Gaussian centres), metres, same frame as the GT.
        pred_classes: [N] GT-class index per predicted point, -1 = no class (does not vote).
        gt_points: [M, 3] ground-truth points.
        gt_classes: [M] class index per GT point, -1 = void.
        class_names: the C ground-truth class names.
        ignore: background class names/indices left out of the means.
        k: neighbours in the majority vote (HOV-SG uses 5).
        ignored_gt_points: HOV-SG keeps them as false positives; "drop" gives the ScanNet convention.
    """
    pp = _points(pred_points, "pred_points")
    pc = _labels(pred_classes, pp.shape[0], "pred_classes")
    gp = _points(gt_points, "gt_points")
    gc = _labels(gt_classes, gp.shape[0], "gt_classes")
    labelled = pc >= 0
    if labelled.any():
        _, idx = nearest_neighbors(pp[labelled], gp, k=k, workers=workers)
        votes = pc[labelled][np.maximum(idx, 0)]
        voted = majority_vote(votes, idx >= 0)
    else:
        voted = np.full(gp.shape[0], -1, dtype=np.int64)
    cm = confusion_matrix(gc, voted, len(class_names))
    desc = f"hovsg (k={k} nearest predicted points vote for each GT point; counted on GT points)"
    return segmentation_metrics(cm, class_names, ignore, ignored_gt_points, protocol=desc)


def conceptgraphs_protocol(
    pred_points: Any,
    pred_classes: Any,
    gt_points: Any,
    gt_classes: Any,
    class_names: Sequence[str],
    ignore: Iterable[str | int] | None = CONCEPTGRAPHS_DEFAULT_IGNORE,
    workers: int = 1,
) -> SegmentationMetrics:
    """ConceptGraphs 3D semantic segmentation protocol (see the module docstring).

    Arguments as :func:`hovsg_protocol`; predicted points whose nearest GT point is void are skipped.
    """
    pp = _points(pred_points, "pred_points")
    pc = _labels(pred_classes, pp.shape[0], "pred_classes")
    gp = _points(gt_points, "gt_points")
    gc = _labels(gt_classes, gp.shape[0], "gt_classes")
    if pp.shape[0] == 0:
        raise ValueError("pred_points is empty: the ConceptGraphs protocol counts on predicted points")
    _, idx = nearest_neighbors(gp, pp, k=1, workers=workers)
    ref = gc[idx[:, 0]]
    cm = confusion_matrix(ref, pc, len(class_names))
    desc = (
        "conceptgraphs (each predicted point takes its nearest GT point's class; counted on predicted points)"
    )
    return segmentation_metrics(cm, class_names, ignore, "drop", protocol=desc)


def evaluate_semantic_3d(
    pred_points: Any,
    pred_classes: Any,
    gt_points: Any,
    gt_classes: Any,
    class_names: Sequence[str],
    protocol: Protocol3D = "hovsg",
    ignore: Iterable[str | int] | None = None,
    k: int = 5,
    workers: int = 1,
) -> SegmentationMetrics:
    """Dispatch to :func:`hovsg_protocol` or :func:`conceptgraphs_protocol`.

    ``ignore=None`` uses the protocol's default (HOV-SG: wall/floor/ceiling, ConceptGraphs: other).
    """
    if protocol == "hovsg":
        ign = HOVSG_DEFAULT_IGNORE if ignore is None else ignore
        return hovsg_protocol(
            pred_points, pred_classes, gt_points, gt_classes, class_names, ign, k=k, workers=workers
        )
    if protocol == "conceptgraphs":
        ign = CONCEPTGRAPHS_DEFAULT_IGNORE if ignore is None else ignore
        return conceptgraphs_protocol(
            pred_points, pred_classes, gt_points, gt_classes, class_names, ign, workers=workers
        )
    raise ValueError(f"unknown protocol {protocol!r}; expected one of {PROTOCOLS}")


def label_lookup(mapping: Mapping[int, int] | np.ndarray, labels: Any) -> np.ndarray:
    """Map scene labels to GT class indices; labels < 0 or absent from ``mapping`` become -1.

    ``mapping`` is a dict {scene label: class index (-1 = none)} or a 1-D array indexed by label.
    Vectorised (sorted-key search), so it suits label maps of any size.
    """
    lab = np.asarray(labels)
    if not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"labels: expected integer labels, got dtype {lab.dtype}")
    lab = lab.astype(np.int64)
    if isinstance(mapping, np.ndarray):
        table = mapping.astype(np.int64).reshape(-1)
        out = np.full(lab.shape, -1, dtype=np.int64)
        ok = (lab >= 0) & (lab < table.shape[0])
        out[ok] = table[lab[ok]]
        return out
    if not mapping:
        return np.full(lab.shape, -1, dtype=np.int64)
    keys = np.fromiter((int(k) for k in mapping), dtype=np.int64, count=len(mapping))
    vals = np.fromiter((int(mapping[k]) for k in mapping), dtype=np.int64, count=len(mapping))
    order = np.argsort(keys)
    keys, vals = keys[order], vals[order]
    pos = np.clip(np.searchsorted(keys, lab), 0, keys.shape[0] - 1)
    hit = (keys[pos] == lab) & (lab >= 0)
    return np.where(hit, vals[pos], -1)


def novel_view_metrics(
    rendered_labels: Sequence[Any],
    gt_class_maps: Sequence[Any],
    label_to_class: Mapping[int, int] | np.ndarray,
    class_names: Sequence[str],
    ignore: Iterable[str | int] | None = None,
) -> SegmentationMetrics:
    """2D novel-view semantic segmentation (paper Table I): mIoU / mAcc over held-out views.

    Args:
        rendered_labels: per view an [H, W] int map of scene labels (``render_semantics(...).labels``),
            -1 where nothing labelled was rendered. torch tensors are accepted.
        gt_class_maps: per view an [H, W] int map of GT class indices, -1 = void.
        label_to_class: scene label -> GT class index (from :mod:`ogscene3d.eval.label_mapping`).
        class_names: C ground-truth class names.
        ignore: class names/indices left out of the means (their pixels are dropped).

    One confusion matrix is accumulated over all views, so large and small views weigh by pixels.
    """
    if len(rendered_labels) != len(gt_class_maps):
        raise ValueError(f"{len(rendered_labels)} rendered maps but {len(gt_class_maps)} ground-truth maps")
    if len(rendered_labels) == 0:
        raise ValueError("no views given")
    c = len(class_names)
    cm = np.zeros((c, c + 1), dtype=np.int64)
    for v, (r, g) in enumerate(zip(rendered_labels, gt_class_maps)):
        r = r.detach().cpu().numpy() if hasattr(r, "detach") else np.asarray(r)
        g = g.detach().cpu().numpy() if hasattr(g, "detach") else np.asarray(g)
        if r.ndim != 2 or r.shape != g.shape:
            raise ValueError(f"view {v}: rendered labels {r.shape} and GT {g.shape} must be equal [H, W]")
        cm += confusion_matrix(g, label_lookup(label_to_class, r), c)
    return segmentation_metrics(
        cm,
        class_names,
        ignore,
        "drop",
        protocol=f"novel-view-2d ({len(rendered_labels)} views, confusion accumulated over pixels)",
    )
