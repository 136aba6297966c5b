"""Evaluate one run directory against its ground truth: the engine behind ``ogscene3d eval``.

Steps: read ``gaussians.ply`` (+ ``graph.json``) and the ground truth; name the scene labels with GT
classes (text matching of node tags, or majority overlap); score 3D semantic segmentation with the
requested protocol(s); score relation recall when the ground truth has relation triplets and the
run has a graph; score renders at dataset frames that carry class maps; optionally score the
trajectory. A sequence with per-frame class maps but no 3D ground truth (label-fusion) is scored in
2D only, its overlap naming made from the renders. The result is a JSON-safe dict in which every
block states its protocol.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from ..datasets.scannet import SCANNET20_CLASSES
from ..device import resolve_device
from ..errors import DataError
from .graph_metrics import match_nodes_by_overlap, relation_recall
from .label_mapping import TextEmbedder, TextMatch, majority_overlap_mapping, text_label_mapping
from .metrics import SegmentationMetrics, warn_unknown_ignore
from .options import EvalOptions
from .protocols import (
    evaluate_semantic_3d,
    label_lookup,
    nearest_neighbors,
)
from .queries import queries_block
from .readers import GroundTruth, RunData, load_ground_truth, read_run
from .rooms import rooms_block
from .views import ViewSet, overlap_mapping_2d, prepare_views, score_views

log = logging.getLogger(__name__)

MappingMethod = Literal["auto", "text", "overlap"]


@dataclass
class EvalResult:
    """Everything one evaluation produced; ``report`` is what goes to ``metrics.json``."""

    report: dict[str, Any]
    semantic: dict[str, SegmentationMetrics]  # protocol name -> metrics
    label_to_class: dict[int, int]
    views: SegmentationMetrics | None = None  # 2D metrics of the rendered views, when asked for


def _subset(run: RunData, keep: np.ndarray) -> RunData:
    """The Gaussians of ``run`` where ``keep`` is True (the graph stays as it is)."""
    return RunData(
        run.means[keep],
        run.labels[keep],
        run.confidences[keep],
        None if run.opacities is None else run.opacities[keep],
        run.graph,
    )


def _associate(run: RunData, gt: GroundTruth, radius: float | None) -> np.ndarray:
    """Index of the nearest GT point of every Gaussian (-1 when farther than ``radius``)."""
    _, idx = nearest_neighbors(gt.points, run.means, k=1, max_distance=radius)
    return idx[:, 0]


def build_label_mapping(
    run: RunData,
    gt: GroundTruth,
    method: MappingMethod = "auto",
    assoc: np.ndarray | None = None,
    embedder: TextEmbedder | None = None,
    overlap_2d: tuple[dict[int, int], list[int]] | None = None,
) -> tuple[dict[int, int], dict[str, Any]]:
    """Scene label -> GT class index, and a JSON-safe description of how it was built.

    ``auto`` uses text matching when ``graph.json`` has node tags from a real captioner (not the offline
    heuristic one, whose "floor"/"wall"/"small red object" tags name no objects) and at least one of them
    names a class, and majority overlap otherwise. The overlap method needs ``assoc`` (Gaussian -> GT
    point index, -1 = none) or, without 3D ground truth, ``overlap_2d``: the mapping
    :func:`~ogscene3d.eval.views.overlap_mapping_2d` made from renders, and the frames it used.
    """
    tags, heuristic = _node_tags(run.graph)
    labels_present = np.unique(run.labels[run.labels >= 0])
    text = text_label_mapping(tags, gt.class_names, embedder=embedder) if tags else {}
    n_text = sum(1 for k, m in text.items() if m.class_index >= 0 and k not in heuristic)
    if method == "auto":
        method = "text" if n_text > 0 else "overlap"
    if method == "text":
        if run.graph is None:
            raise DataError("label mapping 'text' needs graph.json with node tags in the run directory")
        mapping, info = _text_naming(text, len(tags), gt, embedder is not None)
    elif method == "overlap" and assoc is None and overlap_2d is not None:
        mapping = dict(overlap_2d[0])
        info = {
            "method": "overlap",
            "description": "majority pixel overlap of the rendered labels with the GT class maps of "
            f"frames {overlap_2d[1]} (uses the ground truth: an oracle naming)",
            "space": "2d",
            "frames": list(overlap_2d[1]),
        }
    elif method == "overlap":
        if assoc is None:
            raise ValueError("overlap label mapping needs the Gaussian -> GT point association")
        mapping, info = _overlap_naming_3d(run, gt, assoc)
    else:
        raise ValueError(f"unknown label mapping method {method!r}; expected auto, text or overlap")
    info["num_scene_labels"] = int(labels_present.size)
    info["num_mapped_labels"] = (
        int(np.isin(labels_present, np.fromiter(mapping, np.int64)).sum()) if mapping else 0
    )
    return mapping, info


def _node_tags(graph: dict[str, Any] | None) -> tuple[dict[int, str], set[int]]:
    """The tag of each graph node that has one, and the nodes whose tag is the offline heuristic
    captioner's ("detector" tags are class names: they count)."""
    tags: dict[int, str] = {}
    heuristic: set[int] = set()
    for n in graph["nodes"] if graph is not None else ():
        tag = n.get("tag") or ""
        if isinstance(tag, str) and tag.strip():
            tags[int(n["id"])] = tag
            if n.get("caption_source") == "heuristic":
                heuristic.add(int(n["id"]))
    return tags, heuristic


