"""Instance-level scores of a labelled point set against a synthetic scene's ground truth (benchmarks only).

* instance mIoU: each GT point takes the scene label voted by its k = 5 nearest labelled points (the HOV-SG
  vote, on labels instead of classes); scene labels and GT instances are matched one to one by the Hungarian
  method on their IoU (``scipy.optimize.linear_sum_assignment``), and the mean runs over every GT instance
  with at least ``MIN_POINTS`` scored points (an unmatched instance counts 0). Walls, floor and ceiling are
  instances too: a floor left split in two labels loses here.
* class mIoU and F-mIoU: the project's evaluation (HOV-SG protocol, scene labels named by majority overlap
  with the GT instances), for point sets that are not run directories (the yardstick).
* unlabelled share: of the scored GT points, those whose nearest map point carries no label.
* objects lost by repair: objects one row labels well (IoU >= ``LOST_FROM``) and a later row loses
  (IoU < ``LOST_TO``).
* first views: which objects the segments of their first view got wrong (absorbed, merged with another
  object, cut, or missed), so that the benchmark can count how many the map recovered.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ogscene3d.eval.label_mapping import majority_overlap_mapping
from ogscene3d.eval.protocols import HOVSG_DEFAULT_IGNORE, hovsg_protocol, hovsg_vote, nearest_neighbors
from ogscene3d.eval.readers import GroundTruth

MIN_POINTS = 10  # GT instances with fewer scored points are left out of the instance mean
RECOVERED_IOU = 0.5  # an object counts as recovered when its matched label reaches this IoU
LOST_FROM, LOST_TO = 0.5, 0.25  # issue 39: local labels it with IoU >= 0.5, a repair leaves it below 0.25


def scored_points(gt: GroundTruth, which: str = "observed") -> np.ndarray:
    """[M] bool: the GT points scored ("observed": those some frame saw, where the GT says; or "all")."""
    if which == "observed" and gt.observed is not None:
        return gt.observed & (gt.instances >= 0)
    return gt.instances >= 0


def instance_scores(
    pred_points: np.ndarray, pred_labels: np.ndarray, gt: GroundTruth, which: str = "observed", k: int = 5
) -> dict:
    """{"miou": instance mIoU in [0, 1], "iou": {GT instance id: IoU of its matched label}, "matched":
    {GT instance id: scene label}} (Hungarian one-to-one matching, see the module docstring)."""
    from scipy.optimize import linear_sum_assignment

    if gt.instances is None:
        raise ValueError(f"{gt.source}: the ground truth has no instances")
    keep = scored_points(gt, which)
    pts, inst = gt.points[keep], gt.instances[keep]
    labels = np.asarray(pred_labels, dtype=np.int64)
    uniq = np.unique(labels[labels >= 0])
    compact = np.searchsorted(uniq, np.maximum(labels, 0))
    compact = np.where(labels >= 0, compact, -1)
    voted = hovsg_vote(np.asarray(pred_points, np.float64), compact, labels >= 0, pts, len(uniq) + 1, k=k)
    ids, size = np.unique(inst, return_counts=True)
    ids, size = ids[size >= MIN_POINTS], size[size >= MIN_POINTS]
    if ids.size == 0:
        return {"miou": None, "iou": {}, "matched": {}}
    row = np.searchsorted(ids, inst)
    ok = (row < ids.size) & (ids[np.minimum(row, ids.size - 1)] == inst)
    n_pred = max(1, len(uniq))
    inter = np.zeros((ids.size, n_pred))
    both = ok & (voted >= 0)
    np.add.at(inter, (row[both], voted[both]), 1.0)
    pred_size = np.bincount(voted[ok & (voted >= 0)], minlength=n_pred).astype(np.float64)
    iou = inter / np.maximum(size[:, None] + pred_size[None, :] - inter, 1.0)
    r, c = linear_sum_assignment(-iou)
    per = {int(i): 0.0 for i in ids}
    matched: dict[int, int] = {}
    for a, b in zip(r, c):
        if iou[a, b] > 0:
            per[int(ids[a])] = float(iou[a, b])
            matched[int(ids[a])] = int(uniq[b]) if len(uniq) else -1
    return {"miou": float(np.mean(list(per.values()))), "iou": per, "matched": matched}


def class_miou(
    pred_points: np.ndarray, pred_labels: np.ndarray, gt: GroundTruth, which: str = "observed"
) -> float:
    """HOV-SG class mIoU of a labelled point set (see :func:`class_scores`)."""
    return class_scores(pred_points, pred_labels, gt, which)[0]


def class_scores(
    pred_points: np.ndarray, pred_labels: np.ndarray, gt: GroundTruth, which: str = "observed"
) -> tuple[float, float]:
    """HOV-SG class (mIoU, F-mIoU) of a labelled point set, labels named by majority overlap with the GT
    instances (as ``ogscene3d.eval.evaluate_run`` does for a run directory: association radius 0.1 m)."""
    pp = np.asarray(pred_points, np.float64)
    labels = np.asarray(pred_labels, dtype=np.int64)
    _, idx = nearest_neighbors(gt.points, pp, k=1, max_distance=0.1)
    assoc = idx[:, 0]
    gt_ids = np.where(assoc >= 0, gt.instances[np.maximum(assoc, 0)], -1)
    naming = majority_overlap_mapping(labels, gt_ids, id_to_class=gt.instance_classes)
    lut = np.full(int(labels.max(initial=-1)) + 2, -1, dtype=np.int64)
    for lab, cls in naming.items():
        lut[lab] = cls
    classes = np.where(labels >= 0, lut[np.maximum(labels, 0)], -1)
    keep = scored_points(gt, which) if which == "observed" else np.ones(len(gt.points), bool)
    m = hovsg_protocol(
        pp, classes, gt.points[keep], gt.classes[keep], gt.class_names, HOVSG_DEFAULT_IGNORE,
        pred_labelled=labels >= 0,
    )  # fmt: skip
    return float(m.miou), float(m.fmiou)


def unlabelled_share(pred_points: np.ndarray, pred_labels: np.ndarray, gt: GroundTruth) -> float:
    """Of the observed GT points, the share whose nearest map point (any distance) carries no label."""
    keep = scored_points(gt, "observed")
    if not keep.any() or len(pred_points) == 0:
        return 1.0
    _, idx = nearest_neighbors(np.asarray(pred_points, np.float64), gt.points[keep], k=1)
    return float(np.mean(np.asarray(pred_labels)[idx[:, 0]] < 0))


def lost_objects(before: dict[int, float], after: dict[int, float]) -> list[int]:
    """GT instances that ``before`` labels with IoU >= LOST_FROM and ``after`` below LOST_TO."""
    return sorted(i for i, v in before.items() if v >= LOST_FROM and after.get(i, 0.0) < LOST_TO)


def wrong_first_views(scene: str | Path, min_fraction: float = 0.001) -> dict[int, str]:
    """{GT instance id: what went wrong} for the objects whose first view's segments got them wrong.

    An object's first view is the first frame where it covers ``min_fraction`` of the image. There, the
    segment that covers most of it must hold it cleanly: "absorbed/merged" when that segment is less than
    half this object or another object makes up a quarter of it (a refrigerator that took the floor in), "cut/
    missed" when it covers less than half of the object."""
    from ogscene3d.datasets import open_dataset

    ds = open_dataset(scene, kind="synthetic")
    seen: set[int] = set()
    wrong: dict[int, str] = {}
    for frame in ds:
        inst = np.asarray(frame.gt_instances, dtype=np.int64)
        seg = np.asarray(frame.segments if frame.segments is not None else np.zeros_like(inst), np.int64)
        ids, area = np.unique(inst[inst > 0], return_counts=True)
        seg_area = np.bincount(seg.ravel())
        for i, a in zip(ids.tolist(), area.tolist()):
            if i in seen or a < min_fraction * inst.size:
                continue
            seen.add(i)
            s_ids, s_cnt = np.unique(seg[inst == i], return_counts=True)
            nz = s_ids > 0
            if not nz.any():
                wrong[i] = "cut/missed"
                continue
            s, cnt = s_ids[nz][np.argmax(s_cnt[nz])], s_cnt[nz].max()
            others = np.bincount(inst[(seg == s) & (inst != i)], minlength=1)
            if cnt < 0.5 * seg_area[s] or others[1:].max(initial=0) >= 0.25 * seg_area[s]:
                wrong[i] = "absorbed/merged"
            elif cnt < 0.5 * a:
                wrong[i] = "cut/missed"
    return wrong


def recovered(iou: dict[int, float], wrong: dict[int, str]) -> tuple[int, int]:
    """(objects recovered, objects with a wrong first view that are scored)."""
    scored = [i for i in wrong if i in iou]
    return sum(iou[i] >= RECOVERED_IOU for i in scored), len(scored)
