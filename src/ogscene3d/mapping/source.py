"""What a run's frames come from, recorded the same way by ``run``, ``run-batch`` and the live viewer: in
``config.yaml`` (``eval`` finds the ground truth there, ``run --resume`` the frames) and in the checkpoint
(a resume refuses another sequence's frames, or a map that another run's ``config.yaml`` now sits beside)."""

from __future__ import annotations

import hashlib
import json
import logging
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write_text, remove_stale_temps
from ..config import Config, config_to_dict, load_config, save_config
from ..datasets.identity import file_digest, frame_names, sequence_change
from ..datasets.identity import mapped_intrinsics as mapped_intrinsics
from ..datasets.identity import matching_pixel_centers as matching_pixel_centers
from ..errors import DataError
from .memory_files import remove_leftovers

log = logging.getLogger(__name__)


def record_data(cfg: Config, data: str | Path, segments_dir: str | Path | None = None) -> None:
    """Set ``cfg.data.path`` (and ``segments_dir`` when given) to absolute paths."""
    cfg.data.path = str(Path(data).resolve())
    if segments_dir is not None:
        cfg.data.segments_dir = str(Path(segments_dir).resolve())


def dataset_source(cfg: Config, ds: Any) -> dict:
    """The identity of the frames of ``ds`` (an opened dataset of ``cfg.data``), for ``Mapper.source``."""
    K = [round(float(v), 4) for v in np.asarray(ds.K).reshape(-1)]
    # start and stride: a checkpoint's next frame is a position in this selection, which a resume must share;
    # names: which frames those positions were, so that frames added to or removed from the sequence since
    # are found (by a resume and by eval --held-out) instead of shifting what counts as mapped
    return {
        "path": cfg.data.path,
        "frames": len(ds),
        "first": ds.records[0].name,
        "K": K,
        "start": cfg.data.start,
        "stride": cfg.data.stride,
        "names": frame_names(ds),
        "first_digest": file_digest(ds.records[0].rgb_path),
    }


RUN_ID_FILE = "run_id"
RUN_FILES = ("map.npz", "gaussians.ply", "graph.json", "timings.json", "config.yaml", "traj.txt", RUN_ID_FILE)


def remove_run_temps(out: Path) -> None:
    """Remove the temporary files that a killed run's writes left in ``out``, and the memory view files
    that its ``map.npz`` does not name (a killed checkpoint's)."""
    for name in RUN_FILES:
        for tmp in remove_stale_temps(out / name):
            log.info("removed %s, a killed write's leftover", tmp)
    for f in remove_leftovers(out / "map.npz"):
        log.info("removed %s, a killed checkpoint's leftover", f)


def config_digest(cfg: Config) -> str:
    """A digest of the settings ``cfg`` holds: the same for ``cfg`` and for its ``config.yaml`` read back
    (YAML layout, comments and key order do not count)."""
    return hashlib.sha256(json.dumps(config_to_dict(cfg), sort_keys=True).encode()).hexdigest()


def _read_run_id(out: Path) -> str | None:
    try:
        return (out / RUN_ID_FILE).read_text().strip() or None
    except OSError:
        return None


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
    atomic_write_text(out / RUN_ID_FILE, run_id + "\n")
    save_config(cfg, out / "config.yaml")
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
    map_id, map_config = recorded.get("run_id"), recorded.get("config")
    if map_id is None and map_config is None:
        return None
    if map_id is not None and map_id == _read_run_id(out):
        return map_id
    if cfg is not None and map_config == config_digest(cfg):
        # the map's own settings given back (--config): whatever config.yaml holds, they replace it
        log.info("%s goes on with the settings it was mapped with", out / "map.npz")
        return map_id
    saved = out / "config.yaml"
    if not saved.is_file():  # no other run's settings to pair the map with
        return map_id
    if map_config == config_digest(load_config(saved)):
        # another run wrote config.yaml, but with this map's very settings: resuming the map is harmless
        log.info(
            "%s was mapped by an earlier run with the settings of %s: resuming it", out / "map.npz", saved
        )
        return map_id
    raise DataError(
        f"{out / 'map.npz'} was not written by the run whose {saved} is there (run ids and settings "
        f"differ): a later run started in {out} and stopped before saving a map, so the map is an earlier "
        "run's, made with other settings, and resuming would go on with the later run's. Run again without "
        "--resume to map with the settings in config.yaml (this replaces the earlier map), or, to go on with "
        "the earlier map, resume with its run's settings (put its config.yaml back, or pass it with --config)"
    )


