"""Readers for what ``ogscene3d eval`` compares: a run directory and a ground truth.

Run directory (docs/formats.md): ``gaussians.ply`` (vertex fields ``x y z ... opacity ... label
confidence``) and, optionally, ``graph.json``.

Ground truth, any of:

* a synthetic scene directory (or its ``gt/`` folder; layout in :mod:`ogscene3d.datasets.synthetic`):
  ``gt/instances.json`` — ``{"classes": {id: name}, "instances": {"<id>": {"class": name, ...}},
  "relations": [[subject, relation, object], ...], "symmetric_relations": [...],
  "inverse_relations": {...}}``, or the flat ``{"<id>": {"class": name}, ..., "relations": [...]}`` —
  and the labelled point cloud ``gt/points.ply`` (``x y z instance [class]`` vertex fields; the
  class of a point is taken from its instance);
* a labelled PLY file with ``x y z`` and a class field (``class``, ``label``, ``semantic``,
  ``class_id`` or ``category_id``), optionally an ``instance``/``object_id`` field, plus a class-name
  table: ``--classes FILE.json``, else ``<ply stem>.json`` or ``classes.json`` beside the PLY, else, for
  ScanNet's ``*_vh_clean_2.labels.ply`` (NYU40 ids), the built-in NYU40 names. The table is a JSON list
  (index = class id), a ``{"<id>": name}`` object, or either under ``"classes"``; ``--classes scannet20``
  (ScanNet's 20 benchmark classes, the other NYU40 ids void) or ``nyu40`` names a built-in one. A folder
  holding such a PLY (a ScanNet scene folder: its ``*_vh_clean_2.labels.ply`` is preferred) may be given
  instead;
* the original Replica dataset's semantic annotation: a scene folder (``room_0``), its ``habitat/``
  folder or ``habitat/mesh_semantic.ply`` itself, with ``info_semantic.json`` beside the PLY; one point
  per face corner with the class of the face's object, as HOV-SG builds it (:mod:`.replica_gt`);
* an RGB-D sequence folder whose frames carry class maps but that holds no 3D ground truth (label-fusion's
  ``frame-N.segm.png``, ScanNet's ``label-filt/`` without a labels PLY, Semantic-NeRF's Replica
  ``semantic_class/``): a ground truth with no points (``has_3d`` False) that only rendered views can be
  scored against. Its class table: ``--classes``, else ``classes.json`` in the folder, else the layout's
  own (ScanNet: NYU40; Semantic-NeRF: the release's ``info_semantic.json``).

Class ids are re-indexed to 0..C-1 in table order; points whose id is not in the table are void (-1).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..datasets import open_dataset
from ..datasets.replica_semantic import class_entries
from ..datasets.scannet import BUILTIN_CLASS_TABLES, NYU40_CLASSES
from ..errors import DataError
from ..runs import RunFolder, recorded_data_path
from ..runs.gaussians_ply import SEMANTIC_FIELDS, read_gaussians_ply
from ..runs.graph_json import read_graph_json
from .ground_truth import GroundTruth, reindex_class_ids
from .replica_gt import load_replica_ground_truth, replica_semantic_files

log = logging.getLogger(__name__)

SCANNET_LABELS_SUFFIX = "_vh_clean_2.labels.ply"  # ScanNet's 3D semantic ground truth, NYU40 ids

_CLASS_FIELDS = ("class", "label", "semantic", "class_id", "category_id", "semantic_id")
_INSTANCE_FIELDS = ("instance", "instance_id", "object_id", "objectId")


@dataclass
class RunData:
    """What a run directory holds for evaluation."""

    means: np.ndarray  # [N, 3] float64 Gaussian centres, metres
    labels: np.ndarray  # [N] int64 scene labels, -1 = unlabeled
    confidences: np.ndarray  # [N] float32 in [0, 1]
    opacities: np.ndarray | None  # [N] float32 in (0, 1) (sigmoid of the stored logit), None if absent
    graph: dict[str, Any] | None  # parsed graph.json or None


def find_ground_truth(run_dir: str | Path) -> Path | None:
    """The ground truth of the scene a run was made from, if it can be found: ``RUN_DIR/scene`` (where
    ``ogscene3d run`` without ``--data`` generates a synthetic scene) or ``data.path`` of
    ``RUN_DIR/config.yaml`` holding ``gt/instances.json``; else ``data.path`` when it holds ScanNet's
    labels PLY or is a sequence whose frames carry class maps (label-fusion; 2D scores only). None when
    none does."""
    run = Path(run_dir)
    data = recorded_data_path(run)
    for c in (RunFolder(run).scene, data):
        if c is not None and (c / "gt" / "instances.json").is_file():
            return c
    if data is not None and data.is_dir() and (_scannet_label_ply(data) is not None or _frame_classes(data)):
        return data
    return None


def _scannet_label_ply(folder: Path) -> Path | None:
    """ScanNet's 3D semantic ground truth in ``folder`` (``*_vh_clean_2.labels.ply``, NYU40 ids), if one."""
    found = sorted(folder.glob(f"*{SCANNET_LABELS_SUFFIX}"))
    return found[0] if len(found) == 1 else None


