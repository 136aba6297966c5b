"""Render a run's semantic map at dataset poses: 2D semantic metrics and side-by-side pictures.

For sequences whose frames carry ground-truth class maps (``Frame.gt_classes``: synthetic scenes,
label-fusion's ``segm`` images, ScanNet's ``label-filt`` with its label map), the map in
``gaussians.ply`` is rendered with :func:`ogscene3d.render_semantics` at a few poses of the
sequence; rendered scene labels are named with the run's label mapping and compared with the
ground-truth class maps (:func:`~ogscene3d.eval.protocols.rendered_view_metrics`, paper Table I).
The poses are those the dataset reports (what the mapper was given): by default frames spread over the
whole mapped sequence, not held-out novel views (at most, frames a strided run skipped), and the protocol
string says so; the report lists the frames used. With ``held_out`` the frames are chosen among those the
run did not map (:mod:`~ogscene3d.eval.held_out`): novel views, and the protocol string says that instead.

Without 3D ground truth the scene labels can also be named from the renders
(:func:`overlap_mapping_2d`, majority overlap with the GT class maps: an oracle naming, like the 3D
overlap mapping); the frames it used are reported beside the frames scored. Held-out views are not named
from themselves: the naming frames default to mapped frames then.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..config import DataConfig
from ..datasets import detect_kind, open_dataset
from ..datasets.identity import mapped_intrinsics, matching_pixel_centers
from ..datasets.semantic_nerf import is_sequence, sequence_dirs
from ..errors import ConfigError, DataError
from ..gaussians import GaussianMap
from ..rendering import render_semantics
from ..runs import RunFolder, read_config, recorded_data_path
from .held_out import HeldOut, check_held_out, naming_frames, pick_frames, pick_held_out, run_frames
from .label_mapping import majority_overlap_mapping
from .metrics import SegmentationMetrics
from .plots import side_by_side, write_png
from .protocols import (
    EXTRAPOLATED_VIEW_PROTOCOL,
    HELD_OUT_VIEW_PROTOCOL,
    RENDERED_VIEW_PROTOCOL,
    label_lookup,
    rendered_view_metrics,
)
from .readers import GroundTruth

log = logging.getLogger(__name__)


@dataclass
class ViewsResult:
    metrics: SegmentationMetrics
    frames: list[int]  # dataset frame indices rendered
    pictures: list[Path]  # side-by-side PNGs written (empty when out_dir is None)


@dataclass
class RenderedView:
    """One dataset frame with the map rendered at its pose."""

    frame: int  # index in the dataset (all frames, stride 1)
    name: str  # the frame's file stem
    labels: np.ndarray  # [H, W] int64 scene labels, -1 where nothing labelled was rendered
    weights: np.ndarray  # [H, W] float32 rendered label confidence
    gt: np.ndarray  # [H, W] int64 GT class indices, -1 = void
    rgb: np.ndarray  # [H, W, 3] uint8


def spread_frames(ds: Any, num_views: int) -> tuple[list[int], int]:
    """``num_views`` frames of ``ds`` spread evenly over those with a valid pose, and how many frames were
    passed over for want of one. Frames asked for by number must render; an even spread need not land
    on a frame whose tracking was lost (ScanNet writes -inf poses there)."""
    usable = [i for i in range(len(ds)) if ds.has_valid_pose(i)]
    passed_over = len(ds) - len(usable)
    if passed_over:
        log.warning("%s: %d frames without a valid pose are not rendered", ds.root, passed_over)
    return [usable[j] for j in pick_frames(len(usable), num_views)], passed_over


def open_view_dataset(scene_dir: str | Path, run_dir: str | Path | None = None) -> Any:
    """Every frame of the sequence in ``scene_dir``, read with the run's data settings (layout, intrinsics,
    depth format) when ``run_dir`` mapped that folder, so that renders use the camera the mapper used; the
    run's frame selection (start, stride, max_frames) is not applied."""
    cfg = DataConfig()
    if run_dir is not None:
        recorded = recorded_data_path(run_dir)
        if recorded is not None and same_sequence(recorded, scene_dir):
            try:
                data = read_config(run_dir).data
                # eval renders the map and reads no segments (a frame the run did not map may have none)
                cfg = dataclasses.replace(data, start=0, stride=1, max_frames=None, segments_dir=None)
            except ConfigError as e:  # e.g. written by another version: the files' own settings then
                log.warning("%s; rendering with %s's own camera settings", e, scene_dir)
    cfg.path = str(scene_dir)
    ds = open_dataset(config=cfg)
    if run_dir is not None:
        mapped_K = mapped_intrinsics(RunFolder(run_dir).map)
        if mapped_K is not None and not np.allclose(mapped_K, np.asarray(ds.K).reshape(-1), atol=1e-3):
            setting = matching_pixel_centers(ds, mapped_K)
            if setting is not None:
                # mapped before data.pixel_centers shifted this layout's intrinsics, or under the other
                # setting: render with the camera it was mapped with
                log.info(
                    "%s was mapped with %s read with data.pixel_centers=%s: rendering so",
                    run_dir,
                    scene_dir,
                    setting,
                )
                ds = open_dataset(config=dataclasses.replace(cfg, pixel_centers=setting))
    return ds


