"""ogscene3d.eval: the paper's metrics under the community protocols, label naming, pictures.

* :mod:`.metrics` — confusion matrix, mIoU / F-mIoU / mAcc / per-class IoU (conventions documented there).
* :mod:`.protocols` — HOV-SG and ConceptGraphs 3D protocols, 2D metrics of rendered dataset frames.
* :mod:`.label_mapping` — scene labels -> GT classes by majority overlap or by text.
* :mod:`.graph_metrics` — relation recall with nodes matched by 3D overlap.
* :mod:`.trajectory` — ATE RMSE after Umeyama alignment.
* :mod:`.plots` — stable label colours, side-by-side panels, per-class IoU bar chart (OpenCV).
* :mod:`.views` — render a run at dataset poses: 2D metrics and RGB | labels | GT | confidence PNGs.
* :mod:`.run_eval` — :func:`evaluate_run`, the engine of ``ogscene3d eval``."""

from __future__ import annotations

from .._lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        ".graph_metrics": ["RelationRecall", "match_nodes_by_overlap", "node_overlap_iou", "relation_recall"],
        ".label_mapping": [
            "DEFAULT_SYNONYMS",
            "TextEmbedder",
            "TextMatch",
            "majority_overlap_mapping",
            "normalize_label",
            "text_label_mapping",
        ],
        ".metrics": [
            "SegmentationMetrics",
            "confusion_matrix",
            "format_metrics_table",
            "segmentation_metrics",
            "void_predictions",
        ],
        ".plots": [
            "colorize_confidence",
            "colorize_labels",
            "iou_bar_chart",
            "label_colors",
            "side_by_side",
            "write_iou_chart",
            "write_png",
        ],
        ".protocols": [
            "CONCEPTGRAPHS_DEFAULT_IGNORE",
            "CONCEPTGRAPHS_VOXEL_SIZE",
            "HOVSG_DEFAULT_IGNORE",
            "PROTOCOLS",
            "conceptgraphs_protocol",
            "evaluate_semantic_3d",
            "hovsg_protocol",
            "label_lookup",
            "majority_vote",
            "nearest_neighbors",
            "novel_view_metrics",
            "rendered_view_metrics",
            "voxel_resample",
        ],
        ".ground_truth": ["GroundTruth"],
        ".readers": [
            "RunData",
            "find_ground_truth",
            "load_ground_truth",
            "read_graph_json",
            "read_run",
        ],
        ".run_eval": ["EvalResult", "build_label_mapping", "evaluate_run"],
        ".trajectory": ["TrajectoryError", "ate", "ate_rmse", "read_trajectory", "umeyama_alignment"],
        ".views": ["ViewsResult", "evaluate_views"],
        ".held_out": ["pick_frames"],
    },
)

__all__ = [
    "CONCEPTGRAPHS_DEFAULT_IGNORE",
    "CONCEPTGRAPHS_VOXEL_SIZE",
    "DEFAULT_SYNONYMS",
    "HOVSG_DEFAULT_IGNORE",
    "PROTOCOLS",
    "EvalResult",
    "GroundTruth",
    "RelationRecall",
    "RunData",
    "SegmentationMetrics",
    "TextEmbedder",
    "TextMatch",
    "TrajectoryError",
    "ViewsResult",
    "ate",
    "ate_rmse",
    "build_label_mapping",
    "colorize_confidence",
    "colorize_labels",
    "conceptgraphs_protocol",
    "confusion_matrix",
    "evaluate_run",
    "evaluate_semantic_3d",
    "evaluate_views",
    "find_ground_truth",
    "format_metrics_table",
    "hovsg_protocol",
    "iou_bar_chart",
    "label_colors",
    "label_lookup",
    "load_ground_truth",
    "majority_overlap_mapping",
    "majority_vote",
    "match_nodes_by_overlap",
    "nearest_neighbors",
    "node_overlap_iou",
    "normalize_label",
    "novel_view_metrics",
    "pick_frames",
    "read_graph_json",
    "read_run",
    "read_trajectory",
    "relation_recall",
    "rendered_view_metrics",
    "segmentation_metrics",
    "side_by_side",
    "text_label_mapping",
    "umeyama_alignment",
    "void_predictions",
    "voxel_resample",
    "write_iou_chart",
    "write_png",
]
