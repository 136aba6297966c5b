"""Replica's semantic tables: ``info_semantic.json`` (class id -> name, object id -> class id), read by the
Semantic-NeRF layout (the names of its class maps) and by the evaluation's Replica ground truth."""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import DataError


def class_entries(entries: list, path: Path) -> dict[int, str]:
    """Class id -> name from ``[{"id", "name"}, ...]``: Replica's ``info_semantic.json`` ``classes`` (also
    the names of Semantic-NeRF's class maps), COCO-style category lists."""
    out: dict[int, str] = {}
    for n in entries:
        try:
            out[int(n["id"])] = str(n["name"])
        except (KeyError, TypeError, ValueError):
            raise DataError(f"{path}: class entry {n!r:.80} needs an integer 'id' and a 'name'") from None
    return out


def read_info_semantic(path: str | Path) -> tuple[dict[int, str], dict[int, int]]:
    """(class id -> name, object id -> class id) from Replica's ``info_semantic.json``."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(
            f"{path}: missing; Replica's semantic mesh needs the info_semantic.json beside it "
            "(its object -> class table)"
        ) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(f"{path}: invalid JSON ({e})") from None
    if not isinstance(data, dict) or not isinstance(data.get("classes"), list):
        raise DataError(f"{path}: expected an object with a 'classes' list of {{'id', 'name'}}")
    if not isinstance(data.get("objects"), list):
        raise DataError(f"{path}: expected an 'objects' list of {{'id', 'class_id'}}")
    classes = class_entries(data["classes"], path)
    objects: dict[int, int] = {}
    for o in data["objects"]:
        try:
            objects[int(o["id"])] = int(o["class_id"])
        except (KeyError, TypeError, ValueError):
            raise DataError(f"{path}: object entry {o!r:.80} needs integer 'id' and 'class_id'") from None
    return classes, objects
