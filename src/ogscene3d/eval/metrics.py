"""Confusion-matrix semantic segmentation metrics: per-class IoU, mIoU, F-mIoU, mAcc.

Conventions (the ones HOV-SG and ConceptGraphs use, stated once here):

* The confusion matrix has one row per ground-truth class and one column per predicted class, plus
  a last column ``C`` that counts points whose prediction is *no class* (prediction ``< 0``: an
  unlabeled Gaussian, or a scene label that the label mapping could not name). Such points are
  false negatives of their ground-truth class and false positives of nobody.
* Ground truth ``< 0`` is *void* (unannotated): those points never enter the matrix. A protocol that
  counts predictions on void points as false positives (HOV-SG) passes their counts separately
  (``void_predicted``, see :func:`void_predictions`); they count only where ignored GT points do
  (``ignored_gt_points="false_positive"``).
* A class is **evaluated** when it has ground-truth support (> 0 points) and is not in the ignore
  list. Classes absent from the ground truth are left out of every mean (their IoU is reported
  as NaN/None), even when the method predicted them: their false positives still lower the IoU of
  the classes whose points they took (as false negatives of those classes), which is the standard
  ScanNet/HOV-SG handling. A protocol that counts on *predicted* points (ConceptGraphs) passes
  ``gt_present`` instead: the classes present in the ground-truth cloud are evaluated, so a class
  the map never reached still enters the means, with IoU 0 and recall 0.
* Ignore names that match no class are listed (``ignore_unknown``), never an error: a scene may
  simply lack e.g. a ceiling.
* Ignored classes (e.g. wall/floor/ceiling) are left out of the means. What happens to the points
  whose ground truth is an ignored class is protocol dependent (``ignored_gt_points``):
  ``"drop"`` removes them entirely (ConceptGraphs, ScanNet benchmark); ``"false_positive"`` keeps
  them, so a wall point (or a void point, given ``void_predicted``) predicted as ``table`` still
  counts as a false positive of ``table``: HOV-SG's ``metric.py`` counts a class's predictions over
  all points (``n_ij = sum(eval == c)``), and its ``ignore`` list holds void (-1) and background (0)
  like wall and floor.

Formulas over the evaluated set E, with TP_c, FP_c, FN_c from the matrix (FP_c plus the predictions of c
on void points where those count) and support t_c = TP_c + FN_c:

    IoU_c  = TP_c / (TP_c + FP_c + FN_c)
    mIoU   = mean_{c in E} IoU_c
    F-mIoU = sum_{c in E} t_c IoU_c / sum_{c in E} t_c          (frequency-weighted IoU)
    mAcc   = mean_{c in E} TP_c / t_c                           (mean class recall)
    oAcc   = sum_{c in E} TP_c / sum_{c in E} t_c               (overall accuracy)
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

log = logging.getLogger(__name__)

IgnoredGtPoints = Literal["drop", "false_positive"]


def _as_int_array(x: Any, name: str) -> np.ndarray:
    a = np.asarray(x)
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise ValueError(f"{name}: expected an integer label array, got dtype {a.dtype}")
    if np.issubdtype(a.dtype, np.floating):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: contains NaN or inf")
        if not np.all(a == np.round(a)):
            raise ValueError(f"{name}: float labels must be whole numbers")
    return a.astype(np.int64, copy=False).reshape(-1)


def _class_pair(gt: Any, pred: Any, num_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """``gt`` and ``pred`` as int arrays of one size, every prediction < ``num_classes``."""
    g = _as_int_array(gt, "gt")
    p = _as_int_array(pred, "pred")
    if g.shape != p.shape:
        raise ValueError(f"gt and pred differ in size: {np.asarray(gt).shape} vs {np.asarray(pred).shape}")
    if p.size and p.max() >= num_classes:
        raise ValueError(f"pred has class {int(p.max())} >= num_classes={num_classes}")
    return g, p


def confusion_matrix(gt: Any, pred: Any, num_classes: int) -> np.ndarray:
    """Count (ground truth, prediction) pairs.

    Args:
        gt: ground-truth class per point/pixel, any shape, ints in [0, num_classes) or < 0 (void, skipped).
        pred: predicted class per point/pixel, same shape, ints in [0, num_classes) or < 0 (no class).
        num_classes: C, the number of ground-truth classes.

    Returns:
        int64 array [C, C + 1]: entry [g, p] counts points of class g predicted as p; column C counts
        points predicted as *no class*.
    """
    if num_classes <= 0:
        raise ValueError(f"num_classes must be positive, got {num_classes}")
    g, p = _class_pair(gt, pred, num_classes)
    if g.size and g.max() >= num_classes:
        raise ValueError(f"gt has class {int(g.max())} >= num_classes={num_classes}")
    keep = g >= 0
    g = g[keep]
    p = p[keep]
    p = np.where(p < 0, num_classes, p)
    width = num_classes + 1
    counts = np.bincount(g * width + p, minlength=num_classes * width)
    return counts.reshape(num_classes, width).astype(np.int64)


def void_predictions(gt: Any, pred: Any, num_classes: int) -> np.ndarray:
    """[C] int64: how many void ground-truth points (gt < 0) each class was predicted on.

    The confusion matrix leaves void points out; protocols that count these predictions as false
    positives (HOV-SG) pass this to :func:`segmentation_metrics` as ``void_predicted``.
    """
    g, p = _class_pair(gt, pred, num_classes)
    hit = p[(g < 0) & (p >= 0)]
    return np.bincount(hit, minlength=num_classes).astype(np.int64)


def _nan_to_none(x: float) -> float | None:
    return None if (x is None or math.isnan(x)) else float(x)


@dataclass(frozen=True)
class SegmentationMetrics:
    """Metrics of one evaluation. Fractions in [0, 1]; NaN marks a class that was not evaluated."""

    protocol: str  # which protocol produced the counts, e.g. "hovsg (k=5, counted on GT points)"
    class_names: list[str]
    confusion: np.ndarray  # [C, C+1] int64, after the protocol's ignore handling
    iou: np.ndarray  # [C] float64
    acc: np.ndarray  # [C] float64, per-class recall
    support: np.ndarray  # [C] int64, ground-truth count per class
    predicted: np.ndarray  # [C] int64, prediction count per class (column sums, plus void_fp)
    evaluated: np.ndarray  # [C] bool
    ignored: list[str] = field(default_factory=list)
    ignore_unknown: list[str] = field(default_factory=list)  # ignore names that matched no class
    # [C] int64, predictions on void GT points counted as false positives (zeros where they are dropped)
    void_fp: np.ndarray | None = None
    miou: float = float("nan")
    fmiou: float = float("nan")
    macc: float = float("nan")
    overall_acc: float = float("nan")

    @property
    def num_evaluated(self) -> int:
        return int(self.evaluated.sum())

    def per_class(self) -> list[dict[str, Any]]:
        """One JSON-safe dict per class: name, iou, acc, support, predicted, evaluated."""
        return [
            {
                "name": n,
                "iou": _nan_to_none(float(self.iou[i])),
                "acc": _nan_to_none(float(self.acc[i])),
                "support": int(self.support[i]),
                "predicted": int(self.predicted[i]),
                "evaluated": bool(self.evaluated[i]),
            }
            for i, n in enumerate(self.class_names)
        ]

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe summary (NaN becomes null), percentages are *not* applied."""
        return {
            "protocol": self.protocol,
            "miou": _nan_to_none(self.miou),
            "fmiou": _nan_to_none(self.fmiou),
            "macc": _nan_to_none(self.macc),
            "overall_acc": _nan_to_none(self.overall_acc),
            "num_evaluated_classes": self.num_evaluated,
            "ignored_classes": list(self.ignored),
            "ignore_unknown": list(self.ignore_unknown),
            "unassigned_predictions": int(self.confusion[:, -1].sum()),
            "void_false_positives": 0 if self.void_fp is None else int(self.void_fp.sum()),
            "per_class": self.per_class(),
        }


