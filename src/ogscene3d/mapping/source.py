"""What a run's frames come from, recorded the same way by ``run``, ``run-batch``, the ablation and the live
viewer: in ``config.yaml`` (``eval`` finds the ground truth there, ``run --resume`` the frames) and in the
checkpoint (a resume refuses another sequence's frames; the run's id and settings are
:mod:`ogscene3d.runs.record`'s)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import remove_stale_temps
from ..config import Config
from ..datasets.identity import file_digest, frame_names, sequence_change
from ..datasets.identity import mapped_intrinsics as mapped_intrinsics
from ..datasets.identity import matching_pixel_centers as matching_pixel_centers
from ..errors import DataError
from ..runs import RUN_FILES, RunFolder
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


def remove_run_temps(out: Path) -> None:
    """Remove the temporary files that a killed run's writes left in ``out``, and the memory view files
    that its ``map.npz`` does not name (a killed checkpoint's)."""
    for name in RUN_FILES:
        for tmp in remove_stale_temps(out / name):
            log.info("removed %s, a killed write's leftover", tmp)
    for f in remove_leftovers(RunFolder(out).map):
        log.info("removed %s, a killed checkpoint's leftover", f)


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
