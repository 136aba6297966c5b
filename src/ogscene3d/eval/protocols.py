"""Evaluation protocols: how predicted points/pixels are put against the ground truth.

Two 3D protocols from the literature are implemented; they count different things, so their
numbers are not interchangeable and every result names the protocol that produced it.

* ``"hovsg"`` (HOV-SG, ``application/eval/evaluate_sem_seg.py``): every ground-truth point takes the
  majority class of its k = 5 nearest *labelled* predicted points (ties go to the smallest class
  index, like ``np.bincount(...).argmax()``). Unlabelled predicted points (no scene label) do not
  vote. A labelled point whose scene label the label mapping could not name votes *no class*: HOV-SG
  has no free abstention (every mask gets some class), so an unnamed label must not let its
  neighbours' classes fill its space. A GT point whose vote *no class* wins is predicted -1, a miss
  of its class (on a tie a real class wins over *no class*). Metrics are counted on ground-truth
  points. Background classes (default wall/floor/ceiling) are left out of the means, but their
  points stay in the count, so predicting ``table`` on a wall point is a false positive of
  ``table`` (``ignored_gt_points="false_positive"``), and so is predicting it on a void GT point
  (class -1): HOV-SG's ``ignore`` list holds -1 (void) and 0 (background) like wall and floor, and
  its ``per_class_IU`` counts a class's predictions over all GT points. In ``"drop"`` mode (the
  ScanNet convention) ignored and void points leave the count.

  Checked against HOV-SG's ``hovsg/utils/metric.py`` (commit 0613d61), the same figures on the same
  votes: ``mean_IU`` sums the IoU of the classes with both a prediction and a GT point but divides by
  the number of GT classes not ignored, so a GT class without any prediction adds 0, which is its
  IoU anyway (TP = 0, support > 0), and a predicted class absent from the GT is in neither sum nor
  count: our mean over the non-ignored GT classes. ``frequency_weighted_IU`` divides by all points
  less those of ignored GT classes (void included), i.e. the support of the non-ignored GT classes,
  as our F-mIoU. ``mean_accuracy`` (mAcc) and ``pixel_accuracy`` (our oAcc) average recall over the
  same classes. Where we differ: (a) our per-class IoU of a class absent from the GT is NaN (HOV-SG
  reports 0; neither enters the means); (b) a GT point whose vote *no class* wins is predicted -1,
  a miss of its class and a false positive of nobody (HOV-SG's masks always carry a class, so it
  has no such case; its -1 is an ignored class, which gives the same counts); (c) HOV-SG scores
  every point of the GT mesh, while ``ogscene3d eval`` by default removes the GT points no frame of
  a synthetic sequence saw (``--gt-points all`` keeps them): removed, not made void, so they are no
  false positives; (d) the vote runs on Gaussian centres, not on HOV-SG's voxel-downsampled mask
  clouds; counted on GT points, the predicted density only matters where classes meet.
* ``"conceptgraphs"`` (ConceptGraphs, ``scripts/eval_replica_semseg.py``): every predicted point takes
  the class of its nearest ground-truth point as its reference; metrics are counted on predicted
  points. Predicted points whose reference is an ignored class (or void) are dropped. Predicted
  points with no class (unlabelled, or unnamed by the label mapping) count as misses of their
  reference class. The classes averaged are those present in the ground-truth cloud (less the
  ignored ones), as in ConceptGraphs' ``keep_index``: a class no predicted point reached scores IoU
  0 and recall 0.

  Counted on predicted points, the score weighs every region by its predicted density. ConceptGraphs'
  predicted cloud is the union of its objects' point clouds, each voxel-downsampled at
  ``downsample_voxel_size`` = 0.025 m (``configs/slam_pipeline/base.yaml`` and
  ``hydra_configs/base_mapping.yaml``); ours are Gaussian centres, whose density follows the map's
  densification. So the predicted points are first resampled the same way (:func:`voxel_resample`):
  one point per (scene label, voxel) at the mean of its points, unlabelled points per voxel alone,
  ``voxel_size`` = 0.025 m by default (0 = every Gaussian centre counts, as before). Where we differ:
  Open3D's ``voxel_down_sample`` anchors each object's grid at that object's own minimum corner, ours
  is one grid anchored at the whole cloud's (a sub-voxel phase); and ConceptGraphs'
  ``eval_replica_semseg.py`` (commit 231e638) then moves the object classes onto its SLAM
  reconstruction (``rgb_cloud``: each reconstructed point takes its nearest object point's class)
  and counts on those points, a cloud we do not have: the voxel grid stands in for it. ConceptGraphs
  also names its objects only with kept classes (``object_class_sim[:, ignore_index] = -1e10``) and
  then slices its confusion matrix to them; our label mapping may name a label with an ignored or
  absent class, and its points then count as misses of their reference class, where a copy of the
  slicing would drop those predictions unseen (and so reward predicting an ignored class).

Nearest neighbours come from a KD-tree (``scipy.spatial.cKDTree``), queried in chunks, so memory is
O(N + M), never O(N * M).

The 2D rendered-view protocol (paper Table I, following OpenGS-SLAM) accumulates one confusion
matrix over the rendered views: pixels with ground truth < 0 are void, rendered pixels with no label
(-1) or a label the mapping does not name are misses. The views are frames of the mapped sequence
(not held-out novel views), or with ``eval --held-out`` frames the run did not map (novel views), and
the protocol string says which.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Literal

import numpy as np

from .metrics import (
    IgnoredGtPoints,
    SegmentationMetrics,
    confusion_matrix,
    segmentation_metrics,
    void_predictions,
)
from .options import CONCEPTGRAPHS_VOXEL_SIZE, PROTOCOLS

Protocol3D = Literal["hovsg", "conceptgraphs"]

#: HOV-SG's background classes. Its own evaluation ignores more, by data set: ``--ignore
#: preset:hovsg-replica`` / ``preset:hovsg-scannet`` (metrics.IGNORE_PRESETS) for comparing with its tables.
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


def _checked_clouds(
    pred_points: Any, pred_classes: Any, gt_points: Any, gt_classes: Any
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A protocol's two labelled clouds, checked (ValueError naming the argument) and as float64 / int64."""
    pp = _points(pred_points, "pred_points")
    pc = _labels(pred_classes, pp.shape[0], "pred_classes")
    gp = _points(gt_points, "gt_points")
    return pp, pc, gp, _labels(gt_classes, gp.shape[0], "gt_classes")


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


