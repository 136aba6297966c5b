"""Atomic file writes: a crash mid-write never leaves a half-written map, checkpoint or output."""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

_UMASK_LOCK = threading.Lock()
_PROC_STATUS = Path("/proc/self/status")  # Linux >= 4.7 reports the umask here


def current_umask() -> int:
    """The process umask, read without leaving a window in which other threads create open files.

    Linux reports it in ``/proc/self/status``; elsewhere it can only be read by setting it, so it is
    set to the most restrictive mask for that instant (a file another thread creates meanwhile comes
    out private, never world-writable) and restored at once, under a lock against concurrent readers.
    """
    with contextlib.suppress(OSError, ValueError):
        for line in _PROC_STATUS.read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    with _UMASK_LOCK:
        mask = os.umask(0o077)
        os.umask(mask)
    return mask


def _final_mode(path: Path) -> int:
    """The permission bits a plain ``open(path, "w")`` would leave: those of the file it replaces, or
    0o666 less the umask for a new file (``mkstemp`` creates 0o600, which hides outputs from other users)."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        return 0o666 & ~current_umask()


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` in one rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix or ".tmp")
    os.close(fd)
    try:
        yield Path(tmp)
        # Some filesystems (e.g. SMB mounts) refuse chmod: the output is still written, if less readable.
        with contextlib.suppress(OSError):
            os.chmod(tmp, _final_mode(path))
        # on disk before the rename, or a power loss can leave the new name on an empty file
        _fsync(tmp)
        os.replace(tmp, path)
        with contextlib.suppress(OSError):  # the rename itself (not every platform opens directories)
            _fsync(path.parent)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _fsync(path: str | Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def remove_stale_temps(path: str | Path) -> list[Path]:
    """Delete the temporary files that writes of ``path`` left behind when their process was killed
    (``.<stem>.<random><suffix>`` beside it; a checkpoint's can be hundreds of MB). -> the removed ones.
    Call only when nothing else is writing ``path``."""
    path = Path(path)
    removed = []
    for tmp in path.parent.glob(f".{path.stem}.*{path.suffix or '.tmp'}"):
        with contextlib.suppress(OSError):
            tmp.unlink()
            removed.append(tmp)
    return removed


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())
