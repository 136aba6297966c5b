"""Replica's own semantic ground truth, built into labelled points the way HOV-SG builds it.

The original Replica dataset (not NICE-SLAM's rendered sequences) annotates each scene in
``<scene>/habitat/``:

* ``mesh_semantic.ply``: vertices ``x y z`` (with normals and colours) and faces with a
  ``vertex_indices`` list (quads in Replica) and a per-face integer ``object_id`` (habitat-sim reads it
  as 16 bit; any integer type is accepted here);
* ``info_semantic.json``: ``{"classes": [{"id", "name"}, ...], "objects": [{"id", "class_id", ...}, ...]}``.

HOV-SG (``application/eval/evaluate_sem_seg.py``, ``hovsg/utils/eval_utils.py``) scores Replica against
a cloud that holds, for every face, each of its vertices with the class of the face's object: a vertex
shared by k faces appears k times (and may carry different classes there), so the counts of its metrics
weigh a vertex by the number of faces around it. An object id absent from ``objects`` has class 0, and its
class table is ``classes`` plus 0 = "background" (replacing any name Replica gives id 0). The same cloud is
built here, so ``--ignore preset:hovsg-replica`` reproduces its ignore list (-1, 0 and every class whose
name contains wall/floor/ceiling/door/window/background). One difference: an object whose ``class_id`` is
not in ``classes`` is void here (with a warning), where HOV-SG would score it as a class without a name.

The mesh is in Replica's own frame, the one NICE-SLAM's sequences (``room0`` ...) were rendered in, so a
run of such a sequence with its poses lies on it without any transform.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from ..datasets.replica_semantic import read_info_semantic
from ..errors import DataError
from .ground_truth import GroundTruth, reindex_class_ids

log = logging.getLogger(__name__)

SEMANTIC_PLY = "mesh_semantic.ply"
SEMANTIC_INFO = "info_semantic.json"
BACKGROUND_ID = 0  # HOV-SG's class of faces whose object is not in info_semantic.json

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_INDEX_NAMES = ("vertex_indices", "vertex_index")


def replica_semantic_files(path: str | Path) -> tuple[Path, Path] | None:
    """``(mesh_semantic.ply, info_semantic.json)`` when ``path`` is a Replica scene folder, its ``habitat/``
    folder or the ``mesh_semantic.ply`` file itself (the json is the one beside the PLY; it need not
    exist yet); None when it is none of these."""
    p = Path(path)
    if p.is_file():
        ply = p if p.name == SEMANTIC_PLY else None
    elif (p / "habitat" / SEMANTIC_PLY).is_file():
        ply = p / "habitat" / SEMANTIC_PLY
    elif (p / SEMANTIC_PLY).is_file():
        ply = p / SEMANTIC_PLY
    else:
        ply = None
    return None if ply is None else (ply, ply.parent / SEMANTIC_INFO)


@dataclass
class FaceMesh:
    """A PLY face mesh: vertex positions and, per face, its vertex indices and object id."""

    vertices: np.ndarray  # [V, 3] float64
    face_sizes: np.ndarray  # [F] int64, vertices per face
    indices: np.ndarray  # [sum(face_sizes)] vertex indices, face after face
    object_ids: np.ndarray  # [F] int64
    fast_path: bool  # read as one fixed-size block (every face the same size, binary PLY)


# ----------------------------------------------------------------------------------------- PLY reading


@dataclass
class _Prop:
    name: str
    dtype: str | None  # scalar type (numpy code), None for a list
    list_types: tuple[str, str] | None = None  # (count type, item type) of a list


@dataclass
class _Element:
    name: str
    count: int
    props: list[_Prop]


# Real PLY headers are a few hundred bytes; the bound only stops a file that starts "ply" but never ends
# its header (or is no PLY at all) from being read to the end, which for Replica's meshes is gigabytes.
MAX_HEADER_BYTES = 1 << 24


def _read_header(fh: BinaryIO, path: Path) -> bytes:
    """The header of an open PLY file, ``ply`` through the ``end_header`` line, read line by line so that a
    header of any length up to :data:`MAX_HEADER_BYTES` is whole and the body is never read."""
    buf = bytearray()
    while True:
        # readline's limit: a binary file with no newline for gigabytes is cut off at the bound
        line = fh.readline(MAX_HEADER_BYTES + 1 - len(buf))
        if not buf and line.rstrip(b"\r\n") != b"ply":
            raise DataError(f"{path}: not a PLY file (does not start with a 'ply' line)")
        if not line:
            raise DataError(
                f"{path}: truncated PLY header: the file ends after {len(buf)} bytes, "
                "before an 'end_header' line"
            )
        buf += line
        if len(buf) > MAX_HEADER_BYTES:
            raise DataError(
                f"{path}: no 'end_header' line in the first {MAX_HEADER_BYTES} bytes: not a PLY file, "
                "or its header is damaged"
            )
        if line.rstrip(b"\r\n") == b"end_header":
            return bytes(buf)


def _parse_header(data: bytes, path: Path) -> tuple[str, list[_Element], int]:
    """(format, elements, byte offset of the body) of a PLY file whose whole header is ``data``
    (as :func:`_read_header` returns it)."""
    fmt = ""
    elements: list[_Element] = []
    # Lines end at "\n" only (the body offset counts on it): the lines between "ply" and "end_header".
    for raw in data.decode("ascii", "replace").rstrip("\r\n").split("\n")[1:-1]:
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                elements.append(_Element(words[1], int(words[2]), []))
            elif words[0] == "property" and words[1] == "list":
                elements[-1].props.append(_Prop(words[4], None, (_PLY_TYPES[words[2]], _PLY_TYPES[words[3]])))
            elif words[0] == "property":
                elements[-1].props.append(_Prop(words[2], _PLY_TYPES[words[1]]))
        except (IndexError, KeyError, ValueError):
            raise DataError(f"{path}: malformed PLY header line {raw.strip()!r}") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise DataError(f"{path}: unknown PLY format {fmt!r}")
    return fmt, elements, len(data)


def _fixed_dtype(el: _Element, order: str, list_len: int | None = None) -> np.dtype | None:
    """The record dtype of ``el``; its list properties take ``list_len`` items (None: no lists allowed)."""
    fields: list[Any] = []
    for p in el.props:
        if p.list_types is None:
            fields.append((p.name, order + str(p.dtype)))
        elif list_len is None:
            return None
        else:
            fields.append((p.name + "\0count", order + p.list_types[0]))
            fields.append((p.name, order + p.list_types[1], (list_len,)))
    return np.dtype(fields)


def _read_fixed(path: Path, fmt: str, elements: list[_Element], body: int) -> FaceMesh | None:
    """Binary PLY whose faces all have the same vertex count: the vertex and face blocks read as numpy
    records (memory-mapped), no per-face Python. None when the file is not of that kind."""
    if fmt == "ascii":
        return None
    order = "<" if fmt == "binary_little_endian" else ">"
    offset = body
    vertex = face = None
    for el in elements:
        if el.name == "face":
            face = (el, offset)
            break
        dt = _fixed_dtype(el, order)
        if dt is None:
            return None  # a list property before the faces: element sizes unknown
        if el.name == "vertex":
            vertex = (el, dt, offset)
        offset += el.count * dt.itemsize
    if vertex is None or face is None:
        return None
    fel, foff = face
    lists = [p for p in fel.props if p.list_types is not None]
    if len(lists) != 1 or lists[0].name not in _INDEX_NAMES or fel.count == 0:
        return None
    # The first face's list count sits after the fixed properties that precede the list.
    head = _fixed_dtype(_Element("", 0, fel.props[: fel.props.index(lists[0])]), order)
    assert head is not None and lists[0].list_types is not None
    count_dt = np.dtype(order + lists[0].list_types[0])
    size = path.stat().st_size
    if foff + head.itemsize + count_dt.itemsize > size:
        return None
    n = int(np.fromfile(path, count_dt, 1, offset=foff + head.itemsize)[0])
    fdt = _fixed_dtype(fel, order, n)
    assert fdt is not None
    if n == 0 or foff + fel.count * fdt.itemsize > size:
        return None
    faces = np.memmap(path, fdt, "r", foff, (fel.count,))
    if not np.all(faces[lists[0].name + "\0count"] == n):
        return None  # mixed face sizes: the general reader
    vel, vdt, voff = vertex
    verts = np.memmap(path, vdt, "r", voff, (vel.count,))
    _require(path, vdt.names or (), ("x", "y", "z"), "vertex")
    _require(path, fdt.names or (), ("object_id",), "face")
    return FaceMesh(
        vertices=np.stack([verts["x"], verts["y"], verts["z"]], axis=1).astype(np.float64),
        face_sizes=np.full(fel.count, n, np.int64),
        indices=np.asarray(faces[lists[0].name]).reshape(-1),
        object_ids=_integer_ids(np.asarray(faces["object_id"]), path),
        fast_path=True,
    )


def _read_general(path: Path) -> FaceMesh:
    """Any PLY plyfile reads (ASCII, faces of mixed sizes): lists come back one array per face."""
    from plyfile import PlyData

    try:
        ply = PlyData.read(str(path))
    except Exception as e:  # plyfile raises assorted errors on truncated/corrupt files
        raise DataError(f"{path}: not a readable PLY file ({e})") from None
    names = [el.name for el in ply.elements]
    if "vertex" not in names or "face" not in names:
        raise DataError(f"{path}: a semantic mesh needs 'vertex' and 'face' elements (has {names})")
    v, f = ply["vertex"].data, ply["face"].data
    _require(path, v.dtype.names or (), ("x", "y", "z"), "vertex")
    _require(path, f.dtype.names or (), ("object_id",), "face")
    key = next((k for k in _INDEX_NAMES if k in (f.dtype.names or ())), None)
    if key is None:
        raise DataError(f"{path}: face property 'vertex_indices' missing (have {list(f.dtype.names or ())})")
    lists = f[key]
    sizes = np.fromiter((len(x) for x in lists), np.int64, len(lists))
    idx = np.concatenate([np.asarray(x) for x in lists]) if len(lists) else np.zeros(0, np.int64)
    return FaceMesh(
        vertices=np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64),
        face_sizes=sizes,
        indices=idx,
        object_ids=_integer_ids(np.asarray(f["object_id"]), path),
        fast_path=False,
    )


def _require(path: Path, have: tuple[str, ...], need: tuple[str, ...], element: str) -> None:
    missing = [n for n in need if n not in have]
    if missing:
        what = "per-face object ids" if element == "face" else "vertex positions"
        raise DataError(
            f"{path}: {element} property {', '.join(repr(m) for m in missing)} missing (have {list(have)}): "
            f"not a Replica semantic mesh ({what})"
        )


def _integer_ids(a: np.ndarray, path: Path) -> np.ndarray:
    if not np.issubdtype(a.dtype, np.integer):
        raise DataError(f"{path}: face property 'object_id' must be an integer type (is {a.dtype})")
    return a.astype(np.int64)


def read_face_mesh(path: str | Path) -> FaceMesh:
    """Vertices, faces and per-face ``object_id`` of a PLY mesh (binary or ASCII).

    A binary file whose faces all have the same vertex count (Replica's quads) is read as two
    memory-mapped numpy record blocks; anything else goes through plyfile, one array per face.
    """
    path = Path(path)
    try:
        with path.open("rb") as fh:
            head = _read_header(fh, path)
    except FileNotFoundError:
        raise DataError(f"{path}: file not found") from None
    fmt, elements, body = _parse_header(head, path)
    mesh = _read_fixed(path, fmt, elements, body)
    if mesh is None:
        mesh = _read_general(path)
    nv = len(mesh.vertices)
    if not np.all(np.isfinite(mesh.vertices)):
        raise DataError(
            f"{path}: {int((~np.isfinite(mesh.vertices)).any(axis=1).sum())} vertices are NaN/inf"
        )
    if mesh.indices.size and (int(mesh.indices.min()) < 0 or int(mesh.indices.max()) >= nv):
        raise DataError(f"{path}: face vertex indices outside [0, {nv}) (the file has {nv} vertices)")
    return mesh


# ---------------------------------------------------------------------------------- info_semantic.json


# ------------------------------------------------------------------------------------------ ground truth


def _first(ids: np.ndarray, shown: int = 8) -> str:
    more = f", ... ({ids.size} in all)" if ids.size > shown else ""
    return ", ".join(str(int(i)) for i in ids[:shown]) + more


def load_replica_ground_truth(ply: str | Path, info: str | Path) -> GroundTruth:
    """A :class:`~ogscene3d.eval.ground_truth.GroundTruth` from Replica's ``mesh_semantic.ply`` and
    ``info_semantic.json``, built as HOV-SG builds it (module docstring): one point per face corner,
    ``instances`` = object ids, ``class_ids`` = Replica's class ids (plus 0, background)."""

    ply, info = Path(ply), Path(info)
    if not info.is_file():
        raise DataError(
            f"{info}: missing; Replica's semantic mesh {ply.name} needs the info_semantic.json beside it "
            "(its object -> class table)"
        )
    class_table, object_class = read_info_semantic(info)
    mesh = read_face_mesh(ply)
    if class_table.get(BACKGROUND_ID, "background") != "background":
        log.debug(
            "%s: class %d (%r) is named 'background', as HOV-SG names it",
            info,
            BACKGROUND_ID,
            class_table[BACKGROUND_ID],
        )
    class_table[BACKGROUND_ID] = "background"

    # Per object id on the mesh: its Replica class id (objects missing from the json: background).
    oid = mesh.object_ids
    uniq, inverse = np.unique(oid, return_inverse=True)
    known = np.array([int(o) in object_class for o in uniq], dtype=bool)
    raw = np.array([object_class.get(int(o), BACKGROUND_ID) for o in uniq], dtype=np.int64)
    if not known.all():
        log.info(
            "%s: %d faces (object ids %s) have no entry in %s's objects: background, as in HOV-SG",
            ply,
            int(np.count_nonzero(~known[inverse])),
            _first(uniq[~known]),
            info.name,
        )
    uniq_cls, class_names = reindex_class_ids(raw, class_table)
    if (uniq_cls < 0).any():
        bad = uniq_cls[inverse] < 0
        log.warning(
            "%s: %d faces belong to objects whose class_id (%s) is not in its 'classes'; treated as void",
            info,
            int(bad.sum()),
            _first(np.unique(raw[uniq_cls < 0])),
        )
    face_cls = uniq_cls[inverse]

    # One point per face corner (HOV-SG's cloud): the repetition is what weighs a vertex by its faces.
    points = mesh.vertices[mesh.indices]
    classes = np.repeat(face_cls, mesh.face_sizes)
    instances = np.repeat(oid, mesh.face_sizes)
    instance_classes = {int(o): int(c) for o, c in zip(uniq, uniq_cls) if c >= 0}
    return GroundTruth(
        points=points,
        classes=classes,
        class_names=class_names,
        instances=instances,
        instance_classes=instance_classes,
        relations=[],
        class_ids=sorted(class_table),
        source=str(ply),
    )