def _labelled_mask(pred_labelled: Any, pred_classes: np.ndarray) -> np.ndarray:
    """Which predicted points carry a scene label; a point with a class but no label is a caller bug."""
    if pred_labelled is None:
        return pred_classes >= 0
    mask = np.asarray(pred_labelled)
    if mask.dtype != bool or mask.shape != pred_classes.shape:
        raise ValueError(
            f"pred_labelled: expected a [{pred_classes.shape[0]}] bool array, got {mask.dtype} {mask.shape}"
        )
    if np.any(pred_classes[~mask] >= 0):
        raise ValueError("pred_labelled marks points unlabelled that pred_classes gives a class")
    return mask


def hovsg_vote(
    pred_points: np.ndarray,
    pred_classes: np.ndarray,
    labelled: np.ndarray,
    gt_points: np.ndarray,
    num_classes: int,
    k: int = 5,
    workers: int = 1,
) -> np.ndarray:
    """Class of every GT point by the vote of its k nearest labelled predicted points, -1 = no class.

    Labelled points without a class vote the sentinel ``num_classes``; it sorts after every real
    class, so it only wins a strict majority (ties go to the smallest class index).
    """
    if not labelled.any():
        return np.full(gt_points.shape[0], -1, dtype=np.int64)
    _, idx = nearest_neighbors(pred_points[labelled], gt_points, k=k, workers=workers)
    voter_classes = pred_classes[labelled]
    voter_classes = np.where(voter_classes >= 0, voter_classes, num_classes)
    voted = majority_vote(voter_classes[np.maximum(idx, 0)], idx >= 0)
    return np.where(voted == num_classes, -1, voted)


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
    pred_labelled: Any | None = None,
) -> SegmentationMetrics:
    """HOV-SG 3D semantic segmentation protocol (see the module docstring).

    Args:
        pred_points: [N, 3] predicted points (Gaussian centres), metres, same frame as the GT.
        pred_classes: [N] GT-class index per predicted point, -1 = no class.
        gt_points: [M, 3] ground-truth points.
        gt_classes: [M] class index per GT point, -1 = void.
        class_names: the C ground-truth class names.
        ignore: background class names/indices left out of the means.
        k: neighbours in the majority vote (HOV-SG uses 5).
        ignored_gt_points: "false_positive" (HOV-SG): predictions on the points of ignored classes and
            on void points are false positives of the predicted class; "drop" (the ScanNet
            convention) leaves both out.
        pred_labelled: [N] bool, which predicted points carry a scene label. Unlabelled points do not
            vote; labelled points with class -1 (a label the mapping could not name) vote *no class*.
            None = ``pred_classes >= 0`` (every point without a class is taken as unlabelled).
    """
    pp, pc, gp, gc = _checked_clouds(pred_points, pred_classes, gt_points, gt_classes)
    labelled = _labelled_mask(pred_labelled, pc)
    voted = hovsg_vote(pp, pc, labelled, gp, len(class_names), k=k, workers=workers)
    cm = confusion_matrix(gc, voted, len(class_names))
    void = void_predictions(gc, voted, len(class_names))
    desc = f"hovsg (k={k} nearest predicted points vote for each GT point; counted on GT points)"
    return segmentation_metrics(
        cm, class_names, ignore, ignored_gt_points, protocol=desc, void_predicted=void
    )


