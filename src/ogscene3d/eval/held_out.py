"""Which frames of a sequence a run mapped, and held-out views among the others (``eval --held-out``).

A run maps the frames its ``config.yaml`` selects (``data.start``, ``data.stride``, ``data.max_frames``) up to
where it stopped: ``map.npz`` records that position (``mapper_next_index``, a position in the selection),
which also covers a run bounded by ``run --max-frames`` (not in ``config.yaml``) or stopped early, and the
selection's frames by name (``mapper_source``), so that frames added to or removed from the sequence since
it was mapped, which would shift those positions, are refused rather than scored as held out. Every
selected frame before that position counts as mapped, also one the mapper left out (a bad frame skipped
under ``data.on_bad_frame: skip``, an untracked frame, a pose jump): held-out views are frames the mapper
was never given.

Held-out frames between the first and the last mapped frame (those a stride skipped) are novel views of
the mapped scene; frames before the first or after the last mapped one are extrapolation, used only when
no other frame is held out, and the report says so.

Frame indices are positions in :func:`~ogscene3d.eval.views.open_view_dataset`'s dataset (every frame of
the sequence); selection and sequence frames are matched by their rgb file, so frames a layout drops for
missing files shift neither.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..datasets import open_dataset
from ..datasets.identity import frame_names, sequence_change
from ..errors import ConfigError, DataError
from ..runs import RunFolder, read_config
from ..runs.map_npz import read_map_npz

log = logging.getLogger(__name__)


@dataclass
class RunFrames:
    """The frames of a sequence a run was given, as positions in the whole sequence."""

    mapped: list[int]  # sorted positions in the sequence dataset
    selection: str  # the run's frame selection, in words ("start 0, stride 2, all frames")
    num_selected: int  # frames the selection holds
    how: str  # where the number mapped came from

    @property
    def first(self) -> int:
        return self.mapped[0]

    @property
    def last(self) -> int:
        return self.mapped[-1]

    def describe(self) -> str:
        return (
            f"{len(self.mapped)} of the {self.num_selected} frames of its selection ({self.selection}; "
            f"{self.how}), sequence frames {self.first}..{self.last}"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "selection": self.selection,
            "num_selected": self.num_selected,
            "num_mapped": len(self.mapped),
            "first": self.first,
            "last": self.last,
            "how": self.how,
        }


def pick_frames(num_frames: int, num_views: int) -> list[int]:
    """``num_views`` frame indices spread evenly over ``[0, num_frames)`` (first and last included)."""
    if num_frames <= 0 or num_views <= 0:
        return []
    return sorted({int(round(x)) for x in np.linspace(0, num_frames - 1, min(num_views, num_frames))})


def _mapped_count(run_dir: Path, selection: Any, data: Any) -> tuple[int, str]:
    """How many frames of ``selection`` (the run's, opened now) the run read, from ``map.npz``; the whole
    selection without one."""
    num_selected = len(selection)
    ckpt = RunFolder(run_dir).map
    if not ckpt.is_file():
        return num_selected, "no map.npz: the whole selection is taken as mapped"
    try:
        z = read_map_npz(ckpt, ("mapper_next_index", "mapper_source"))
        nxt = int(z["mapper_next_index"]) if "mapper_next_index" in z else None
        source = json.loads(str(z["mapper_source"])) if "mapper_source" in z else {}
    except (DataError, ValueError) as e:
        raise DataError(f"{ckpt}: cannot read how far the run got ({e})") from None
    # its next frame is a position in the selection it was mapped with (recorded since checkpoints say so)
    for key in ("start", "stride"):
        if key in source and source[key] != getattr(data, key):
            raise DataError(
                f"{ckpt} was mapped with data.{key} {source[key]}, but the run's config.yaml says "
                f"{getattr(data, key)}: cannot tell which frames the run mapped"
            )
    recorded = source.get("names")
    if recorded is not None and nxt is not None:
        # frames added to or removed from the sequence since would shift the positions nxt counts, and a
        # frame the run mapped would be scored as a held-out view
        current = frame_names(selection)
        why = sequence_change(recorded, current, nxt)
        if why is None and len(current) < nxt:
            why = f"the run read {nxt} frames of its selection, which now holds {len(current)}"
        if why is not None:
            raise DataError(
                f"{ckpt}: the sequence changed since the run mapped it ({why}): with frames added or "
                f"removed, which frames of {selection.root} it mapped cannot be told; restore the sequence, "
                "or map it again to hold frames out"
            )
    else:
        # the checkpoint names the selection's first frame: another one means config.yaml is not this map's
        first = source.get("first")
        first_name = selection.records[0].name
        if first is not None and first != first_name:
            raise DataError(
                f"{ckpt} was mapped from frames starting at {first!r}, but the run's config.yaml selects "
                f"frames starting at {first_name!r}: cannot tell which frames the run mapped"
            )
        if recorded is None:
            log.info(
                "%s records no frame names (an older version): frames added to or removed from the sequence "
                "since it was mapped cannot be told",
                ckpt,
            )
    if nxt is None:
        return num_selected, "map.npz records no frame position (an older run): the whole selection is taken"
    if not 0 < nxt <= num_selected:
        raise DataError(
            f"{ckpt} has read {nxt} frames, but the run's config.yaml selects {num_selected}: cannot tell "
            "which frames the run mapped"
        )
    if nxt < num_selected:
        return nxt, f"map.npz: the run stopped after {nxt} of them"
    return nxt, "map.npz: the run read all of them"


def run_frames(run_dir: str | Path, ds: Any) -> RunFrames:
    """The frames of ``ds`` (every frame of a sequence) that the run in ``run_dir`` was given.

    Raises:
        DataError: the run has no readable ``config.yaml``, its selection is empty in ``ds``, or its
            ``map.npz`` disagrees with the selection.
    """
    run = Path(run_dir)
    cfg_path = RunFolder(run).config
    if not cfg_path.is_file():
        raise DataError(
            f"{run}: held-out views need the run's config.yaml (its data.start/stride/max_frames say which "
            "frames it mapped)"
        )
    try:
        data = read_config(run).data
    except ConfigError as e:
        raise DataError(f"{cfg_path}: cannot read the run's frame selection ({e})") from None
    # the run's selection of the same folder, read by the same code the mapper used
    sel_cfg = dataclasses.replace(data, path=str(ds.root), segments_dir=None)
    selection = open_dataset(config=sel_cfg)
    n_mapped, how = _mapped_count(run, selection, data)
    position = {rec.rgb_path: i for i, rec in enumerate(ds.records)}
    mapped = sorted(position[r.rgb_path] for r in selection.records[:n_mapped] if r.rgb_path in position)
    if len(mapped) < n_mapped:
        raise DataError(
            f"{ds.root}: {n_mapped - len(mapped)} frames the run mapped are not among the sequence's frames"
        )
    words = f"start {data.start}, stride {data.stride}, " + (
        "all frames" if data.max_frames is None else f"max_frames {data.max_frames}"
    )
    return RunFrames(mapped=mapped, selection=words, num_selected=len(selection), how=how)


@dataclass
class HeldOut:
    """Held-out views and what they are."""

    frames: list[int]
    extrapolated: bool  # some frame lies before the first or after the last mapped frame
    run: RunFrames
    passed_over: int = 0  # held-out frames without a valid pose that the even spread left out


def pick_held_out(ds: Any, run: RunFrames, num_views: int) -> HeldOut:
    """``num_views`` frames spread evenly over the held-out frames between the first and last mapped ones,
    else (none there) over those outside the mapped range, with a valid pose.

    Raises:
        DataError: the run mapped every frame (with a valid pose) of the sequence.
    """
    mapped = set(run.mapped)
    unmapped = [i for i in range(len(ds)) if i not in mapped]
    usable = [i for i in unmapped if ds.has_valid_pose(i)]
    inside = [i for i in usable if run.first < i < run.last]
    pool, extrapolated = (inside, False) if inside else (usable, True)
    if not pool:
        why = (
            f"the {len(unmapped)} frames it did not map have no valid pose"
            if unmapped
            else "it mapped every frame"
        )
        raise DataError(
            f"{ds.root}: no held-out frame to render: the run was given {run.describe()} and {why}; map "
            "every other frame to hold the others out (ogscene3d run ... --set data.stride=2)"
        )
    if extrapolated:
        log.warning(
            "%s: no unmapped frame with a pose lies between the run's first and last mapped frames (%d..%d): "
            "the held-out views are frames outside that range (extrapolation, not views between mapped ones)",
            ds.root,
            run.first,
            run.last,
        )
    frames = [pool[j] for j in pick_frames(len(pool), num_views)]
    return HeldOut(frames=frames, extrapolated=extrapolated, run=run, passed_over=len(unmapped) - len(usable))


def check_held_out(ds: Any, run: RunFrames, frames: Sequence[int]) -> HeldOut:
    """``frames`` given by number as held-out views: refused when the run mapped any of them.

    Raises:
        DataError: naming the frames the run mapped.
    """
    mapped = set(run.mapped)
    bad = sorted({int(i) for i in frames if int(i) in mapped})
    if bad:
        free = [i for i in range(len(ds)) if i not in mapped]
        hint = f"; frames it did not map include {', '.join(map(str, free[:8]))}" if free else ""
        raise DataError(
            f"--held-out: the run mapped view frame{'s' if len(bad) > 1 else ''} {', '.join(map(str, bad))} "
            f"(it was given {run.describe()}){hint}"
        )
    outside = any(not run.first < int(i) < run.last for i in frames)
    return HeldOut(frames=list(frames), extrapolated=outside, run=run)


def naming_frames(ds: Any, run: RunFrames, count: int) -> list[int]:
    """``count`` mapped frames with a valid pose, evenly spread: the renders a 2D overlap naming reads when
    the scored frames are held out (naming from them would look at the very views being scored)."""
    usable = [i for i in run.mapped if ds.has_valid_pose(i)]
    return [usable[j] for j in pick_frames(len(usable), count)]
