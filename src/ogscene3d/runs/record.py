"""A run's record in its folder: its id (``run_id``), its settings (``config.yaml``), what it ran
(``timings.json``) and what ``eval`` found (``metrics.json``).

``run`` and ``run-batch`` write ``config.yaml`` with the data the run maps and, beside it, the run's id
before the first frame (:func:`start_run_dir`); each checkpoint records both (``Mapper.source``), so that a
resume refuses a map that another run's ``config.yaml`` now sits beside (:func:`resumed_run_id`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..atomic import atomic_write_text
from ..config import Config, config_to_dict, load_config, save_config
from ..errors import DataError
from .layout import RunFolder

if TYPE_CHECKING:
    import numpy as np

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------------- run_id
def read_run_id(out: str | Path) -> str | None:
    """The id in ``out/run_id`` (None: no file, or an empty one)."""
    try:
        return RunFolder(out).run_id.read_text().strip() or None
    except OSError:
        return None


def write_run_id(out: str | Path, run_id: str) -> None:
    atomic_write_text(RunFolder(out).run_id, run_id + "\n")


def remove_run_id(out: str | Path) -> None:
    RunFolder(out).run_id.unlink(missing_ok=True)


# ------------------------------------------------------------------------------------------- config.yaml
def write_config(path: str | Path, cfg: Config) -> None:
    """Write a run's settings (atomically; :func:`ogscene3d.config.load_config` reads them back)."""
    save_config(cfg, path)


def read_config(run_dir: str | Path) -> Config:
    """The settings a run recorded (``RUN_DIR/config.yaml``), checked as ``--config`` is.

    Raises:
        ConfigError: not a valid config (e.g. written by another version).
    """
    return load_config(RunFolder(run_dir).config)


def _recorded(run_dir: str | Path) -> dict[str, Any] | None:
    """``RUN_DIR/config.yaml`` as plain YAML (no checks: another version's file is read too); None when
    absent."""
    import yaml

    path = RunFolder(run_dir).config
    if not path.is_file():
        return None
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        raise DataError(f"{path}: invalid YAML ({e})") from None
    return doc if isinstance(doc, dict) else {}


def recorded_data_path(run_dir: str | Path) -> Path | None:
    """The ``data.path`` a run recorded (relative to the run folder when relative), or None.

    Raises:
        DataError: ``config.yaml`` is not YAML.
    """
    doc = _recorded(run_dir)
    data = doc.get("data") if doc else None
    path = data.get("path") if isinstance(data, dict) else None
    if not path or not isinstance(path, str):
        return None
    p = Path(path)
    return p if p.is_absolute() else Path(run_dir) / p


def recorded_up(run_dir: str | Path, trajectory: Any = None) -> np.ndarray | None:
    """The unit world-up vector a run was configured with (``config.yaml``'s ``graph.up_axis``), or where
    that stayed ``auto`` (chosen from the tracked cameras during the run) the up direction of the keyframe
    cameras ``trajectory`` ([T, 4, 4] camera-to-world); None, with a warning when the file is unreadable,
    when there is none (it only orients a viewer's camera).

    This is the run's configured up, known without a scene graph; the up its scene graph was built with
    (``graph.json``'s ``up``, which rooms and heights are read with) is
    :func:`ogscene3d.runs.graph_json.graph_up`'s.
    """
    from ..up_axis import CameraUp, is_auto, unit_up  # numpy: `ogscene3d --help` reads this module without

    try:
        doc = _recorded(run_dir)
        if doc is None:
            return None
        value = doc["graph"]["up_axis"]
        if is_auto(value):
            cams = CameraUp()
            for pose in trajectory if trajectory is not None else ():
                cams.add(pose)
            return cams.estimate()
        return unit_up(value)
    except Exception:  # noqa: BLE001 - the up vector only orients the camera; a default is fine
        log.warning(
            "%s: no readable graph.up_axis; using the viewer's default up direction",
            RunFolder(run_dir).config,
        )
        return None


def config_digest(cfg: Config) -> str:
    """A digest of the settings ``cfg`` holds: the same for ``cfg`` and for its ``config.yaml`` read back
    (YAML layout, comments and key order do not count)."""
    return hashlib.sha256(json.dumps(config_to_dict(cfg), sort_keys=True).encode()).hexdigest()