def _text_naming(
    text: dict[int, TextMatch], num_tags: int, gt: GroundTruth, with_embedder: bool
) -> tuple[dict[int, int], dict[str, Any]]:
    """The text matches of the node tags as a mapping, and its description."""
    mapping = {k: m.class_index for k, m in text.items() if m.class_index >= 0}
    methods: dict[str, int] = {}
    for m in text.values():
        methods[m.method] = methods.get(m.method, 0) + 1
    info = {
        "method": "text",
        "description": "graph node tags matched to class names (exact / synonym / head noun"
        + (" / embedding" if with_embedder else "")
        + ")",
        "num_tags": num_tags,
        "matches_by_method": methods,
        "per_label": {
            str(k): {
                "tag": m.tag,
                "class": gt.class_names[m.class_index] if m.class_index >= 0 else None,
                "method": m.method,
            }
            for k, m in sorted(text.items())
        },
    }
    return mapping, info


def _overlap_naming_3d(
    run: RunData, gt: GroundTruth, assoc: np.ndarray
) -> tuple[dict[int, int], dict[str, Any]]:
    """Scene labels named by majority overlap with the GT instances (then their class) or classes of the
    Gaussians' nearest GT points, and its description."""
    ok = assoc >= 0
    if gt.instances is not None and gt.instance_classes:
        gt_ids = np.where(ok, gt.instances[np.maximum(assoc, 0)], -1)
        mapping = majority_overlap_mapping(run.labels, gt_ids, id_to_class=gt.instance_classes)
        desc = "majority overlap with GT instances (class-agnostic), then the instance's class"
    else:
        gt_ids = np.where(ok, gt.classes[np.maximum(assoc, 0)], -1)
        mapping = majority_overlap_mapping(run.labels, gt_ids)
        desc = "majority overlap with GT classes"
    mapping = {k: v for k, v in mapping.items() if v >= 0}
    info = {
        "method": "overlap",
        "description": desc + " (uses the ground truth: an oracle naming)",
        "space": "3d",
    }
    return mapping, info


