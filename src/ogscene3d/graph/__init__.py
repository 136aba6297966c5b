"""ogscene3d.graph: the progressive 3D scene graph (paper Sec. III-D).

The mapper uses :class:`SceneGraph` only (``observe`` every keyframe, ``update`` when ``is_due``,
``finalize`` at the end); captioners, relation predictors and node-confidence scorers are pluggable
through the :class:`Captioner`, :class:`RelationPredictor` and :class:`NodeConfidence` protocols."""

from __future__ import annotations

from .._lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        ".captioner": [
            "CAPTION_PROMPT",
            "TAG_PROMPT",
            "Captioner",
            "GroundTruthCaptioner",
            "HeuristicCaptioner",
            "OpenAICaptioner",
            "build_captioner",
        ],
        ".confidence": [
            "ClipConfidence",
            "ClipTokenizer",
            "MeanConfidence",
            "NodeConfidence",
            "build_confidence",
        ],
        ".geometry": ["directed_ratios", "proximate_points", "proximity_ratios"],
        ".openai_client": ["ChatClient", "EndpointUnreachable"],
        ".relations": [
            "RELATIONS",
            "GeometricRelations",
            "LLMRelations",
            "Relation",
            "RelationPredictor",
            "build_relations",
            "edge_prompt",
            "normalize_relation",
        ],
        ".scenegraph": ["SceneGraph"],
        ".types": [
            "CaptionRequest",
            "Crop",
            "Description",
            "ObservationSet",
            "SceneContext",
            "SceneEdge",
            "SceneNode",
        ],
    },
)

__all__ = [
    "CAPTION_PROMPT",
    "RELATIONS",
    "TAG_PROMPT",
    "CaptionRequest",
    "Captioner",
    "ChatClient",
    "ClipConfidence",
    "ClipTokenizer",
    "Crop",
    "Description",
    "EndpointUnreachable",
    "GeometricRelations",
    "GroundTruthCaptioner",
    "HeuristicCaptioner",
    "LLMRelations",
    "MeanConfidence",
    "NodeConfidence",
    "ObservationSet",
    "OpenAICaptioner",
    "Relation",
    "RelationPredictor",
    "SceneContext",
    "SceneEdge",
    "SceneGraph",
    "SceneNode",
    "build_captioner",
    "build_confidence",
    "build_relations",
    "directed_ratios",
    "edge_prompt",
    "normalize_relation",
    "proximate_points",
    "proximity_ratios",
]
