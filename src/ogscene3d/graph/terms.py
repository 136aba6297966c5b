"""Words for objects: the offline synonyms of queries and room typing, and whole-word matching of a term
against node tags and captions."""

from __future__ import annotations

import re
from collections.abc import Iterable

#: Offline query synonyms: a query matching any word of a group also matches the others.
SYNONYM_GROUPS: tuple[frozenset[str], ...] = tuple(
    frozenset(g)
    for g in (
        {"sofa", "couch", "settee", "loveseat"},
        {"tv", "television", "monitor", "screen", "display"},
        {"cup", "mug"},
        {"trash can", "trash bin", "garbage can", "bin", "wastebasket", "waste bin", "dustbin"},
        {"rug", "carpet", "mat"},
        {"picture", "painting", "photo", "photograph", "poster", "artwork", "picture frame"},
        {"cabinet", "cupboard", "dresser", "sideboard", "wardrobe"},
        {"shelf", "shelves", "bookshelf", "bookcase", "shelving"},
        {"table", "desk"},
        {"lamp", "light", "light fixture"},
        {"chair", "seat", "stool", "armchair"},
        {"plant", "potted plant", "houseplant", "flower pot"},
        {"pillow", "cushion"},
        {"blinds", "curtain", "drape", "window shade"},
        {"laptop", "computer", "notebook computer"},
        {"phone", "telephone", "cellphone", "mobile phone"},
        {"refrigerator", "fridge"},
        {"sink", "basin", "washbasin"},
        {"floor", "ground", "flooring"},
        {"book", "books"},
        {"stove", "cooker", "hob"},
        {"bathtub", "bath", "tub"},
        {"nightstand", "bedside table", "night table"},
        {"counter", "countertop", "worktop"},
    )
)


def normalize_text(text: str) -> str:
    """Lower case, single spaces: the form terms are compared in."""
    return " ".join(str(text).lower().split())


def expand(term: str) -> dict[str, float]:
    """``{word: weight}``: the term itself (1.0) and its synonyms (0.9)."""
    q = normalize_text(term)
    out = {q: 1.0}
    for group in SYNONYM_GROUPS:
        if q in group:
            for w in group:
                out.setdefault(w, 0.9)
    return out


def word_pattern(term: str) -> re.Pattern:
    """Whole-word, plural-tolerant match of ``term``."""
    return re.compile(r"\b" + re.escape(term) + r"(?:s|es)?\b")


def text_score(term: str, tag: str, caption: str) -> float:
    """How well ``term`` names a node: 1.0 for its exact tag, 0.9 for a whole word of the tag, 0.6 for a
    whole word of the caption (pass "" for an offline caption: it says nothing the tag does not), 0
    otherwise; a synonym counts 0.9 times as the whole tag only (a caption's "light gray" or a "light
    switch" is no lamp)."""
    q, t, c = normalize_text(term), normalize_text(tag), normalize_text(caption)
    pat = word_pattern(q)
    best = 1.0 if t == q else 0.9 if pat.search(t) else 0.6 if pat.search(c) else 0.0
    for word, w in expand(term).items():
        if word != q and t in (word, word + "s", word + "es"):
            best = max(best, w)
    return best


def known_terms(tags: Iterable[str]) -> set[str]:
    """The object terms a query may name: the given tags and every synonym word."""
    out = {normalize_text(t) for t in tags if normalize_text(t)}
    for g in SYNONYM_GROUPS:
        out |= g
    return out