def evaluate_run(
    run_dir: str | Path,
    gt_path: str | Path,
    options: EvalOptions | None = None,
    *,
    embedder: TextEmbedder | None = None,
    out_dir: str | Path | None = None,
    device: str | torch.device = "cpu",
    **settings: Any,
) -> EvalResult:
    """Evaluate ``run_dir`` against ``gt_path`` (see the module docstring).

    Args:
        options: how to score (:class:`~ogscene3d.eval.options.EvalOptions`, its defaults when None);
            ``settings`` change single fields by name, e.g. ``protocols=["hovsg"], ignore=[],
            mapping="overlap"`` (an unknown name is a TypeError). The fields:
            ``protocols`` (any of "hovsg", "conceptgraphs"); ``ignore`` (class names left out of the means;
            None = each protocol's default); ``mapping`` ("auto", "text" or "overlap", see
            :func:`build_label_mapping`); ``classes`` (class-name table for a bare labelled PLY ground truth
            or a sequence's class maps); ``k`` (neighbours of the HOV-SG vote); ``min_opacity`` (Gaussians
            below it are left out as floaters; unlabelled Gaussians stay: misses under conceptgraphs, no vote
            under hovsg, ``unlabelled_fraction``); ``assoc_radius`` (metres; a Gaussian farther than this
            from every GT point takes no part in the overlap label mapping and node matching, None = no
            limit; the protocols themselves use no radius, as in the original code); ``min_node_iou`` (IoU a
            node needs to match a GT instance for relation recall); ``num_views`` / ``view_frames`` (render
            the map at that many evenly spread dataset frames, or at the given frame indices, of
            ``gt_path`` when it is a sequence with ground-truth class maps, and report 2D semantic metrics
            "semantic_2d"; 0 / None = no rendering, which a ground truth without 3D points refuses);
            ``gt_points`` ("observed" scores only the GT points that some frame saw, when the ground truth
            says which: synthetic scenes' ``observed`` in gt/points.ply; "all" scores every point, as
            HOV-SG does on its meshes); ``cg_voxel_size`` (metres; conceptgraphs resamples the Gaussians to
            one point per scene label and voxel of this size, 0 = every Gaussian); ``mapping_frames``
            (without 3D ground truth, the frames whose renders the overlap naming reads; None = the scored
            frames, or with ``held_out`` as many frames the run mapped); ``held_out`` (score frames the run
            did not map, :mod:`~ogscene3d.eval.held_out`: ``num_views`` spread evenly over them, or
            ``view_frames``, refused if the run mapped one); ``plots`` (false: no pictures).
        embedder: text embeddings for the text label mapping (None: words only).
        out_dir: where the side-by-side view PNGs go (None = no pictures).
        device: rendering device.

    Returns:
        The report (what ``metrics.json`` holds: every block states its protocol, None where it could not
        be scored, with a note saying why), the metrics per protocol, the label naming and the 2D metrics.

    Raises:
        DataError: an unreadable run or ground truth, no labelled Gaussian, or nothing that can be scored.
        ConfigError: options out of their rules.
    """
    opts = (options or EvalOptions()).replace(**settings)
    opts.check()
    out_dir = out_dir if opts.plots else None
    device = resolve_device(device)
    run_data = read_run(run_dir)
    gt = load_ground_truth(gt_path, opts.classes)
    want_views = opts.num_views > 0 or bool(opts.view_frames)
    if not gt.has_3d and not want_views:
        raise DataError(
            f"{gt.source}: no 3D ground truth, only per-frame class maps: render views to score (--views N)"
        )
    scored, labelled = _scored_gaussians(run_data, opts.min_opacity, run_dir)
    run = _subset(scored, labelled)
    notes: list[str] = []
    mapping_frames = _mapping_frames(gt, gt_path, opts.mapping_frames, notes)
    # Rendered before the naming: without 3D ground truth the overlap naming reads the renders.
    rendered = _render_views(run_dir, gt_path, gt, opts, mapping_frames, device, notes)
    assoc = _associate(run, gt, opts.assoc_radius) if gt.has_3d else None
    label_to_class, mapping_info = _name_labels(run, gt, opts, assoc, embedder, rendered, notes)
    _check_ignore(opts.ignore, gt, notes)
    gt_classes, gt_block = _scored_gt_points(gt, opts.gt_points, notes)
    semantic = _semantic_3d(scored, labelled, gt, gt_classes, gt_block, label_to_class, opts)
    graph_block = _graph_block(run, gt, assoc, opts, notes)
    rooms, queries = _rooms_and_queries(run, scored, gt, assoc, gt_block, opts.min_node_iou, notes)
    semantic_2d, views = (None, None) if rendered is None else _views_block(
        rendered, gt, label_to_class, out_dir, opts.ignore, mapping_info.get("space") == "2d"
    )  # fmt: skip
    semantic_3d = {p: m.to_dict() for p, m in semantic.items()}
    report = _report(run_dir, gt, scored, labelled, gt_points=gt_block, label_mapping=mapping_info,
                     semantic_3d=semantic_3d, semantic_2d=semantic_2d, scene_graph=graph_block,
                     rooms=rooms, queries=queries, notes=notes)  # fmt: skip
    return EvalResult(report=report, semantic=semantic, label_to_class=label_to_class, views=views)