def _frame_classes(folder: Path) -> Any:
    """The dataset in ``folder`` when it is an RGB-D sequence whose frames carry class maps, else None."""
    try:
        ds = open_dataset(folder)
    except DataError:
        return None
    return ds if ds.has_class_maps else None


def _read_ply_vertices(path: Path) -> Any:
    from plyfile import PlyData

    try:
        ply = PlyData.read(str(path))
    except FileNotFoundError:
        raise DataError(f"{path}: file not found") from None
    except Exception as e:  # plyfile raises assorted errors on truncated/corrupt files
        raise DataError(f"{path}: not a readable PLY file ({e})") from None
    if "vertex" not in ply:
        raise DataError(f"{path}: PLY has no 'vertex' element")
    return ply["vertex"].data


def _xyz(v: Any, path: Path) -> np.ndarray:
    names = v.dtype.names or ()
    for f in ("x", "y", "z"):
        if f not in names:
            raise DataError(f"{path}: vertex field '{f}' missing (have {list(names)})")
    pts = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    if not np.all(np.isfinite(pts)):
        raise DataError(
            f"{path}: {int((~np.isfinite(pts)).any(axis=1).sum())} vertices have NaN/inf coordinates"
        )
    return pts


def _int_field(v: Any, name: str, path: Path) -> np.ndarray:
    a = np.asarray(v[name])
    if np.issubdtype(a.dtype, np.floating):
        if not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
            raise DataError(f"{path}: field '{name}' must hold whole numbers")
    return a.astype(np.int64)


def read_run(run_dir: str | Path) -> RunData:
    """Read ``gaussians.ply`` (required) and ``graph.json`` (optional) of a run directory."""
    run = Path(run_dir)
    if not run.is_dir():
        raise DataError(f"{run}: run directory not found")
    ply = RunFolder(run).gaussians
    if not ply.is_file():
        raise DataError(f"{ply}: missing (a run directory holds gaussians.ply; docs/formats.md)")
    gaussians = read_gaussians_ply(ply, SEMANTIC_FIELDS)
    labels = gaussians.labels
    assert labels is not None  # a required field
    conf = gaussians.confidences
    if conf is None:
        conf = np.ones(len(labels), np.float32)
    opac = gaussians.opacities() if gaussians.opacity_logits is not None else None
    means = gaussians.means.astype(np.float64)
    labels = labels.astype(np.int64)
    graph = None
    gpath = RunFolder(run).graph
    if gpath.is_file():
        graph = read_graph_json(gpath)
    return RunData(means=means, labels=labels, confidences=conf, opacities=opac, graph=graph)