def _sequence_folder(path: str | Path) -> Path:
    """The folder whose frames ``open_dataset(path)`` reads: ``path``, the one scene a parent folder holds, or
    a Semantic-NeRF scene folder's first ``Sequence_N/``."""
    try:
        kind, root = detect_kind(path)
    except DataError:
        return Path(path).resolve()
    if kind == "semantic_nerf" and not is_sequence(root) and (seqs := sequence_dirs(root)):
        root = seqs[0]
    return Path(root).resolve()


def same_sequence(recorded: str | Path, folder: str | Path) -> bool:
    """Whether a run's ``data.path`` and ``folder`` name the same frames: a run of ``Replica_Dataset/room_0``
    mapped ``room_0/Sequence_1``, which eval opens from either path."""
    if Path(recorded).resolve() == Path(folder).resolve():
        return True
    return _sequence_folder(recorded) == _sequence_folder(folder)


def render_views(
    run_dir: str | Path,
    ds: Any,
    gt: GroundTruth,
    frames: Iterable[int],
    device: str = "cpu",
) -> dict[int, RenderedView]:
    """Render ``run_dir/gaussians.ply`` at the poses of ``frames`` of dataset ``ds``.

    Raises:
        DataError: a frame index is out of range, or a frame has no ground-truth class map or no pose.
    """
    idx = sorted(set(frames))
    for i in idx:
        if not 0 <= i < len(ds):
            raise DataError(f"{ds.root}: view frame {i} out of range [0, {len(ds)})")
    gm = GaussianMap.read_ply(RunFolder(run_dir).gaussians, device=device)
    out: dict[int, RenderedView] = {}
    for i in idx:
        frame = ds[i]
        if frame.gt_classes is None:
            raise DataError(f"{ds.root}: frame {i} ({frame.name}) has no ground-truth class map")
        if frame.pose is None:
            raise DataError(f"{ds.root}: frame {i} ({frame.name}) has no pose to render from")
        viewmat = torch.as_tensor(np.linalg.inv(frame.pose), dtype=torch.float32, device=device)[None]
        K = torch.as_tensor(frame.K, dtype=torch.float32, device=device)[None]
        sem = render_semantics(
            gm.means, gm.quats, gm.scales, gm.opacities, gm.labels, gm.confidences, viewmat, K,
            frame.width, frame.height,
        )  # fmt: skip
        out[i] = RenderedView(
            frame=i,
            name=frame.name or f"{i:06d}",
            labels=sem.labels[0].cpu().numpy().astype(np.int64),
            weights=sem.weights[0].cpu().numpy(),
            gt=gt.class_index_of_ids(frame.gt_classes),
            rgb=frame.rgb,
        )
    return out


