"""Render a run's semantic map at dataset poses: 2D semantic metrics and side-by-side pictures.

For scenes whose frames carry ground-truth class maps (synthetic scenes), the map in
``gaussians.ply`` is rendered with :func:`ogscene3d.render_semantics` at a few poses of the
scene's trajectory; rendered scene labels are named with the run's label mapping and compared with
the ground-truth class maps (:func:`~ogscene3d.eval.protocols.rendered_view_metrics`, paper Table I).
The poses are those the dataset reports (``traj.txt``, what the mapper was given): these are frames
of the mapped sequence, not held-out novel views (at most, frames a strided run skipped), and the
protocol string says so; the report lists the frames used.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError
from .metrics import SegmentationMetrics
from .plots import side_by_side, write_png
from .protocols import label_lookup, rendered_view_metrics
from .readers import GroundTruth

log = logging.getLogger(__name__)


@dataclass
class ViewsResult:
    metrics: SegmentationMetrics
    frames: list[int]  # dataset frame indices rendered
    pictures: list[Path]  # side-by-side PNGs written (empty when out_dir is None)


def pick_frames(num_frames: int, num_views: int) -> list[int]:
    """``num_views`` frame indices spread evenly over ``[0, num_frames)`` (first and last included)."""
    if num_frames <= 0 or num_views <= 0:
        return []
    return sorted({int(round(x)) for x in np.linspace(0, num_frames - 1, min(num_views, num_frames))})


def evaluate_views(
    run_dir: str | Path,
    scene_dir: str | Path,
    gt: GroundTruth,
    label_to_class: Mapping[int, int],
    num_views: int = 3,
    frames: Sequence[int] | None = None,
    out_dir: str | Path | None = None,
    device: str = "cpu",
    ignore: Sequence[str] | None = None,
) -> ViewsResult:
    """Render ``run_dir/gaussians.ply`` at dataset poses of ``scene_dir`` and score the label maps.

    Args:
        gt: the scene's ground truth (its ``class_ids`` translate the frames' class maps).
        label_to_class: scene label -> GT class index (the run's label mapping).
        num_views: evenly spread frames to render when ``frames`` is None.
        frames: explicit dataset frame indices.
        out_dir: where ``view_<frame name>.png`` (RGB | rendered | GT | confidence) go; None = none.
        device: rendering device ("cpu", "cuda", ...).
        ignore: class names left out of the 2D means.

    Raises:
        DataError: the scene has no ground-truth class maps, or a frame has no pose.
    """
    import torch

    from ..datasets import open_dataset
    from ..gaussians import GaussianMap
    from ..semantics import render_semantics

    ds = open_dataset(scene_dir)
    idx = list(frames) if frames is not None else pick_frames(len(ds), num_views)
    for i in idx:
        if not 0 <= i < len(ds):
            raise DataError(f"{scene_dir}: view frame {i} out of range [0, {len(ds)})")
    if not idx:
        raise DataError(f"{scene_dir}: no frames to render")
    gm = GaussianMap.read_ply(Path(run_dir) / "gaussians.ply", device=device)
    rendered, gts, pictures = [], [], []
    for i in idx:
        frame = ds[i]
        if frame.gt_classes is None:
            raise DataError(
                f"{scene_dir}: frame {i} has no ground-truth class map (only synthetic scenes do)"
            )
        if frame.pose is None:
            raise DataError(f"{scene_dir}: frame {i} has no pose to render from")
        viewmat = torch.as_tensor(np.linalg.inv(frame.pose), dtype=torch.float32, device=device)[None]
        K = torch.as_tensor(frame.K, dtype=torch.float32, device=device)[None]
        sem = render_semantics(
            gm.means, gm.quats, gm.scales, gm.opacities, gm.labels, gm.confidences, viewmat, K,
            frame.width, frame.height,
        )  # fmt: skip
        labels = sem.labels[0].cpu().numpy()
        gt_cls = gt.class_index_of_ids(frame.gt_classes)
        rendered.append(labels)
        gts.append(gt_cls)
        if out_dir is not None:
            pred_cls = label_lookup(label_to_class, labels)
            weights = sem.weights[0].cpu().numpy()
            weights = np.where(labels >= 0, weights, np.nan)
            pic = side_by_side(frame.rgb, pred_cls, gt_cls, weights,
                               titles=("RGB", "rendered labels", "ground truth", "confidence"))  # fmt: skip
            name = frame.name or f"{i:06d}"
            pictures.append(write_png(Path(out_dir) / f"view_{name}.png", pic))
    metrics = rendered_view_metrics(rendered, gts, label_to_class, gt.class_names, ignore=ignore)
    metrics = _with_protocol(metrics, f"{metrics.protocol}; frames {idx}")
    return ViewsResult(metrics=metrics, frames=idx, pictures=pictures)


def _with_protocol(m: SegmentationMetrics, protocol: str) -> SegmentationMetrics:
    from dataclasses import replace

    return replace(m, protocol=protocol)