#: The ignore lists of HOV-SG's own evaluation (its evaluate_sem_seg.py), by data set, for comparing with
#: its tables: on Replica every class whose name *contains* one of the words (so also wall-cabinet,
#: wall-plug and, through "door", indoor-plant), on ScanNet the classes of these names (among ScanNet's 20
#: benchmark classes, ``--classes scannet20``; over the 40 NYU40 classes the means hold more classes).
IGNORE_PRESETS: dict[str, tuple[str, tuple[str, ...]]] = {
    "hovsg-replica": ("contains", ("wall", "floor", "ceiling", "door", "window", "background")),
    "hovsg-scannet": ("exact", ("wall", "floor", "door", "window", "background")),
}


def _preset_classes(name: str, class_names: Sequence[str]) -> list[int]:
    if name not in IGNORE_PRESETS:
        raise ValueError(f"ignore: unknown preset {name!r}; presets: {', '.join(IGNORE_PRESETS)}")
    rule, words = IGNORE_PRESETS[name]
    names = [n.strip().lower() for n in class_names]
    if rule == "contains":
        return [i for i, n in enumerate(names) if any(w in n for w in words)]
    return [i for i, n in enumerate(names) if n in words]


def resolve_ignore(
    ignore: Iterable[str | int] | None, class_names: Sequence[str]
) -> tuple[list[int], list[str]]:
    """Turn an ignore list of class names (case-insensitive, exact), indices and presets
    (``preset:NAME``, see ``IGNORE_PRESETS``) into indices.

    Returns (indices, names that are not in ``class_names``); unknown names are not an error since
    a scene may simply lack e.g. a ceiling.
    """
    if ignore is None:
        return [], []
    lookup = {n.strip().lower(): i for i, n in reversed(list(enumerate(class_names)))}
    idx: list[int] = []
    unknown: list[str] = []
    for item in ignore:
        if isinstance(item, (int, np.integer)) and not isinstance(item, bool):
            if not 0 <= int(item) < len(class_names):
                raise ValueError(f"ignore: class index {item} out of range [0, {len(class_names)})")
            idx.append(int(item))
            continue
        key = str(item).strip().lower()
        if not key:
            continue
        if key.startswith("preset:"):
            idx.extend(_preset_classes(key.removeprefix("preset:"), class_names))
        elif key in lookup:
            idx.append(lookup[key])
        else:
            unknown.append(str(item))
    return sorted(set(idx)), unknown


