"""What a run's frames come from, recorded the same way by ``run``, ``run-batch`` and the live viewer: in
``config.yaml`` (``eval`` finds the ground truth there, ``run --resume`` the frames) and in the checkpoint
(a resume refuses another sequence's frames)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..atomic import remove_stale_temps
from ..config import Config, save_config
from ..errors import DataError
from .memory_files import remove_leftovers

log = logging.getLogger(__name__)


def record_data(cfg: Config, data: str | Path, segments_dir: str | Path | None = None) -> None:
    """Set ``cfg.data.path`` (and ``segments_dir`` when given) to absolute paths."""
    cfg.data.path = str(Path(data).resolve())
    if segments_dir is not None:
        cfg.data.segments_dir = str(Path(segments_dir).resolve())


def dataset_source(cfg: Config, ds) -> dict:
    """The identity of the frames of ``ds`` (an opened dataset of ``cfg.data``), for ``Mapper.source``."""
    K = [round(float(v), 4) for v in np.asarray(ds.K).reshape(-1)]
    # start and stride: a checkpoint's next frame is a position in this selection, which a resume must share
    return {
        "path": cfg.data.path,
        "frames": len(ds),
        "first": ds.records[0].name,
        "K": K,
        "start": cfg.data.start,
        "stride": cfg.data.stride,
    }


RUN_FILES = ("map.npz", "gaussians.ply", "graph.json", "timings.json", "config.yaml", "traj.txt")


def remove_run_temps(out: Path) -> None:
    """Remove the temporary files that a killed run's writes left in ``out``, and the memory view files
    that its ``map.npz`` does not name (a killed checkpoint's)."""
    for name in RUN_FILES:
        for tmp in remove_stale_temps(out / name):
            log.info("removed %s, a killed write's leftover", tmp)
    for f in remove_leftovers(out / "map.npz"):
        log.info("removed %s, a killed checkpoint's leftover", f)


def start_run_dir(out: Path, cfg: Config) -> None:
    """Before the first frame (after a resume was accepted): write the config with the data it records, so
    that a run stopped before its end can be resumed with its settings."""
    out.mkdir(parents=True, exist_ok=True)
    save_config(cfg, out / "config.yaml")


def check_same_source(ckpt: Path, recorded: dict, current: dict) -> None:
    """Refuse to resume a map with frames of another sequence or camera; a moved dataset (same frames) is
    fine."""
    if recorded.get("K") is not None and not np.allclose(recorded["K"], current["K"], atol=1e-3):
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
    if not recorded or recorded.get("path") == current["path"]:
        return
    same = recorded.get("frames") == current["frames"] and recorded.get("first") == current["first"]
    if same:
        log.warning(
            "%s was mapped from %s; resuming with the same frames from %s",
            ckpt,
            recorded["path"],
            current["path"],
        )
        return
    raise DataError(
        f"{ckpt} was mapped from {recorded['path']} ({recorded.get('frames')} frames, first "
        f"{recorded.get('first')!r}), not from {current['path']} ({current['frames']} frames, first "
        f"{current['first']!r}): resume with the same --data, or map the other sequence into a new --out"
    )