def check_same_source(
    ckpt: Path,
    recorded: dict,
    current: dict,
    mapped: int = 0,
    pixel_centers: Callable[[Any], str | None] | None = None,
) -> None:
    """Refuse to resume a map with frames of another sequence or camera, or of a sequence whose first
    ``mapped`` frames (those the map has read) changed; a moved dataset (same frames) is fine, and so are
    frames added after the mapped ones. ``pixel_centers``: given the map's K, the ``data.pixel_centers``
    that reads the frames so (:func:`matching_pixel_centers`), asked for only when the map's K is not
    today's."""
    if recorded.get("K") is not None and not np.allclose(recorded["K"], current["K"], atol=1e-3):
        setting = pixel_centers(recorded["K"]) if pixel_centers is not None else None
        if setting is not None:
            raise DataError(
                f"{ckpt} was mapped with intrinsics {recorded['K']}, these frames have {current['K']}: the "
                f"same camera, read with data.pixel_centers={setting} (a map made before that setting "
                "existed read every layout's intrinsics as they are, which is 'half'; see the README): "
                f"resume with --set data.pixel_centers={setting}, or map into a new --out"
            )
        raise DataError(
            f"{ckpt} was mapped with intrinsics {recorded['K']}, these frames have {current['K']} (another "
            "camera or image size): map them into a new --out"
        )
    changed = [k for k in ("start", "stride") if k in recorded and recorded[k] != current.get(k)]
    if changed:
        # the checkpoint's next frame is a position in the run's selection: another selection would map other
        # frames than the ones that position counts (and eval --held-out would count the wrong ones mapped)
        was = f"data.start {recorded.get('start')}, data.stride {recorded.get('stride')}"
        now = f"start {current.get('start')}, stride {current.get('stride')}"
        raise DataError(
            f"{ckpt} was mapped with {was}; this run selects {now}: a resume needs the run's frame selection "
            "(drop the --set, or map into a new --out)"
        )
    if recorded and recorded.get("path") != current["path"]:
        same = recorded.get("first") == current["first"]
        if recorded.get("first_digest") and current.get("first_digest"):
            # the first frame's bytes tell a moved sequence from another one, whatever --max-frames bounded
            same = same and recorded["first_digest"] == current["first_digest"]
        else:  # an older checkpoint: the frame count has to tell
            same = same and recorded.get("frames") == current["frames"]
        if not same:
            raise DataError(
                f"{ckpt} was mapped from {recorded['path']} ({recorded.get('frames')} frames, first "
                f"{recorded.get('first')!r}), not from {current['path']} ({current['frames']} frames, first "
                f"{current['first']!r}): resume with the same --data, or map the other sequence into a new "
                "--out"
            )
        log.warning(
            "%s was mapped from %s; resuming with the same frames from %s",
            ckpt,
            recorded["path"],
            current["path"],
        )
    names = recorded.get("names")
    if names is None:  # an older checkpoint: which frames it read is not recorded
        return
    # the resume reads on from position `mapped`: a frame added or removed before it would shift the frames
    # read next (one mapped twice, or never) without anything failing
    why = sequence_change(names, current["names"], mapped)
    if why is not None:
        raise DataError(
            f"{ckpt}: the sequence changed since it was mapped ({why}): with frames added or removed among "
            f"the {mapped} the map has read, its position no longer names the next frame; map the sequence "
            "into a new --out, or restore its frames"
        )
