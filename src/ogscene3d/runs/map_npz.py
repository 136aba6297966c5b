"""``map.npz``: the one reader and writer of the checkpoint file as a container of named arrays.

What the arrays mean is their owners' (docs/formats.md "map.npz and map_memory/"): the Gaussians are
``GaussianMap.state_dict``'s, the mapper's state ``mapping/checkpoint.py``'s, the memory view lists
``mapping/memory_files.py``'s (the views themselves are files of ``map_memory/``). Here the file is
written atomically and read back with one error for every kind of damage (a save cut short by a full disk
or a kill, a broken copy), and a missing file is said to be missing.
"""

from __future__ import annotations

import zipfile
import zlib
from collections.abc import Callable, Collection
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import DataError

#: The format of map.npz. 2: a mapper checkpoint holds every mapper array (``mapping/checkpoint.py``);
#: 1: older files, which may lack those added over its life (upgraded on load).
NPZ_VERSION = 2

#: What np.load raises on a damaged or truncated npz file (a checkpoint cut short by a full disk or a kill).
NPZ_READ_ERRORS: tuple[type[Exception], ...] = (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error)


class CorruptMapError(DataError):
    """map.npz is there but cannot be read (damaged or truncated)."""


def corrupt_npz_message(path: Path, error: Exception) -> str:
    """The error for an npz file np.load cannot read (truncated by a full disk, damaged in a copy)."""
    # np.load calls any non-zip file "pickled (object) data" and suggests unpickling it: never for a map
    return (
        f"{path}: not a readable map npz, corrupt or truncated ({type(error).__name__}); restore a copy or "
        "start a new run"
    )


def pop_npz_version(arrays: dict[str, np.ndarray], path: str | Path, what: str, to: str) -> int:
    """Take the file format's number out of the arrays :func:`read_map_npz` read from ``path``.

    Args:
        arrays: the arrays read, ``version`` among them where the file holds one (removed here).
        path: the file, for the messages.
        what: what its owner reads it as ("map", "checkpoint"), for the messages.
        to: what a newer ogscene3d is needed to do ("read it", "resume it").

    Returns:
        The format's number: 1 for files written before it was recorded.

    Raises:
        DataError: it is not a number (a damaged file), or newer than :data:`NPZ_VERSION`.
    """
    try:
        version = int(arrays.pop("version", 1))
    except (TypeError, ValueError) as e:
        raise DataError(corrupt_npz_message(Path(path), e)) from e
    if version > NPZ_VERSION:
        raise DataError(
            f"{path}: written by a newer ogscene3d ({what} format {version}; this one reads up to "
            f"{NPZ_VERSION}): update ogscene3d to {to}"
        )
    return version


def write_map_npz(path: str | Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` (uncompressed) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)


def read_map_npz(
    path: str | Path, keep: Collection[str] | Callable[[str], bool] | None = None
) -> dict[str, np.ndarray]:
    """The arrays of ``path`` that ``keep`` names (a collection of names, or a test of a name; None: all).
    A name the file lacks is simply absent from the result: its owner decides what that means.

    Raises:
        DataError: the file does not exist; :class:`CorruptMapError` (a DataError): it is damaged or
            truncated (:func:`corrupt_npz_message`).
    """
    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: map file does not exist")
    wanted: Callable[[str], bool]
    if keep is None:
        wanted = lambda name: True  # noqa: E731
    elif callable(keep):
        wanted = keep
    else:
        wanted = set(keep).__contains__
    try:
        with np.load(p, allow_pickle=False) as z:
            return {k: z[k] for k in z.files if wanted(k)}
    except NPZ_READ_ERRORS as e:
        raise CorruptMapError(corrupt_npz_message(p, e)) from e


__all__ = [
    "CorruptMapError",
    "NPZ_READ_ERRORS",
    "NPZ_VERSION",
    "corrupt_npz_message",
    "pop_npz_version",
    "read_map_npz",
    "write_map_npz",
]