def voxel_resample(
    points: Any, classes: Any, labels: Any | None = None, voxel_size: float = CONCEPTGRAPHS_VOXEL_SIZE
) -> tuple[np.ndarray, np.ndarray]:
    """One point per (scene label, voxel) at the mean of its points, with their class.

    The analogue of ConceptGraphs' object clouds, each voxel-downsampled (Open3D's
    ``voxel_down_sample`` averages the points of a voxel): a region weighs by the voxels it fills, not
    by how many points the map put there. Unlabelled points (label < 0) are grouped by voxel alone.

    Args:
        points: [N, 3] predicted points.
        classes: [N] class per point, -1 = no class.
        labels: [N] scene label per point, -1 = unlabelled; None = group by class (one object per class).
        voxel_size: voxel edge in metres; the grid starts half a voxel below the cloud's minimum
            corner, as Open3D's does.

    Returns:
        (points [G, 3] float64, classes [G] int64), one row per group, ordered by (label, class, voxel).
    """
    pts = _points(points, "points")
    cls = _labels(classes, pts.shape[0], "classes")
    lab = cls if labels is None else _labels(labels, pts.shape[0], "labels")
    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise ValueError(f"voxel_size must be a positive number of metres, got {voxel_size}")
    if pts.shape[0] == 0:
        return pts.copy(), cls.copy()
    lab = np.maximum(lab, -1)  # every unlabelled point shares one group key per voxel
    cell = np.floor((pts - (pts.min(axis=0) - 0.5 * voxel_size)) / voxel_size).astype(np.int64)
    # The class is part of the key so that a group never mixes classes, whatever the caller passes.
    keys = np.concatenate([lab[:, None], cls[:, None], cell], axis=1)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    if np.prod(dims.astype(np.float64)) < 2.0**62:
        # One int64 per row: a 1-D unique is an order of magnitude faster than unique(axis=0).
        _, first, group = np.unique(
            np.ravel_multi_index(tuple(keys.T), tuple(dims)), return_index=True, return_inverse=True
        )
    else:
        _, first, group = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    group = group.reshape(-1)
    count = np.bincount(group, minlength=first.shape[0]).astype(np.float64)
    mean = np.stack(
        [np.bincount(group, weights=pts[:, d], minlength=first.shape[0]) / count for d in range(3)], axis=1
    )
    return mean, cls[first]