def warn_unknown_ignore(
    ignore: Iterable[str | int] | None, class_names: Sequence[str], shown: int = 8
) -> list[str]:
    """Log a warning naming the ``ignore`` names that match no class (and the first class names).

    Meant for ignore lists a user typed (a typo would otherwise leave a class in the means without a
    word); returns the unknown names.
    """
    _, unknown = resolve_ignore(ignore, class_names)
    if unknown:
        more = f", ... ({len(class_names)} in all)" if len(class_names) > shown else ""
        log.warning(
            "ignore names matching no class (so nothing is ignored for them): %s; classes: %s%s",
            ", ".join(repr(u) for u in unknown),
            ", ".join(class_names[:shown]),
            more,
        )
    return unknown


def segmentation_metrics(
    confusion: np.ndarray,
    class_names: Sequence[str] | None = None,
    ignore: Iterable[str | int] | None = None,
    ignored_gt_points: IgnoredGtPoints = "drop",
    protocol: str = "confusion",
    gt_present: Any | None = None,
    void_predicted: Any | None = None,
) -> SegmentationMetrics:
    """mIoU, F-mIoU, mAcc and per-class IoU/accuracy from a confusion matrix (see the module docstring).

    Args:
        confusion: [C, C+1] counts from :func:`confusion_matrix` (a square [C, C] matrix is accepted
            and treated as having no *no class* column).
        class_names: C names (default "class_<i>").
        ignore: class names or indices left out of the means.
        ignored_gt_points: "drop" or "false_positive", what the points of ignored GT classes do.
        protocol: recorded in the result so every output states how it was computed.
        gt_present: [C] bool, the classes present in the ground truth, for protocols whose matrix rows
            do not count GT points (ConceptGraphs counts predicted points): these classes, less the
            ignored ones, are evaluated even with no counted point (IoU 0, recall 0). None = the
            classes with support > 0.
        void_predicted: [C] counts of predictions on void GT points (:func:`void_predictions`); with
            ``ignored_gt_points="false_positive"`` they are false positives of their class, with
            "drop" they are dropped like every void point. None = none.

    Raises:
        ValueError: bad shapes/values, or no evaluated class has any counted point.
    """
    cm = _checked_confusion(confusion)
    c = cm.shape[0]
    names = list(class_names) if class_names is not None else [f"class_{i}" for i in range(c)]
    if len(names) != c:
        raise ValueError(f"class_names has {len(names)} entries but the confusion matrix has {c} classes")
    if ignored_gt_points not in ("drop", "false_positive"):
        raise ValueError(f"ignored_gt_points must be 'drop' or 'false_positive', got {ignored_gt_points!r}")
    ignore_idx, ignore_unknown = resolve_ignore(ignore, names)
    void_fp = _void_false_positives(void_predicted, c, ignored_gt_points)
    if ignored_gt_points == "drop" and ignore_idx:
        cm[ignore_idx, :] = 0
    tp = np.diag(cm[:, :c]).astype(np.float64)
    support = cm.sum(axis=1)
    predicted = cm[:, :c].sum(axis=0) + void_fp
    fp = predicted - tp
    fn = support - tp
    ignored_mask = np.zeros(c, dtype=bool)
    ignored_mask[ignore_idx] = True
    evaluated = _present_mask(gt_present, c) if gt_present is not None else support > 0
    evaluated &= ~ignored_mask
    if not support[evaluated].any():
        raise ValueError(
            f"no evaluated class has ground-truth points ({protocol}); "
            f"ignored: {[names[i] for i in ignore_idx]}"
        )
    with np.errstate(invalid="ignore", divide="ignore"):
        # An evaluated class with no counted point at all (only possible with gt_present) scores 0,
        # as in ConceptGraphs' max(1, denominator).
        iou = np.where(evaluated, tp / np.maximum(tp + fp + fn, 1), np.nan)
        acc = np.where(evaluated, tp / np.maximum(support, 1), np.nan)
    t = support[evaluated].astype(np.float64)
    return SegmentationMetrics(
        protocol=protocol,
        class_names=names,
        confusion=cm,
        iou=iou,
        acc=acc,
        support=support,
        predicted=predicted,
        evaluated=evaluated,
        ignored=[names[i] for i in ignore_idx],
        ignore_unknown=ignore_unknown,
        void_fp=void_fp,
        miou=float(np.mean(iou[evaluated])),
        fmiou=float(np.sum(t * iou[evaluated]) / t.sum()),
        macc=float(np.mean(acc[evaluated])),
        overall_acc=float(tp[evaluated].sum() / t.sum()),
    )