def start_run_dir(out: Path, cfg: Config, run_id: str | None = None) -> dict[str, str]:
    """Before the first frame (after a resume was accepted): write the config with the data it records, so
    that a run stopped before its end can be resumed with its settings, and beside it the run's id (new
    unless given: a resume goes on with its map's). -> ``{"run_id", "config"}`` (the id and the settings'
    digest) for ``Mapper.source``: each checkpoint then names the run it belongs to (see
    :func:`resumed_run_id`).
    """
    out.mkdir(parents=True, exist_ok=True)
    run_id = run_id or uuid.uuid4().hex
    # the id first: killed between the two writes, the old config.yaml is left with the new id, and an old map
    # is then refused (ids differ) unless it was made with that very config.yaml, instead of the other way
    # round, where the old id would vouch for an old map beside a new config.yaml
    write_run_id(out, run_id)
    write_config(RunFolder(out).config, cfg)
    return {"run_id": run_id, "config": config_digest(cfg)}


def resumed_run_id(out: Path, recorded: dict, cfg: Config | None = None) -> str | None:
    """The run id a resume of ``out`` goes on with: that of the run that wrote ``out/map.npz`` (whose
    ``Mapper.source`` is ``recorded``); None for a map that records none (an older version's: it is
    resumed unchecked, as it always was). ``cfg``: the settings the resume would map with (``--config``
    and ``--set`` applied), when known.

    Raises:
        DataError: the map was written by another run than the one whose ``config.yaml`` is in ``out``
            (a run started there after the map was saved, then stopped before saving its own), and with
            other settings, and ``cfg`` is not the map's either: resuming would continue the earlier map
            with a later run's settings.
    """
    folder = RunFolder(out)
    map_id, map_config = recorded.get("run_id"), recorded.get("config")
    if map_id is None and map_config is None:
        return None
    if map_id is not None and map_id == read_run_id(out):
        return map_id
    if cfg is not None and map_config == config_digest(cfg):
        # the map's own settings given back (--config): whatever config.yaml holds, they replace it
        log.info("%s goes on with the settings it was mapped with", folder.map)
        return map_id
    saved = folder.config
    if not saved.is_file():  # no other run's settings to pair the map with
        return map_id
    if map_config == config_digest(load_config(saved)):
        # another run wrote config.yaml, but with this map's very settings: resuming the map is harmless
        log.info("%s was mapped by an earlier run with the settings of %s: resuming it", folder.map, saved)
        return map_id
    raise DataError(
        f"{folder.map} was not written by the run whose {saved} is there (run ids and settings "
        f"differ): a later run started in {out} and stopped before saving a map, so the map is an earlier "
        "run's, made with other settings, and resuming would go on with the later run's. Run again without "
        "--resume to map with the settings in config.yaml (this replaces the earlier map), or, to go on with "
        "the earlier map, resume with its run's settings (put its config.yaml back, or pass it with --config)"
    )


# ------------------------------------------------------------------------------------ timings, metrics
def write_timings(path: str | Path, timings: dict[str, Any]) -> None:
    atomic_write_text(path, json.dumps(timings, indent=2))


def read_timings(path: str | Path) -> dict[str, Any]:
    """timings.json as a dict; {} with a warning when it is unreadable or not an object (it only feeds
    reports and the viewer's timings panel, so a bad file must not stop them)."""
    path = Path(path)
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        log.warning("%s: unreadable (%s); no timings shown", path, e)
        return {}
    if not isinstance(doc, dict):
        log.warning("%s: expected a JSON object, got %s; no timings shown", path, type(doc).__name__)
        return {}
    return doc


def json_safe(x: Any) -> Any:
    """NaN/inf -> None, numpy scalars -> Python, tuples -> lists (strict JSON), recursively."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if hasattr(x, "item") and callable(x.item) and getattr(x, "ndim", 1) == 0:
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def write_metrics(path: str | Path, report: dict[str, Any]) -> Path:
    """Write ``eval``'s report (``metrics.json``) as strict JSON (NaN -> null), atomically."""
    path = Path(path)
    atomic_write_text(path, json.dumps(json_safe(report), indent=2, allow_nan=False) + "\n")
    return path