def conceptgraphs_protocol(
    pred_points: Any,
    pred_classes: Any,
    gt_points: Any,
    gt_classes: Any,
    class_names: Sequence[str],
    ignore: Iterable[str | int] | None = CONCEPTGRAPHS_DEFAULT_IGNORE,
    workers: int = 1,
    pred_labels: Any | None = None,
    voxel_size: float = CONCEPTGRAPHS_VOXEL_SIZE,
) -> SegmentationMetrics:
    """ConceptGraphs 3D semantic segmentation protocol (see the module docstring).

    Arguments as :func:`hovsg_protocol`. The predicted points are first resampled to one point per
    (scene label, voxel of ``voxel_size`` metres) by :func:`voxel_resample` (``pred_labels``: [N]
    scene labels, -1 = unlabelled; None = group by class; ``voxel_size`` 0 = no resampling). Every
    resampled point counts, unlabelled ones too (class -1: a miss of its reference class); points
    whose nearest GT point is void are skipped. The classes averaged are those with a (non-void)
    point in ``gt_classes``, less the ignored ones.
    """
    pp, pc, gp, gc = _checked_clouds(pred_points, pred_classes, gt_points, gt_classes)
    if pp.shape[0] == 0:
        raise ValueError("pred_points is empty: the ConceptGraphs protocol counts on predicted points")
    if not (np.isfinite(voxel_size) and voxel_size >= 0):
        raise ValueError(f"voxel_size must be >= 0 metres (0 = no resampling), got {voxel_size}")
    if voxel_size > 0:
        labels = None if pred_labels is None else _labels(pred_labels, pp.shape[0], "pred_labels")
        pp, pc = voxel_resample(pp, pc, labels, voxel_size)
        sampling = f"predicted points resampled to one per scene label and {voxel_size:g} m voxel"
    else:
        sampling = "every predicted point counts, not resampled"
    _, idx = nearest_neighbors(gp, pp, k=1, workers=workers)
    ref = gc[idx[:, 0]]
    c = len(class_names)
    cm = confusion_matrix(ref, pc, c)
    # The rows count predicted points, so a GT class the map never reached has no row support; it is
    # averaged anyway (IoU 0), like ConceptGraphs' keep_index of the classes in the GT cloud.
    gt_present = np.bincount(gc[(gc >= 0) & (gc < c)], minlength=c)[:c] > 0
    desc = (
        f"conceptgraphs ({sampling}; each predicted point takes its nearest GT point's class; counted on "
        "predicted points; the classes present in the GT are averaged)"
    )
    return segmentation_metrics(cm, class_names, ignore, "drop", protocol=desc, gt_present=gt_present)


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
    pred_labelled: Any | None = None,
    pred_labels: Any | None = None,
    voxel_size: float = CONCEPTGRAPHS_VOXEL_SIZE,
) -> SegmentationMetrics:
    """Dispatch to :func:`hovsg_protocol` or :func:`conceptgraphs_protocol`.

    ``ignore=None`` uses the protocol's default (HOV-SG: wall/floor/ceiling, ConceptGraphs: other).
    ``pred_labelled`` (which predicted points carry a scene label) only matters to HOV-SG's vote;
    ConceptGraphs counts every predicted point. ``pred_labels`` (scene labels, -1 = unlabelled) and
    ``voxel_size`` (metres, 0 = none) set ConceptGraphs' resampling of the predicted points.
    """
    if protocol == "hovsg":
        ign = HOVSG_DEFAULT_IGNORE if ignore is None else ignore
        return hovsg_protocol(
            pred_points, pred_classes, gt_points, gt_classes, class_names, ign, k=k, workers=workers,
            pred_labelled=pred_labelled,
        )  # fmt: skip
    if protocol == "conceptgraphs":
        ign = CONCEPTGRAPHS_DEFAULT_IGNORE if ignore is None else ignore
        return conceptgraphs_protocol(
            pred_points, pred_classes, gt_points, gt_classes, class_names, ign, workers=workers,
            pred_labels=pred_labels, voxel_size=voxel_size,
        )  # fmt: skip
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


#: What the 2D block is: renders at poses of the sequence's own frames, so it is not a novel-view score.
RENDERED_VIEW_PROTOCOL = "rendered-view-2d (dataset frames of the mapped sequence, not held-out novel views)"
#: ``eval --held-out``: frames the run was not given, between its first and last mapped frames.
HELD_OUT_VIEW_PROTOCOL = (
    "rendered-view-2d (held-out novel views: frames between mapped frames the run did not map)"
)
#: ``eval --held-out`` where no unmapped frame lies inside the mapped range: views beyond it.
EXTRAPOLATED_VIEW_PROTOCOL = (
    "rendered-view-2d (held-out frames the run did not map, outside its mapped range: extrapolated views)"
)


def rendered_view_metrics(
    rendered_labels: Sequence[Any],
    gt_class_maps: Sequence[Any],
    label_to_class: Mapping[int, int] | np.ndarray,
    class_names: Sequence[str],
    ignore: Iterable[str | int] | None = None,
    views: str = RENDERED_VIEW_PROTOCOL,
) -> SegmentationMetrics:
    """2D semantic segmentation of rendered views (paper Table I): mIoU / mAcc over dataset frames.

    Args:
        rendered_labels: per view an [H, W] int map of scene labels (``render_semantics(...).labels``),
            -1 where nothing labelled was rendered. torch tensors are accepted.
        gt_class_maps: per view an [H, W] int map of GT class indices, -1 = void.
        label_to_class: scene label -> GT class index (from :mod:`ogscene3d.eval.label_mapping`).
        class_names: C ground-truth class names.
        ignore: class names/indices left out of the means (their pixels are dropped).
        views: what the views are, the protocol string's head (:data:`RENDERED_VIEW_PROTOCOL`,
            :data:`HELD_OUT_VIEW_PROTOCOL` or :data:`EXTRAPOLATED_VIEW_PROTOCOL`).

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
        protocol=f"{views}: {len(rendered_labels)} views, confusion accumulated over pixels",
    )


#: Former name of :func:`rendered_view_metrics`, kept so existing imports keep working.
novel_view_metrics = rendered_view_metrics
