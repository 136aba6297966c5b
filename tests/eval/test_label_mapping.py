"""Scene label -> GT class mapping: text rules, optional embedder, majority overlap."""

import numpy as np
import pytest

from ogscene3d.eval.label_mapping import (
    TextEmbedder,
    majority_overlap_mapping,
    normalize_label,
    text_label_mapping,
)

CLASSES = ["chair", "sofa", "wall cabinet", "shelf", "tv-screen", "box", "glass"]


@pytest.mark.parametrize(
    "text,norm",
    [
        ("The Wall_Cabinets", "wall cabinet"),
        ("Shelves", "shelf"),
        ("boxes", "box"),
        ("glass", "glass"),
        ("TV-Screen", "tv screen"),
        ("an  Office   Chair!", "office chair"),
        ("batteries", "battery"),
    ],
)
def test_normalize_label(text, norm):
    assert normalize_label(text) == norm


def test_text_mapping_rules():
    tags = {1: "Chairs", 2: "couch", 3: "wooden chair", 4: "spaceship", 5: "", 6: "television", 7: "Glasses"}
    m = text_label_mapping(tags, CLASSES)
    assert (m[1].class_index, m[1].method) == (0, "exact")
    assert (m[2].class_index, m[2].method) == (1, "synonym")
    assert (m[3].class_index, m[3].method) == (0, "head-noun")
    assert (m[4].class_index, m[4].method) == (-1, "none")
    assert m[5].class_index == -1
    assert (m[6].class_index, m[6].method) == (4, "synonym")
    assert m[7].class_index == 6
    assert text_label_mapping({2: "couch"}, CLASSES, synonyms=None)[2].class_index == -1


class _BagOfLettersEmbedder:
    """A deterministic stand-in for a sentence encoder: letter histograms."""

    def embed(self, texts):
        out = np.zeros((len(texts), 26))
        for i, t in enumerate(texts):
            for ch in t.lower():
                if "a" <= ch <= "z":
                    out[i, ord(ch) - 97] += 1
        return out


def test_text_mapping_embedding_fallback_only_for_unmatched():
    emb = _BagOfLettersEmbedder()
    assert isinstance(emb, TextEmbedder)
    m = text_label_mapping({1: "chiar", 2: "sofa", 3: "qqqq"}, CLASSES, embedder=emb, min_similarity=0.9)
    assert (m[1].class_index, m[1].method) == (0, "embedding") and m[1].score > 0.9
    assert m[2].method == "synonym" or m[2].method == "exact"
    assert m[3].class_index == -1  # below the similarity threshold


def test_majority_overlap_class_and_instance():
    labels = np.array([5, 5, 5, 7, 7, -1, 9])
    gt_ids = np.array([1, 1, 2, 2, 2, 1, -1])
    assert majority_overlap_mapping(labels, gt_ids) == {5: 1, 7: 2}
    # class-agnostic on instances: two chair instances (1, 2) -> both labels are "chair" (class 0)
    assert majority_overlap_mapping(labels, gt_ids, id_to_class={1: 0, 2: 0}) == {5: 0, 7: 0}
    # ties go to the smallest GT id; min_points drops thin overlaps
    assert majority_overlap_mapping(np.array([3, 3]), np.array([4, 2])) == {3: 2}
    assert majority_overlap_mapping(labels, gt_ids, min_points=3) == {}
    with pytest.raises(ValueError, match="equal 1-D"):
        majority_overlap_mapping(labels, gt_ids[:3])