def _checked_confusion(confusion: Any) -> np.ndarray:
    """``confusion`` as a new int64 [C, C+1] matrix (a [C, C] one gets an empty *no class* column)."""
    cm = np.asarray(confusion)
    if cm.ndim != 2 or cm.shape[0] == 0:
        raise ValueError(f"confusion must be a [C, C+1] or [C, C] matrix, got shape {cm.shape}")
    c = cm.shape[0]
    if cm.shape[1] == c:
        cm = np.concatenate([cm, np.zeros((c, 1), dtype=cm.dtype)], axis=1)
    elif cm.shape[1] != c + 1:
        raise ValueError(f"confusion must be [C, C+1] or [C, C], got shape {cm.shape}")
    if not np.all(np.isfinite(cm)) or np.any(cm < 0):
        raise ValueError("confusion has negative or non-finite entries")
    return cm.astype(np.int64)  # (a copy: the caller zeroes the rows of dropped classes)


def _void_false_positives(void_predicted: Any, c: int, ignored_gt_points: str) -> np.ndarray:
    """Per class, the predictions on void GT points counted as its false positives (none when they are
    dropped)."""
    void_fp = np.zeros(c, dtype=np.int64)
    if void_predicted is not None:
        vp = np.asarray(void_predicted)
        if vp.shape != (c,) or not np.issubdtype(vp.dtype, np.integer) or np.any(vp < 0):
            raise ValueError(f"void_predicted must be [{c}] non-negative counts, got {vp.dtype} {vp.shape}")
        if ignored_gt_points == "false_positive":
            void_fp = vp.astype(np.int64)
    return void_fp


def _present_mask(gt_present: Any, num_classes: int) -> np.ndarray:
    mask = np.asarray(gt_present)
    if mask.dtype != bool or mask.shape != (num_classes,):
        raise ValueError(f"gt_present must be a [{num_classes}] bool array, got {mask.dtype} {mask.shape}")
    return mask.copy()


def format_metrics_table(metrics: SegmentationMetrics, per_class: bool = True) -> str:
    """A plain-text table (percentages) naming the protocol, for terminals and logs."""
    lines = [f"protocol: {metrics.protocol}"]
    if metrics.ignored:
        lines.append(f"ignored classes: {', '.join(metrics.ignored)}")
    if metrics.void_fp is not None and metrics.void_fp.any():
        lines.append(f"void GT points predicted as a class (false positives): {int(metrics.void_fp.sum())}")
    lines.append(
        f"mIoU {100 * metrics.miou:6.2f}   F-mIoU {100 * metrics.fmiou:6.2f}   "
        f"mAcc {100 * metrics.macc:6.2f}   oAcc {100 * metrics.overall_acc:6.2f}   "
        f"({metrics.num_evaluated} classes)"
    )
    if per_class:
        width = max([5] + [len(n) for n in metrics.class_names])
        lines.append(f"{'class':<{width}}  {'IoU':>6}  {'Acc':>6}  {'support':>9}  {'predicted':>9}")
        for i, n in enumerate(metrics.class_names):
            if not metrics.evaluated[i]:
                if metrics.predicted[i] == 0 and metrics.support[i] == 0:
                    continue
                why = "ignored" if n in metrics.ignored else "not in GT"
                lines.append(
                    f"{n:<{width}}  {'-':>6}  {'-':>6}  {metrics.support[i]:>9d}  "
                    f"{metrics.predicted[i]:>9d}  ({why})"
                )
                continue
            lines.append(
                f"{n:<{width}}  {100 * metrics.iou[i]:6.2f}  {100 * metrics.acc[i]:6.2f}  "
                f"{metrics.support[i]:>9d}  {metrics.predicted[i]:>9d}"
            )
    return "\n".join(lines)