def _report(
    run_dir: str | Path, gt: GroundTruth, scored: RunData, labelled: np.ndarray, **blocks: Any
) -> dict[str, Any]:
    """``metrics.json``: what was scored, then ``blocks`` in their order (None where not scored)."""
    return {
        "version": 1,
        "run_dir": str(run_dir),
        "ground_truth": gt.source,
        "num_gaussians_evaluated": int(scored.means.shape[0]),
        "num_gaussians_labelled": int(labelled.sum()),
        "unlabelled_fraction": 1.0 - float(labelled.mean()),
        "num_gt_points": int(gt.points.shape[0]),
        "has_3d_ground_truth": gt.has_3d,
        **blocks,
    }


def _mapping_frames(
    gt: GroundTruth, gt_path: str | Path, mapping_frames: Sequence[int] | None, notes: list[str]
) -> Sequence[int] | None:
    """The frames whose renders the overlap naming reads: only without 3D ground truth (else named in 3D)."""
    if not gt.has_3d:
        notes.append(f"no 3D ground truth in {gt_path}: rendered-view (2D) scores only")
    elif mapping_frames:
        notes.append("mapping frames not used: with 3D ground truth the overlap mapping is made in 3D")
        return None
    return mapping_frames


def _scored_gaussians(run: RunData, min_opacity: float, run_dir: str | Path) -> tuple[RunData, np.ndarray]:
    """The Gaussians every protocol is given (those above ``min_opacity``, unlabelled ones included) and
    which of them are labelled.

    ConceptGraphs counts on predicted points, so an unlabelled Gaussian is a miss there, while HOV-SG's vote
    leaves it out (pred_labelled). Label naming and node matching look at labelled Gaussians only."""
    scored = run
    if min_opacity > 0 and run.opacities is not None:
        scored = _subset(run, run.opacities >= min_opacity)
    labelled = scored.labels >= 0
    if not labelled.any():
        raise DataError(f"{run_dir}: no labelled Gaussians to evaluate (min_opacity={min_opacity})")
    return scored, labelled


def _render_views(
    run_dir: str | Path,
    gt_path: str | Path,
    gt: GroundTruth,
    opts: EvalOptions,
    mapping_frames: Sequence[int] | None,
    device: torch.device,
    notes: list[str],
) -> ViewSet | None:
    """The map rendered at the scored (and naming) frames; None when no views are asked for, or, with a
    note, when they cannot be rendered (an error when nothing else could be scored)."""
    if not (opts.num_views > 0 or opts.view_frames):
        return None
    rendered, why = prepare_views(
        run_dir, gt_path, gt, opts.num_views, opts.view_frames, mapping_frames, device, opts.held_out
    )
    if rendered is None and not gt.has_3d:
        raise DataError(f"nothing to score: {why}")
    if rendered is None:
        notes.append(f"2D views skipped: {why}")
    elif rendered.passed_over:
        notes.append(
            f"2D views: {rendered.passed_over} frames without a valid pose (lost tracking) were not "
            "among the evenly spread frames"
        )
    return rendered


