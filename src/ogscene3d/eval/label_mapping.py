"""Map open-vocabulary scene labels to ground-truth classes before computing metrics.

Two strategies, each recorded in the outputs because they measure different things:

* **Majority overlap** (:func:`majority_overlap_mapping`): each scene label takes the ground-truth
  id it overlaps most with, counted over corresponding points (e.g. every Gaussian and its nearest
  GT point). With instance ids it is class-agnostic: the label is matched to one *instance*, and the
  class of that instance is reported. It looks at the ground truth, so it is an oracle naming: it
  scores the consistency of the segmentation, not the quality of the names.
* **Text matching** (:func:`text_label_mapping`): each graph node's tag is compared with the class
  names after normalisation (case, ``_``/``-`` and punctuation, leading articles, simple English
  plurals), then through a synonym table, then by head noun ("wooden chair" -> "chair"), and finally,
  only if a :class:`TextEmbedder` is given, by embedding cosine similarity. The paper used an LLM
  (Gemma) for this step; an embedder behind the small protocol is the pluggable equivalent.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

#: Conservative synonym groups (every member is interchangeable with the others). Deliberately
#: small: e.g. "monitor" and "tv" stay apart because Replica and ScanNet have both as classes.
DEFAULT_SYNONYMS: tuple[tuple[str, ...], ...] = (
    ("sofa", "couch", "settee"),
    ("tv screen", "tv", "television", "tv monitor"),
    ("trash can", "trash bin", "garbage can", "garbage bin", "waste bin", "wastebasket", "dustbin", "bin"),
    ("refrigerator", "fridge"),
    ("nightstand", "night stand", "bedside table"),
    ("indoor plant", "plant", "potted plant", "houseplant"),
    ("picture", "painting", "photo", "photograph", "artwork"),
    ("blind", "window blind", "blinds"),
    ("cabinet", "cupboard"),
    ("sink", "washbasin", "wash basin"),
    ("rug", "carpet"),
    ("bookshelf", "bookcase", "book shelf"),
    ("pillow", "throw pillow"),
    ("lamp", "light fixture"),
)

_ARTICLES = {"a", "an", "the", "some"}
_KEEP_S = ("ss", "us", "is", "ous")


def _singular(word: str) -> str:
    if len(word) <= 3 or not word.endswith("s") or word.endswith(_KEEP_S):
        return word
    if word.endswith("ies") and len(word) > 4:
        return word[:-3] + "y"
    if word.endswith("lves"):
        return word[:-3] + "f"
    if word.endswith(("ches", "shes", "xes", "sses", "zes")):
        return word[:-2]
    return word[:-1]


def normalize_label(text: str) -> str:
    """Lower-case, ``_ - /`` and punctuation to spaces, no leading article, singular words.

    >>> normalize_label("The Wall_Cabinets")
    'wall cabinet'
    """
    t = re.sub(r"[_\-/]+", " ", str(text).lower())
    t = re.sub(r"[^\w\s]", " ", t)
    words = t.split()
    while words and words[0] in _ARTICLES:
        words = words[1:]
    return " ".join(_singular(w) for w in words)


@runtime_checkable
class TextEmbedder(Protocol):
    """Anything that turns texts into vectors (e.g. a CLIP/sentence-encoder ONNX wrapper)."""

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        """[len(texts), D] float array; rows need not be normalised."""
        ...


@dataclass(frozen=True)
class TextMatch:
    """How one tag was named: ``class_index`` -1 means no class matched."""

    tag: str
    class_index: int
    method: str  # "exact" | "synonym" | "head-noun" | "embedding" | "none"
    score: float  # 1.0 for rule matches, cosine similarity for "embedding", 0.0 for "none"


def _synonym_index(synonyms: Iterable[Iterable[str]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for g, group in enumerate(synonyms):
        for word in group:
            out.setdefault(normalize_label(word), g)
    return out


def text_label_mapping(
    tags: Mapping[int, str],
    class_names: Sequence[str],
    synonyms: Iterable[Iterable[str]] | None = DEFAULT_SYNONYMS,
    embedder: TextEmbedder | None = None,
    min_similarity: float = 0.5,
) -> dict[int, TextMatch]:
    """Name scene labels by text: ``{scene label: TextMatch}`` for every entry of ``tags``.

    Args:
        tags: scene label -> node tag (``graph.json`` node ``tag``; an empty tag matches nothing).
        class_names: the ground-truth class names.
        synonyms: groups of interchangeable names (None = no synonym step).
        embedder: optional :class:`TextEmbedder` for tags no rule matched.
        min_similarity: cosine similarity an embedding match needs.
    """
    if len(class_names) == 0:
        raise ValueError("class_names is empty")
    norm_classes = [normalize_label(c) for c in class_names]
    exact: dict[str, int] = {}
    for i, n in enumerate(norm_classes):
        exact.setdefault(n, i)
    syn = _synonym_index(synonyms or ())
    by_group: dict[int, int] = {}
    for i, n in enumerate(norm_classes):
        if n in syn:
            by_group.setdefault(syn[n], i)

    def rule_match(name: str) -> tuple[int, str] | None:
        if name in exact:
            return exact[name], "exact"
        if name in syn and syn[name] in by_group:
            return by_group[syn[name]], "synonym"
        return None

    out: dict[int, TextMatch] = {}
    pending: list[int] = []
    for label, tag in tags.items():
        name = normalize_label(tag or "")
        hit = rule_match(name) if name else None
        if hit is None and " " in name:
            head = rule_match(name.rsplit(" ", 1)[1])
            hit = (head[0], "head-noun") if head else None
        if hit is not None:
            out[int(label)] = TextMatch(str(tag), hit[0], hit[1], 1.0)
        else:
            out[int(label)] = TextMatch(str(tag or ""), -1, "none", 0.0)
            if name:
                pending.append(int(label))
    if embedder is not None and pending:
        sims = _cosine(embedder.embed([str(tags[p]) for p in pending]), embedder.embed(list(class_names)))
        best = np.argmax(sims, axis=1)
        for row, label in enumerate(pending):
            s = float(sims[row, best[row]])
            if s >= min_similarity:
                out[label] = TextMatch(str(tags[label]), int(best[row]), "embedding", s)
    return out


def _cosine(a: Any, b: Any) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ValueError(f"embedder returned incompatible shapes {a.shape} and {b.shape}")
    a = a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-12)
    b = b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-12)
    return a @ b.T


def majority_overlap_mapping(
    pred_labels: Any,
    gt_ids: Any,
    id_to_class: Mapping[int, int] | None = None,
    min_points: int = 1,
    weights: Any | None = None,
) -> dict[int, int]:
    """Name each scene label by the ground-truth id it overlaps most with.

    Args:
        pred_labels: [N] scene label per point, -1 = unlabeled (skipped).
        gt_ids: [N] ground-truth id of the *same* points (class index, or instance id for the
            class-agnostic variant), < 0 = void (skipped).
        id_to_class: instance id -> class index; when given the result holds class indices
            (instance ids missing from it map to -1).
        min_points: overlaps smaller than this leave the label unmapped.
        weights: [N] non-negative count of each entry (e.g. pixel counts of (label, class) pairs); None = 1.

    Returns:
        {scene label: class index (or GT id without ``id_to_class``)}; labels with no valid overlap
        are absent. Ties go to the smallest GT id.
    """
    p = np.asarray(pred_labels)
    g = np.asarray(gt_ids)
    if p.shape != g.shape or p.ndim != 1:
        raise ValueError(f"pred_labels {p.shape} and gt_ids {g.shape} must be equal 1-D arrays")
    if not (np.issubdtype(p.dtype, np.integer) and np.issubdtype(g.dtype, np.integer)):
        raise ValueError("pred_labels and gt_ids must be integer arrays")
    w = None
    if weights is not None:
        w = np.asarray(weights)
        if w.shape != p.shape or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError(f"weights {w.shape} must be finite, non-negative and shaped like pred_labels")
    keep = (p >= 0) & (g >= 0)
    if not keep.any():
        return {}
    pairs = np.stack([p[keep].astype(np.int64), g[keep].astype(np.int64)], axis=1)
    if w is None:
        uniq, counts = np.unique(pairs, axis=0, return_counts=True)
    else:
        uniq, inverse = np.unique(pairs, axis=0, return_inverse=True)
        counts = np.bincount(inverse.reshape(-1), weights=w[keep], minlength=uniq.shape[0])
    # Sort by label, then count descending, then GT id ascending: the first row per label wins.
    order = np.lexsort((uniq[:, 1], -counts, uniq[:, 0]))
    uniq, counts = uniq[order], counts[order]
    first = np.ones(uniq.shape[0], dtype=bool)
    first[1:] = uniq[1:, 0] != uniq[:-1, 0]
    out: dict[int, int] = {}
    for (label, gid), n in zip(uniq[first], counts[first]):
        if n < min_points:
            continue
        out[int(label)] = int(gid) if id_to_class is None else int(id_to_class.get(int(gid), -1))
    return out