def _load_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(f"{path}: file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(f"{path}: invalid JSON ({e})") from None


def read_class_table(path: str | Path) -> dict[int, str]:
    """Class id -> name from a JSON list of names or of ``{"id", "name"}`` objects (Replica's
    ``info_semantic.json``), an ``{"<id>": name}`` object, or any of these under ``"classes"``; or a
    built-in table by name (``nyu40``, ``scannet20``: ScanNet's NYU40 ids) when no such file exists."""
    key = str(path).strip().lower()
    if key in BUILTIN_CLASS_TABLES and not Path(path).exists():
        return dict(BUILTIN_CLASS_TABLES[key])
    path = Path(path)
    data = _load_json(path)
    if isinstance(data, dict) and "classes" in data:
        data = data["classes"]
    if isinstance(data, list) and data and all(isinstance(n, dict) for n in data):
        return class_entries(data, path)
    if isinstance(data, list):
        if not all(isinstance(n, str) for n in data):
            raise DataError(f"{path}: a class list must hold names (strings) or {{'id', 'name'}} objects")
        return dict(enumerate(data))
    if isinstance(data, dict):
        out: dict[int, str] = {}
        for k, n in data.items():
            try:
                out[int(k)] = str(n["name"] if isinstance(n, dict) else n)
            except (ValueError, KeyError, TypeError):
                raise DataError(f"{path}: class table entry {k!r}: {n!r} is not 'id': name") from None
        return out
    raise DataError(f"{path}: expected a list of class names or an {{id: name}} object")


@dataclass
class _InstanceTable:
    instance_class: dict[int, str]
    class_table: dict[int, str] | None
    relations: list[tuple[int, str, int]]
    symmetric: list[str] | None
    inverses: list[tuple[str, str]] | None
    instance_rooms: dict[int, int] = field(default_factory=dict)
    rooms: dict[int, dict[str, Any]] = field(default_factory=dict)


def _read_instances_json(path: Path) -> _InstanceTable:
    """Both the synthetic generator's layout (``{"classes", "instances", "relations", ...}``) and the
    flat one (``{"<id>": {"class": name}, ..., "relations": [...]}``)."""
    data = _load_json(path)
    if not isinstance(data, dict):
        raise DataError(f"{path}: expected an object with instances and relations")
    entries = data["instances"] if isinstance(data.get("instances"), dict) else data
    inst: dict[int, str] = {}
    for k, val in entries.items():
        try:
            iid = int(k)
        except ValueError:
            continue  # top-level metadata of the flat layout ("relations", "version", ...)
        if isinstance(val, dict) and isinstance(val.get("class"), str):
            inst[iid] = val["class"]
        elif isinstance(val, str):
            inst[iid] = val
        else:
            raise DataError(f"{path}: instance {k}: expected {{'class': name}}, got {val!r:.80}")
    table = None
    if isinstance(data.get("classes"), dict):
        try:
            table = {int(k): str(v) for k, v in data["classes"].items()}
        except ValueError:
            raise DataError(f"{path}: 'classes' must map class ids to names") from None
    rels: list[tuple[int, str, int]] = []
    raw = data.get("relations", [])
    if not isinstance(raw, list):
        raise DataError(f"{path}: 'relations' must be a list of [subject, relation, object]")
    for r in raw:
        if not (isinstance(r, (list, tuple)) and len(r) == 3):
            raise DataError(f"{path}: relation {r!r} is not [subject, relation, object]")
        try:
            rels.append((int(r[0]), str(r[1]), int(r[2])))
        except (TypeError, ValueError):
            raise DataError(f"{path}: relation {r!r}: subject/object must be instance ids") from None
    sym = data.get("symmetric_relations")
    inv = data.get("inverse_relations")
    rooms, instance_rooms = _read_rooms(path, data, entries)
    return _InstanceTable(
        instance_class=inst,
        class_table=table,
        relations=rels,
        symmetric=[str(x) for x in sym] if isinstance(sym, list) else None,
        inverses=[(str(a), str(b)) for a, b in inv.items()] if isinstance(inv, dict) else None,
        instance_rooms=instance_rooms,
        rooms=rooms,
    )


def _read_rooms(path: Path, data: dict, entries: dict) -> tuple[dict[int, dict[str, Any]], dict[int, int]]:
    """The rooms of an apartment's instances.json ({} without): {room id: {"type", "floor", "first_frame"}}
    and {instance id: room id}."""
    raw = data.get("rooms") or {}
    if not isinstance(raw, dict):
        raise DataError(f"{path}: 'rooms' must map room ids to rooms")
    try:
        rooms = {
            int(k): {
                "type": str(v.get("type", "room")),
                "floor": int(v.get("floor", 0)),
                "first_frame": None if v.get("first_frame") is None else int(v["first_frame"]),
            }
            for k, v in raw.items()
        }
        inst_room = {
            int(k): int(v["room"])
            for k, v in entries.items()
            if isinstance(v, dict) and v.get("room") is not None
        }
    except (AttributeError, TypeError, ValueError) as e:
        raise DataError(f"{path}: malformed rooms ({type(e).__name__}: {e})") from None
    unknown = sorted({r for r in inst_room.values() if r not in rooms})
    if unknown:
        raise DataError(f"{path}: instances are in rooms {unknown}, which are not in 'rooms'")
    return rooms, inst_room


def _find_gt_ply(folder: Path) -> Path:
    plys = sorted(folder.glob("*.ply"))
    if not plys:
        raise DataError(f"{folder}: no labelled point cloud (*.ply) found")
    if len(plys) == 1:
        return plys[0]
    scannet = _scannet_label_ply(folder)  # beside it lie the unlabelled meshes of the scan
    if scannet is not None:
        return scannet
    for name in ("points.ply", "gt_points.ply", "labels.ply", "pointcloud.ply", "semantic.ply"):
        if (folder / name).is_file():
            return folder / name
    raise DataError(f"{folder}: several PLY files {[p.name for p in plys]}; pass the labelled one to --gt")


def load_ground_truth(gt: str | Path, classes: str | Path | None = None) -> GroundTruth:
    """Load ground truth from a synthetic scene directory, a ``gt/`` folder, a Replica scene (its folder,
    ``habitat/`` or ``mesh_semantic.ply``), a labelled PLY file or a sequence with class maps."""
    path = Path(gt)
    if not path.exists():
        raise DataError(f"{path}: ground truth not found")
    replica = None if (path / "gt" / "instances.json").is_file() else replica_semantic_files(path)
    if replica is not None:
        if classes is not None:
            log.warning("--classes %s not used: Replica's class table is %s", classes, replica[1])
        return load_replica_ground_truth(*replica)
    if path.is_dir():
        folder = path / "gt" if (path / "gt" / "instances.json").is_file() else path
        inst_json = folder / "instances.json"
        if inst_json.is_file():
            return _load_instance_gt(folder, inst_json)
        if _scannet_label_ply(folder) is None and (ds := _frame_classes(folder)) is not None:
            # A sequence's PLYs (if any) are meshes, not labelled clouds: only the scanner's labels
            # PLY (above) or a gt/ folder is 3D ground truth there.
            return _frames_only_gt(folder, ds, classes)
        ply = _find_gt_ply(folder)
    else:
        ply = path
    return _load_labelled_ply(ply, classes)


def _load_instance_gt(folder: Path, inst_json: Path) -> GroundTruth:
    table = _read_instances_json(inst_json)
    ply = _find_gt_ply(folder)
    v = _read_ply_vertices(ply)
    names = v.dtype.names or ()
    pts = _xyz(v, ply)
    inst_field = next((f for f in _INSTANCE_FIELDS if f in names), None)
    if inst_field is None:
        raise DataError(
            f"{ply}: no instance field ({'/'.join(_INSTANCE_FIELDS)}) to join with {inst_json.name}"
        )
    inst = _int_field(v, inst_field, ply)
    observed = _int_field(v, "observed", ply).astype(bool) if "observed" in names else None
    if table.class_table:
        class_ids: list[int] | None = sorted(table.class_table)
        class_names = [table.class_table[i] for i in class_ids]
        missing = sorted(set(table.instance_class.values()) - set(class_names))
        if missing:
            raise DataError(f"{inst_json}: instance classes {missing} are not in its 'classes' table")
    else:
        class_ids = None
        class_names = sorted(set(table.instance_class.values()))
    cidx = {n: i for i, n in reversed(list(enumerate(class_names)))}
    instance_classes = {i: cidx[n] for i, n in table.instance_class.items()}
    ids = np.array(sorted(instance_classes), dtype=np.int64)
    lut = np.array([instance_classes[int(i)] for i in ids], dtype=np.int64)
    if ids.size:
        pos = np.clip(np.searchsorted(ids, inst), 0, ids.size - 1)
        known = ids[pos] == inst
        classes = np.where(known, lut[pos], -1)
    else:
        known = np.zeros(inst.shape, bool)
        classes = np.full(inst.shape, -1, np.int64)
    unknown = int(((inst >= 0) & ~known).sum())
    if unknown:
        log.warning(
            "%s: %d points have instance ids absent from %s; treated as void", ply, unknown, inst_json
        )
    for s, _, o in table.relations:
        if s not in instance_classes or o not in instance_classes:
            raise DataError(f"{inst_json}: relation ({s}, ..., {o}) names an unknown instance")
    return GroundTruth(
        points=pts,
        classes=classes.astype(np.int64),
        class_names=class_names,
        instances=np.where(known, inst, -1).astype(np.int64),
        instance_classes=instance_classes,
        relations=table.relations,
        symmetric_relations=table.symmetric,
        inverse_relations=table.inverses,
        class_ids=class_ids,
        source=str(folder),
        observed=observed,
        instance_rooms=table.instance_rooms,
        rooms=table.rooms,
    )


def _frames_only_gt(folder: Path, ds: Any, classes: str | Path | None) -> GroundTruth:
    """Ground truth with no 3D points: the class table of the per-frame class maps of sequence ``ds``."""
    table_path = Path(classes) if classes is not None else None
    if table_path is None and (folder / "classes.json").is_file():
        table_path = folder / "classes.json"
    if table_path is not None:
        table = read_class_table(table_path)
        source = f"{folder} (per-frame class maps, names from {table_path.name})"
        void = ds.void_class_id
        if void is not None and void in table:
            # a layout's no-class value stays void as in its own table (Semantic-NeRF writes 0 where no
            # class is): a table given by --classes (Replica's info_semantic.json) must not score it
            log.info(
                "%s: class id %d (%r) is void in %s class maps", table_path, void, table.pop(void), ds.kind
            )
    elif ds.class_names is not None:
        table = ds.class_names
        source = f"{folder} (per-frame class maps, {ds.kind} class names)"
    else:
        raise DataError(
            f"{folder}: its {ds.kind} frames carry class ids but no class names: pass --classes FILE.json "
            "(a list of names or {id: name}) or put classes.json in the folder"
        )
    return GroundTruth(
        points=np.zeros((0, 3)),
        classes=np.zeros(0, np.int64),
        class_names=[table[i] for i in sorted(table)],
        class_ids=sorted(table),
        source=source,
        has_3d=False,
    )


def _load_labelled_ply(ply: Path, classes: str | Path | None) -> GroundTruth:
    v = _read_ply_vertices(ply)
    names = v.dtype.names or ()
    pts = _xyz(v, ply)
    cfield = next((f for f in _CLASS_FIELDS if f in names), None)
    if cfield is None:
        raise DataError(f"{ply}: no class field (one of {list(_CLASS_FIELDS)}); have {list(names)}")
    raw = _int_field(v, cfield, ply)
    table_path = Path(classes) if classes is not None else None
    if table_path is None:
        for cand in (ply.with_suffix(".json"), ply.parent / "classes.json"):
            if cand.is_file():
                table_path = cand
                break
    scannet = ply.name.endswith(SCANNET_LABELS_SUFFIX)
    if table_path is None and scannet:
        table = dict(NYU40_CLASSES)  # ScanNet's labels PLY holds NYU40 ids
        table_path = Path("NYU40 (built in)")
    elif table_path is None:
        raise DataError(
            f"{ply}: no class-name table; pass --classes FILE.json (a list of names or {{id: name}})"
        )
    else:
        table = read_class_table(table_path)
    cls, class_names = reindex_class_ids(raw, table)
    unexpected = (raw >= 0) & (cls < 0)
    if scannet:
        # ScanNet's id 0 is "unannotated", and a built-in subset (scannet20) voids the other NYU40 ids on
        # purpose: warning about either on every scene would bury a real mismatch.
        expected = raw == 0
        if str(table_path).lower() in BUILTIN_CLASS_TABLES:
            expected |= np.isin(raw, list(NYU40_CLASSES))
        unexpected &= ~expected
    void = int(unexpected.sum())
    if void:
        log.warning("%s: %d points have class ids absent from %s; treated as void", ply, void, table_path)
    ifield = next((f for f in _INSTANCE_FIELDS if f in names), None)
    instances = None
    instance_classes: dict[int, int] = {}
    if ifield is not None:
        instances = _int_field(v, ifield, ply)
        ok = (instances >= 0) & (cls >= 0)
        if ok.any():
            pairs = np.unique(np.stack([instances[ok], cls[ok]], axis=1), axis=0)
            instance_classes = {int(i): int(c) for i, c in pairs}
    return GroundTruth(
        points=pts,
        classes=cls,
        class_names=class_names,
        instances=instances,
        instance_classes=instance_classes,
        relations=[],
        class_ids=sorted(table),
        source=str(ply),
    )