def _name_labels(
    run: RunData,
    gt: GroundTruth,
    opts: EvalOptions,
    assoc: np.ndarray | None,
    embedder: TextEmbedder | None,
    rendered: ViewSet | None,
    notes: list[str],
) -> tuple[dict[int, int], dict[str, Any]]:
    """The GT class of each scene label (:func:`build_label_mapping`; from the renders without 3D ground
    truth) and the mapping's report, with a note when few Gaussians got a class."""
    overlap_2d = None
    if rendered is not None and not gt.has_3d:
        pick = rendered.mapping_frames
        overlap_2d = (overlap_mapping_2d(rendered.views[i] for i in pick), pick)
    label_to_class, mapping_info = build_label_mapping(run, gt, opts.mapping, assoc, embedder, overlap_2d)
    if rendered is not None and rendered.held_out is not None:
        notes.extend(_held_out_notes(rendered, mapping_info.get("space") == "2d"))
    named = float((label_lookup(label_to_class, run.labels) >= 0).mean())
    mapping_info["fraction_of_gaussians_named"] = named
    if named < 0.5:
        notes.append(
            f"only {100 * named:.0f}% of the labelled Gaussians have a GT class under the "
            f"'{mapping_info['method']}' label mapping; the others are predictions of no class "
            "(they vote 'no class' under hovsg and are misses under conceptgraphs)"
        )
    return label_to_class, mapping_info


def _check_ignore(ignore: Sequence[str] | None, gt: GroundTruth, notes: list[str]) -> None:
    """Warn about names of the ignore list that are no class (a typo would otherwise leave that class in
    the means without a word) and about a HOV-SG ScanNet preset over other classes."""
    if ignore is None:
        return
    warn_unknown_ignore(ignore, gt.class_names)
    # (classes without a 3D point never enter the 3D means; without 3D GT every class may)
    present = [n for i, n in enumerate(gt.class_names) if not gt.has_3d or np.any(gt.classes == i)]
    if (why := _hovsg_scannet_mismatch(ignore, present)) is not None:
        log.warning("%s", why)
        notes.append(why)


def _scored_gt_points(
    gt: GroundTruth, gt_points: str, notes: list[str]
) -> tuple[np.ndarray, dict[str, Any] | None]:
    """The GT classes scored (-1 for the points left out) and the report's ``gt_points`` block (None
    without 3D ground truth)."""
    if not gt.has_3d:
        return gt.classes, None
    if gt_points == "observed" and gt.observed is not None:
        gt_classes = np.where(gt.observed, gt.classes, -1)
        return gt_classes, {
            "points": "observed",
            "num_scored": int((gt_classes >= 0).sum()),
            "observed_fraction": float(gt.observed.mean()) if gt.observed.size else 0.0,
        }
    if gt_points == "observed":
        notes.append("the ground truth does not say which points were observed: every GT point is scored")
    return gt.classes, {"points": "all", "num_scored": int((gt.classes >= 0).sum())}


def _semantic_3d(
    scored: RunData,
    labelled: np.ndarray,
    gt: GroundTruth,
    gt_classes: np.ndarray,
    gt_block: dict[str, Any] | None,
    label_to_class: dict[int, int],
    opts: EvalOptions,
) -> dict[str, SegmentationMetrics]:
    """3D semantic metrics per protocol (none without 3D ground truth)."""
    semantic: dict[str, SegmentationMetrics] = {}
    scored_classes = label_lookup(label_to_class, scored.labels)
    for p in opts.protocols if gt.has_3d else ():
        gt_pts, gt_cls = gt.points, gt_classes
        if p == "hovsg" and gt_block is not None and gt_block["points"] == "observed":
            # HOV-SG counts predictions on void GT points as false positives: unobserved points leave
            # the cloud instead (HOV-SG's vote of a GT point does not depend on the other GT points).
            gt_pts, gt_cls = gt.points[gt.observed], gt_classes[gt.observed]
        semantic[p] = evaluate_semantic_3d(
            scored.means,
            scored_classes,
            gt_pts,
            gt_cls,
            gt.class_names,
            protocol=p,  # type: ignore[arg-type]
            ignore=opts.ignore,
            k=opts.k,
            pred_labelled=labelled,
            pred_labels=scored.labels,
            voxel_size=opts.cg_voxel_size,
        )
    return semantic