def overlap_mapping_2d(views: Iterable[RenderedView]) -> dict[int, int]:
    """Scene label -> GT class index by majority pixel overlap of the rendered labels with the GT class
    maps of ``views`` (pixels summed over all of them; ties go to the smaller class index). It reads
    the ground truth to name labels: an oracle naming, as the 3D overlap mapping is."""
    labels, classes, counts = [], [], []
    for v in views:
        ok = (v.labels >= 0) & (v.gt >= 0)
        pairs, n = np.unique(np.stack([v.labels[ok], v.gt[ok]]), axis=1, return_counts=True)
        labels.append(pairs[0])
        classes.append(pairs[1])
        counts.append(n)
    if not labels:
        return {}
    mapping = majority_overlap_mapping(
        np.concatenate(labels), np.concatenate(classes), weights=np.concatenate(counts)
    )
    return {k: c for k, c in mapping.items() if c >= 0}


@dataclass
class ViewSet:
    """The renders eval needs: the frames scored and the frames that name scene labels (2D overlap)."""

    source: str  # the sequence folder
    kind: str  # its layout
    views: dict[int, RenderedView]  # every frame of either list, rendered once
    frames: list[int]  # scored
    mapping_frames: list[int]  # for a 2D overlap naming
    passed_over: int = 0  # frames without a valid pose the even spread of ``num_views`` left out
    held_out: HeldOut | None = None  # the scored frames are held-out views (``prepare_views(held_out=True)``)
    # without held_out: the scored frames the run mapped (None: unknown, e.g. no config.yaml in the run)
    scored_mapped: list[int] | None = None


def prepare_views(
    run_dir: str | Path,
    gt_path: str | Path,
    gt: GroundTruth,
    num_views: int = 3,
    frames: Sequence[int] | None = None,
    mapping_frames: Sequence[int] | None = None,
    device: str = "cpu",
    held_out: bool = False,
) -> tuple[ViewSet | None, str]:
    """Render the frames eval scores (``frames``, else ``num_views`` evenly spread) and those that may name
    the scene labels (``mapping_frames``, else the scored ones).

    With ``held_out`` the scored frames are frames the run did not map: ``num_views`` spread evenly over
    them (:func:`~ogscene3d.eval.held_out.pick_held_out`), or ``frames``, refused if the run mapped one;
    without ``mapping_frames`` and without 3D ground truth the naming frames are as many mapped frames,
    so that an oracle naming does not read the views it is scored on.

    The sequence is ``gt_path`` when it is a folder whose frames carry class maps, else the run's
    ``data.path`` when ``gt_path`` lies inside it (``SCENE/gt``, ``SCENE/*_vh_clean_2.labels.ply``): the
    same scene, whose class ids the ground truth's table covers.

    Returns:
        (the renders, "") or (None, why no frame can be scored) when no such sequence is at hand.

    Raises:
        DataError: a frame is out of range, or a chosen frame has no class map or no pose; with
            ``held_out``, the run mapped every frame or one of ``frames``.
    """
    if gt.class_ids is None:
        return None, "the ground truth has no class-id table to read per-frame class maps with"
    gt_path = Path(gt_path)
    candidates = [gt_path] if gt_path.is_dir() else []
    data = recorded_data_path(run_dir)
    if data is not None and gt_path.resolve().is_relative_to(data.resolve()):
        candidates.append(data)
    for folder in candidates:
        try:
            detect_kind(folder)
        except DataError:
            continue
        ds = open_view_dataset(folder, run_dir)
        if not ds.has_class_maps:
            continue
        held: HeldOut | None = None
        scored_mapped: list[int] | None = None
        if held_out:
            run = run_frames(run_dir, ds)
            held = check_held_out(ds, run, frames) if frames else pick_held_out(ds, run, num_views)
            idx, passed_over = held.frames, held.passed_over
        else:
            idx, passed_over = (list(frames), 0) if frames else spread_frames(ds, num_views)
            scored_mapped = _scored_mapped(run_dir, ds, idx)
        if not idx:
            why = (
                f"no frame of {ds.root} has a valid pose"
                if passed_over
                else f"no frames of {ds.root} asked for"
            )
            return None, why
        naming = list(mapping_frames) if mapping_frames else idx
        if held is not None and not mapping_frames and not gt.has_3d:
            naming = naming_frames(ds, held.run, len(idx))
            if not naming:
                raise DataError(
                    f"{ds.root}: none of the frames the run mapped has a valid pose to name the scene labels "
                    "from; give --mapping-frames"
                )
        views = render_views(run_dir, ds, gt, [*idx, *naming], device)
        return ViewSet(str(ds.root), ds.kind, views, idx, naming, passed_over, held, scored_mapped), ""
    where = " or ".join(str(c) for c in candidates) or str(gt_path)
    return None, f"{where} is no RGB-D sequence whose frames carry ground-truth class maps"


