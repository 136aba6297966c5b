"""ogscene3d.graph: the progressive 3D scene graph (paper Sec. III-D), with its rooms and storeys
(:mod:`.rooms`) and queries over objects, relations and rooms (:mod:`.query`).

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
        ".query": ["QueryAnswer", "QueryHit", "parse_query"],
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
        ".rooms": ["Floor", "RoomMap", "RoomNode", "assign_rooms", "segment_rooms"],
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
    "Floor",
    "GeometricRelations",
    "GroundTruthCaptioner",
    "HeuristicCaptioner",
    "LLMRelations",
    "MeanConfidence",
    "NodeConfidence",
    "ObservationSet",
    "OpenAICaptioner",
    "QueryAnswer",
    "QueryHit",
    "Relation",
    "RelationPredictor",
    "RoomMap",
    "RoomNode",
    "SceneContext",
    "SceneEdge",
    "SceneGraph",
    "SceneNode",
    "assign_rooms",
    "build_captioner",
    "build_confidence",
    "build_relations",
    "directed_ratios",
    "edge_prompt",
    "normalize_relation",
    "parse_query",
    "proximate_points",
    "proximity_ratios",
    "segment_rooms",
]