def _graph_block(
    run: RunData, gt: GroundTruth, assoc: np.ndarray | None, opts: EvalOptions, notes: list[str]
) -> dict[str, Any] | None:
    """Relation recall of the run's scene graph, nodes matched to GT instances in 3D; None (with a note
    saying why, where one helps) when it cannot be scored."""
    if not gt.has_3d:
        return None  # nodes are matched to GT instances in 3D
    if not gt.relations:
        notes.append("scene graph not scored: the ground truth has no relation triplets")
        return None
    if run.graph is None:
        notes.append("scene graph not scored: the run directory has no graph.json")
        return None
    if gt.instances is None:
        notes.append("scene graph not scored: the ground truth has no instance ids")
        return None
    assert assoc is not None  # (there is 3D ground truth)
    gt_inst = np.where(assoc >= 0, gt.instances[np.maximum(assoc, 0)], -1)
    # Only labels that are graph nodes compete for GT instances.
    node_ids = np.array(sorted({int(n["id"]) for n in run.graph["nodes"]}), dtype=np.int64)
    node_labels = np.where(np.isin(run.labels, node_ids), run.labels, -1)
    matches = match_nodes_by_overlap(node_labels, gt_inst, min_iou=opts.min_node_iou)
    conventions: dict[str, Any] = {}
    if gt.symmetric_relations is not None:
        conventions["symmetric"] = gt.symmetric_relations
    if gt.inverse_relations is not None:
        conventions["inverses"] = gt.inverse_relations
    rr = relation_recall(
        gt.relations,
        run.graph["edges"],
        matches,
        **conventions,
        protocol=f"relation recall (nodes matched to GT instances by point IoU >= {opts.min_node_iou}, "
        f"Gaussians paired with their nearest GT point within {opts.assoc_radius} m; "
        "unmatched endpoints are misses)",
    )
    return rr.to_dict()


def _rooms_and_queries(
    run: RunData,
    scored: RunData,
    gt: GroundTruth,
    assoc: np.ndarray | None,
    gt_block: dict[str, Any] | None,
    min_node_iou: float,
    notes: list[str],
) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """Room segmentation (when the GT has rooms) and query accuracy (when it has instances), each None when
    it cannot be scored (a note says why)."""
    if not gt.has_3d or run.graph is None or gt.instances is None or assoc is None:
        return None, None
    observed = gt.observed if gt_block is not None and gt_block["points"] == "observed" else None
    keep = observed if observed is not None else np.ones(len(gt.points), bool)
    rooms = None
    if not gt.rooms:
        notes.append("rooms not scored: the ground truth has no rooms (an apartment's has)")
    elif "rooms" not in run.graph:
        notes.append(
            "rooms not scored: graph.json has no rooms (graph.rooms.enabled was off, or an older run)"
        )
    else:
        # every surface point of a room, seen or not, as HOV-SG's ground-truth room is its whole region: the
        # floor under the camera's path or behind furniture is the room's, and its outline may hold it
        lut = gt.instance_rooms
        point_rooms = np.array([lut.get(int(i), -1) for i in gt.instances], dtype=np.int64)
        entered = {k: v.get("first_frame") for k, v in gt.rooms.items()}
        try:
            types = {k: str(v["type"]) for k, v in gt.rooms.items()}
            rooms = rooms_block(run.graph, scored.means, gt.points, point_rooms, entered, types)
        except DataError as e:
            notes.append(f"rooms not scored: {e}")
    gt_inst = np.where(assoc >= 0, gt.instances[np.maximum(assoc, 0)], -1)
    names = {i: gt.class_names[c] for i, c in gt.instance_classes.items()}
    present = {int(i) for i in np.unique(gt.instances[keep]) if i >= 0}
    room_types = {k: str(v["type"]) for k, v in gt.rooms.items()}
    symmetric = gt.symmetric_relations if gt.symmetric_relations is not None else ("next to",)
    try:
        queries = queries_block(
            run.graph, run.labels, gt_inst, names, gt.relations, gt.instance_rooms, room_types, present,
            min_node_iou, symmetric,
        )  # fmt: skip
    except DataError as e:  # a graph.json with too little in it to answer queries (no node geometry)
        notes.append(f"queries not scored: {e}")
        queries = None
    return rooms, queries