def _scored_mapped(run_dir: str | Path, ds: Any, frames: Sequence[int]) -> list[int] | None:
    """Which of ``frames`` the run mapped, when its config.yaml tells and names this sequence (None
    otherwise): the report of an ordinary 2D eval says how many of its views the mapper saw."""
    recorded = recorded_data_path(run_dir)
    if recorded is None or not same_sequence(recorded, ds.root):
        return None
    try:
        mapped = set(run_frames(run_dir, ds).mapped)
    except DataError as e:
        log.debug("which scored frames the run mapped is unknown: %s", e)
        return None
    return [i for i in frames if i in mapped]


def score_views(
    views: Mapping[int, RenderedView],
    frames: Sequence[int],
    gt: GroundTruth,
    label_to_class: Mapping[int, int],
    out_dir: str | Path | None = None,
    ignore: Sequence[str] | None = None,
    held_out: HeldOut | None = None,
) -> ViewsResult:
    """2D metrics of the rendered ``frames`` (keys of ``views``) and, with ``out_dir``, one
    ``view_<frame name>.png`` (RGB | rendered | GT | confidence) per frame. ``held_out``: the frames are
    held-out views (the protocol string says so)."""
    if not frames:
        raise ValueError("no frames to score")
    pictures = []
    for i in frames:
        v = views[i]
        if out_dir is not None:
            pred_cls = label_lookup(label_to_class, v.labels)
            weights = np.where(v.labels >= 0, v.weights, np.nan)
            pic = side_by_side(v.rgb, pred_cls, v.gt, weights,
                               titles=("RGB", "rendered labels", "ground truth", "confidence"))  # fmt: skip
            pictures.append(write_png(Path(out_dir) / f"view_{v.name}.png", pic))
    kind = RENDERED_VIEW_PROTOCOL
    if held_out is not None:
        kind = EXTRAPOLATED_VIEW_PROTOCOL if held_out.extrapolated else HELD_OUT_VIEW_PROTOCOL
    metrics = rendered_view_metrics(
        [views[i].labels for i in frames], [views[i].gt for i in frames], label_to_class, gt.class_names,
        ignore=ignore, views=kind,
    )  # fmt: skip
    metrics = dataclasses.replace(metrics, protocol=f"{metrics.protocol}; frames {list(frames)}")
    return ViewsResult(metrics=metrics, frames=list(frames), pictures=pictures)


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
    ds = open_view_dataset(scene_dir, run_dir)
    idx = list(frames) if frames is not None else spread_frames(ds, num_views)[0]
    if not idx:
        raise DataError(f"{scene_dir}: no frames to render")
    views = render_views(run_dir, ds, gt, idx, device)
    return score_views(views, idx, gt, label_to_class, out_dir, ignore)
