"""The long-term memory's views on disk: one file per view, written once, beside the checkpoint.

A checkpoint ``RUN/map.npz`` keeps its memory views in ``RUN/map_memory/view_<keyframe>_<crc32>.npz``
(``rgb``, ``depth``, ``keyframe`` and, when the view has them, ``segments``); ``map.npz`` lists the files
it needs, relative to its own directory, with each file's size and CRC-32 (docs/formats.md). A view
never changes once in the memory, so a checkpoint writes only the views the previous one did not have,
instead of every view again (hundreds of MB with 64 views at 1200x680). The optimisation's recent keyframes
(``mapping.optimize.memory_frames``) that are not in the memory are kept the same way, listed apart
(``recent_*``): without them a resume would pair its first keyframes with other views than an uninterrupted
run does (and draw other random numbers from then on).

Crash safety comes from the order of the writes: every view file is on disk (atomic, fsynced) before the
``map.npz`` that names it, and the files of evicted views are removed only once the new ``map.npz`` is in
place. A killed save leaves unreferenced files behind; the next save, or the next run
(``remove_leftovers``), removes them. The CRC in the name keeps two runs' views of one keyframe apart, so a
new run in an old directory never overwrites a file that the old checkpoint still names.
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import re
import zlib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from ..atomic import atomic_write_bytes
from ..errors import DataError
from ..runs.map_npz import NPZ_READ_ERRORS, CorruptMapError, read_map_npz
from .longterm import MemoryEntry

log = logging.getLogger(__name__)

# the lists of view files in map.npz: the memory's, and the recent keyframes' outside it (``manifest``)
VIEW_LISTS = ("mem", "recent")
VIEW_NAME = re.compile(r"view_\d+_[0-9a-f]{8}\.npz")
# what atomic_path leaves behind when a write of a view file is killed
VIEW_TEMP = re.compile(r"\.view_\d+_[0-9a-f]{8}\..+\.npz")


@dataclass(frozen=True)
class ViewFile:
    """Where one memory view is stored: ``name`` relative to the checkpoint's directory (POSIX), and the
    file's size and CRC-32, which tell a wrong or truncated file."""

    name: str
    nbytes: int
    crc32: int


@dataclass(frozen=True)
class ViewRecord:
    """One memory view as ``map.npz`` lists it: everything but the images, and the file holding those."""

    keyframe: int
    K: np.ndarray
    pose: np.ndarray
    scores: dict[int, float]
    shape: tuple[int, int]
    file: ViewFile


def views_dir(checkpoint: Path) -> Path:
    """The folder of ``checkpoint``'s views: ``map.npz`` -> ``map_memory`` beside it (one per checkpoint
    name, so that two checkpoints in one folder never remove each other's views)."""
    return checkpoint.with_name(f"{checkpoint.stem}_memory")


def _folder_key(checkpoint: Path, folder: str) -> str:
    """The absolute path of ``checkpoint``'s sibling ``folder``: the key of ``MemoryEntry.saved``."""
    return str(checkpoint.parent.resolve() / folder)


def store_view(checkpoint: Path, entry: MemoryEntry) -> ViewFile:
    """The file of ``entry`` for ``checkpoint``: the one written before when it is still there, else a
    new one (atomic and fsynced, so it is whole on disk before any ``map.npz`` names it)."""
    folder = _folder_key(checkpoint, views_dir(checkpoint).name)
    known = entry.saved.get(folder)
    if known is not None:
        with contextlib.suppress(OSError):
            if (checkpoint.parent / known.name).stat().st_size == known.nbytes:
                return known
    arrays = {"keyframe": np.array(entry.keyframe), "rgb": entry.rgb, "depth": entry.depth}
    if entry.segments is not None:
        arrays["segments"] = entry.segments
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    data = buf.getvalue()
    crc = zlib.crc32(data)
    ref = ViewFile(f"{views_dir(checkpoint).name}/view_{entry.keyframe:06d}_{crc:08x}.npz", len(data), crc)
    atomic_write_bytes(checkpoint.parent / ref.name, data)
    entry.saved[folder] = ref
    return ref


def manifest(entries: list[MemoryEntry], files: list[ViewFile], prefix: str = "mem") -> dict[str, np.ndarray]:
    """The arrays ``map.npz`` lists views with (none for no views): the memory's under ``mem_``, the
    optimisation's recent keyframes that are not in the memory under ``recent_``. ``mem_keyframe`` and
    ``mem_pose`` are what the viewer draws the camera path from."""
    if not entries:
        return {}
    return {
        f"{prefix}_keyframe": np.array([e.keyframe for e in entries], dtype=np.int64),
        f"{prefix}_K": np.stack([e.K for e in entries]),
        f"{prefix}_pose": np.stack([e.pose for e in entries]),
        f"{prefix}_scores": np.array(json.dumps([{str(k): v for k, v in e.scores.items()} for e in entries])),
        f"{prefix}_shape": np.array([e.depth.shape for e in entries], dtype=np.int64),
        f"{prefix}_file": np.array([f.name for f in files]),
        f"{prefix}_bytes": np.array([f.nbytes for f in files], dtype=np.int64),
        f"{prefix}_crc32": np.array([f.crc32 for f in files], dtype=np.int64),
    }


def _check_name(checkpoint: Path, name: str) -> None:
    parts = PurePosixPath(name).parts
    if len(parts) != 2 or parts[0] in (".", "..") or not VIEW_NAME.fullmatch(parts[1]):
        raise DataError(
            f"{checkpoint}: memory view file {name!r} is not a view file in a folder beside it "
            "(map.npz names view files relative to its own folder)"
        )


