"""The models folder's manifest (``models.json``): what ``ogscene3d models export`` wrote, read by
``ogscene3d run --models DIR``.

Layout (paths relative to the folder)::

    {"format": "ogscene3d.models", "version": 1,
     "sam":      {"kind": "sam-vit-b", "checkpoint": ..., "encoder": "sam_encoder.onnx",
                  "decoder": "sam_decoder.onnx", "input_size": 1024},
     "detector": {"kind": "yolo-world", "checkpoint": ..., "model": "detector.onnx",
                  "classes": ["chair", ...], "input_size": 640},
     "clip":     {"kind": "open-clip", "checkpoint": ..., "image": "clip_image.onnx",
                  "text": "clip_text.onnx", "vocab": "bpe_simple_vocab_16e6.txt.gz", "merges": null,
                  "image_size": 224, "context_length": 77}}

Each export adds or replaces its own entry, so one folder can hold a SAM, a detector and a CLIP export.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..atomic import atomic_write_text
from ..errors import ConfigError

MANIFEST = "models.json"
FORMAT = "ogscene3d.models"
VERSION = 1
SECTIONS = ("sam", "detector", "clip")


def read_manifest(directory: str | Path) -> dict[str, Any]:
    """The manifest of ``directory``; ConfigError naming the file when it is missing or malformed."""
    path = Path(directory) / MANIFEST
    if not path.is_file():
        raise ConfigError(
            f"{path}: no models manifest; make one with `ogscene3d models export KIND --checkpoint PATH "
            f"--out {directory}`"
        )
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: not a valid models manifest ({e})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ConfigError(f'{path}: not an ogscene3d models manifest (no "format": "{FORMAT}")')
    if data.get("version") != VERSION:
        raise ConfigError(f"{path}: manifest version {data.get('version')!r}; this ogscene3d reads {VERSION}")
    return data


def update_manifest(directory: str | Path, section: str, entry: dict[str, Any]) -> Path:
    """Adds or replaces ``section`` (sam | detector | clip) of the folder's manifest; returns its path."""
    if section not in SECTIONS:
        raise ValueError(f"manifest section must be one of {SECTIONS}, got {section!r}")
    d = Path(directory)
    path = d / MANIFEST
    data = read_manifest(d) if path.is_file() else {"format": FORMAT, "version": VERSION}
    data[section] = entry
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")
    return path


def _file(d: Path, section: str, entry: dict, key: str) -> str:
    name = entry.get(key)
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{d / MANIFEST}: {section}.{key} is missing")
    p = d / name
    if not p.is_file():
        raise ConfigError(f"{d / MANIFEST}: {section}.{key} names {p}, which does not exist")
    return str(p.resolve())


def manifest_overrides(directory: str | Path) -> list[str]:
    """The config overrides (``key=value``, values in YAML/JSON syntax) that use the folder's models:

    * SAM: ``segmentation.backend=sam`` (``sam+detector`` with a detector too), its two ONNX files and
      input size;
    * detector: its ONNX file, classes and input size;
    * CLIP: ``graph.confidence.kind=clip`` with its encoders and tokenizer files, and
      ``graph.query_embedding=clip`` (queries through the same text encoder).
    """
    d = Path(directory)
    data = read_manifest(d)
    out: list[str] = []

    def put(key: str, value: Any) -> None:
        out.append(f"{key}={json.dumps(value)}")

    sam, det, clip = (data.get(s) for s in SECTIONS)
    if not (sam or det or clip):
        raise ConfigError(f"{d / MANIFEST}: the manifest lists no model")
    if sam:
        put("segmentation.backend", "sam+detector" if det else "sam")
        put("segmentation.sam_encoder", _file(d, "sam", sam, "encoder"))
        put("segmentation.sam_decoder", _file(d, "sam", sam, "decoder"))
        if sam.get("input_size"):
            put("segmentation.sam_input_size", int(sam["input_size"]))
    if det:
        put("segmentation.detector", _file(d, "detector", det, "model"))
        classes = det.get("classes")
        if not isinstance(classes, list) or not classes or not all(isinstance(c, str) for c in classes):
            raise ConfigError(f"{d / MANIFEST}: detector.classes must be a non-empty list of names")
        put("segmentation.detector_classes", classes)
        if det.get("input_size"):
            put("segmentation.detector_input_size", int(det["input_size"]))
    if clip:
        put("graph.confidence.kind", "clip")
        put("graph.confidence.clip_image", _file(d, "clip", clip, "image"))
        put("graph.confidence.clip_text", _file(d, "clip", clip, "text"))
        put("graph.confidence.clip_vocab", _file(d, "clip", clip, "vocab"))
        if clip.get("merges"):
            put("graph.confidence.clip_merges", _file(d, "clip", clip, "merges"))
        if clip.get("image_size"):
            put("graph.confidence.clip_image_size", int(clip["image_size"]))
        put("graph.query_embedding", "clip")
    return out