def _hovsg_scannet_mismatch(ignore: Iterable[str], class_names: Sequence[str]) -> str | None:
    """Why ``preset:hovsg-scannet`` does not give HOV-SG's ScanNet class set with these (GT) classes, or None.

    HOV-SG scores ScanNet's 20 benchmark classes (plus a background); over the 40 NYU40 classes of a
    ScanNet labels PLY the same ignore list leaves ceiling, otherprop, pillow, ... in the means."""
    if not any(str(i).strip().lower() == "preset:hovsg-scannet" for i in ignore):
        return None
    allowed = {n.lower() for n in SCANNET20_CLASSES.values()} | {"background", "furniture"}
    extra = [n for n in class_names if n.strip().lower() not in allowed]
    if not extra:
        return None
    shown = ", ".join(extra[:5]) + (f", ... ({len(extra)} in all)" if len(extra) > 5 else "")
    return (
        f"preset:hovsg-scannet is HOV-SG's ignore list over ScanNet's 20 classes, but these classes are not "
        f"among them: {shown}; they stay in the means, unlike in HOV-SG's tables (--classes scannet20 "
        "scores the 20 classes and makes the other NYU40 ids void)"
    )


def _views_block(
    rendered: ViewSet,
    gt: GroundTruth,
    label_to_class: dict[int, int],
    out_dir: str | Path | None,
    ignore: Iterable[str] | None,
    named_from_views: bool,
) -> tuple[dict[str, Any], SegmentationMetrics]:
    """2D metrics + pictures of the scored frames; the naming frames are listed when they named labels."""
    res = score_views(
        rendered.views,
        rendered.frames,
        gt,
        label_to_class,
        out_dir,
        None if ignore is None else list(ignore),
        held_out=rendered.held_out,
    )
    block = res.metrics.to_dict()
    block["source"] = rendered.source
    block["dataset_kind"] = rendered.kind
    block["frames"] = res.frames
    block["frame_names"] = [rendered.views[i].name for i in res.frames]
    block["mapping_frames"] = rendered.mapping_frames if named_from_views else None
    held = rendered.held_out
    block["held_out"] = held is not None
    # held-out frames outside the mapped range (none inside it): extrapolation rather than novel views
    block["extrapolated"] = held.extrapolated if held is not None else None
    block["run_frames"] = held.run.to_dict() if held is not None else None
    # an ordinary eval: which of its frames the run mapped, when the run's config.yaml tells
    block["scored_frames_mapped"] = rendered.scored_mapped
    block["pictures"] = [p.name for p in res.pictures]
    return block, res.metrics


def _held_out_notes(rendered: ViewSet, named_from_views: bool) -> list[str]:
    """What the report says about held-out views: which frames the run mapped, extrapolation, the naming."""
    held = rendered.held_out
    assert held is not None
    notes = [f"2D views held out: the run was given {held.run.describe()}, none of the frames scored"]
    if held.extrapolated:
        notes.append(
            "2D held-out views lie outside the run's mapped range (no unmapped frame between its first and "
            "last mapped ones): extrapolated views, not novel views between mapped frames; map with "
            "--set data.stride=2 to hold every other frame out"
        )
    if named_from_views:
        reused = sorted(set(rendered.mapping_frames) & set(rendered.frames))
        if reused:
            notes.append(
                f"the 2D overlap naming reads held-out frames {reused} that are scored (--mapping-frames): "
                "an oracle naming of the very views scored"
            )
        else:
            notes.append(
                f"the 2D overlap naming reads frames {rendered.mapping_frames}, none of the held-out views "
                "scored"
            )
    return notes