def read_manifest(z, checkpoint: Path, prefix: str = "mem") -> list[ViewRecord]:
    """The views listed under ``prefix`` (``manifest``) by an opened ``map.npz`` ``z``: none when it has no
    such list (raises KeyError for a missing array of one)."""
    if f"{prefix}_file" not in z:
        return []
    names = [str(n) for n in z[f"{prefix}_file"]]
    keyframes, nbytes, crcs = z[f"{prefix}_keyframe"], z[f"{prefix}_bytes"], z[f"{prefix}_crc32"]
    Ks, poses, shapes = z[f"{prefix}_K"], z[f"{prefix}_pose"], z[f"{prefix}_shape"]
    scores = json.loads(str(z[f"{prefix}_scores"]))
    if len({len(a) for a in (names, keyframes, nbytes, crcs, Ks, poses, shapes, scores)}) != 1:
        raise DataError(f"{checkpoint}: its lists of views ({prefix}_*) differ in length")
    out = []
    for i, name in enumerate(names):
        _check_name(checkpoint, name)
        out.append(
            ViewRecord(
                int(keyframes[i]),
                Ks[i].copy(),
                poses[i].copy(),
                {int(k): float(v) for k, v in scores[i].items()},
                (int(shapes[i][0]), int(shapes[i][1])),
                ViewFile(name, int(nbytes[i]), int(crcs[i])),
            )
        )
    return out


def load_view(checkpoint: Path, record: ViewRecord) -> MemoryEntry:
    """The memory entry of ``record``, its file read once and checked (size, CRC-32, keyframe, shapes);
    a missing or damaged file is a DataError naming it."""
    ref = record.file
    path = checkpoint.parent / ref.name
    what = f"{path}: memory view of keyframe {record.keyframe} that {checkpoint.name} needs"
    advice = "restore a copy of the whole run directory, or start a new run"
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise DataError(f"{what} does not exist; {advice}") from None
    except OSError as e:
        raise DataError(f"{what} is unreadable ({e.strerror or type(e).__name__}); {advice}") from e
    if len(data) != ref.nbytes or zlib.crc32(data) != ref.crc32:
        raise DataError(
            f"{what} is damaged or another file ({len(data)} bytes, CRC-32 {zlib.crc32(data):08x}; expected "
            f"{ref.nbytes} bytes, {ref.crc32:08x}); {advice}"
        )
    h, w = record.shape
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except NPZ_READ_ERRORS as e:
        raise DataError(f"{what} is not a readable npz ({type(e).__name__}); {advice}") from e
    segments = arrays.get("segments")
    ok = (
        "keyframe" in arrays
        and int(arrays["keyframe"]) == record.keyframe
        and arrays.get("rgb", np.empty(0)).shape == (h, w, 3)
        and arrays.get("depth", np.empty(0)).shape == (h, w)
        and (segments is None or segments.shape == (h, w))
    )
    if not ok:
        raise DataError(f"{what} does not hold keyframe {record.keyframe}'s {w}x{h} view; {advice}")
    entry = MemoryEntry(
        record.keyframe, arrays["rgb"], arrays["depth"], record.K, record.pose, segments, record.scores
    )
    entry.saved[_folder_key(checkpoint, PurePosixPath(ref.name).parent.name)] = ref
    return entry


def _remove(folder: Path, unwanted) -> list[Path]:
    removed = []
    for f in folder.iterdir() if folder.is_dir() else []:
        if unwanted(f.name):
            with contextlib.suppress(OSError):
                f.unlink()
                removed.append(f)
    return removed


def remove_unreferenced(checkpoint: Path, keep: list[ViewFile]) -> list[Path]:
    """Delete the view files in ``checkpoint``'s folder of views that are not in ``keep`` (evicted views,
    a killed save's files), and killed writes' temporaries. Call only once the checkpoint naming ``keep`` is
    in place, and while nothing else writes it. -> the removed files."""
    folder = views_dir(checkpoint)
    kept = {PurePosixPath(f.name).name for f in keep if PurePosixPath(f.name).parent.name == folder.name}

    def unwanted(name: str) -> bool:
        return bool((VIEW_NAME.fullmatch(name) and name not in kept) or VIEW_TEMP.fullmatch(name))

    return _remove(folder, unwanted)


def remove_leftovers(checkpoint: Path) -> list[Path]:
    """At the start of a run: remove the view files that ``checkpoint`` (a ``map.npz`` as it is on disk,
    or none) does not name, and killed writes' temporaries. An unreadable checkpoint keeps its views (they
    may be what a repaired copy of it needs): only the temporaries go."""
    keep: list[ViewFile] = []
    if checkpoint.is_file():
        try:
            lists = read_map_npz(checkpoint, lambda k: k.startswith(tuple(f"{p}_" for p in VIEW_LISTS)))
            keep = [r.file for prefix in VIEW_LISTS for r in read_manifest(lists, checkpoint, prefix)]
        except (KeyError, CorruptMapError, *NPZ_READ_ERRORS) as e:
            cause = type(e.__cause__ or e).__name__
            log.warning("%s: unreadable (%s), its memory views are left alone", checkpoint, cause)
            return _remove(views_dir(checkpoint), lambda name: bool(VIEW_TEMP.fullmatch(name)))
    return remove_unreferenced(checkpoint, keep)
