"""One writer per run folder: an exclusive lock on ``OUT/.ogscene3d.lock`` from before a run's first write
to its end (docs/runs.md "One writer per run directory")."""

from __future__ import annotations

import contextlib
import datetime
import errno
import json
import logging
import os
import socket
import sys
from collections.abc import Iterator
from pathlib import Path

from ..errors import OGSceneError
from .layout import LOCK

log = logging.getLogger(__name__)


class RunDirBusyError(OGSceneError):
    """Another live process is writing the run directory."""


class RunDirLock:
    """An exclusive ``flock`` on ``OUT/.ogscene3d.lock``, which names its holder (pid, host, command, start).

    The kernel drops the lock when its process ends in any way (kill -9 included), so a lock file left
    by a killed run is taken over, never obeyed. The file is removed on release (under the lock; a
    process that opened the old file finds it unlinked and opens the new one)."""

    def __init__(self, out: str | Path, command: str) -> None:
        self.out = Path(out)
        self.path = self.out / LOCK
        self.command = command
        self._fd: int | None = None

    def acquire(self) -> None:
        try:
            import fcntl
        except ImportError:  # not a POSIX system
            log.warning("%s: no file locks here: a second run writing there is not detected", self.out)
            return
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                os.close(fd)
                if e.errno in (errno.ENOLCK, errno.ENOTSUP, errno.EOPNOTSUPP):
                    # a filesystem without locks (some network mounts): the run goes on unguarded
                    log.warning(
                        "%s: the filesystem refuses file locks (%s): a second run writing there is not "
                        "detected",
                        self.out,
                        e.strerror,
                    )
                    with contextlib.suppress(OSError):
                        self.path.unlink()
                    return
                if e.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                    raise
                raise RunDirBusyError(self._busy_message()) from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)  # the holder released (and removed) the file meanwhile: lock the new one
        holder = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv else self.command,
            "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "run": self.command,
        }
        os.ftruncate(fd, 0)
        os.write(fd, (json.dumps(holder) + "\n").encode())
        self._fd = fd

    def _busy_message(self) -> str:
        try:
            holder = json.loads(self.path.read_text() or "{}")
        except (OSError, ValueError):
            holder = {}
        get = holder.get
        who = (
            f"pid {get('pid', '?')} on {get('host', '?')}, started {get('started', '?')}: "
            f"{get('command', '?')}"
            if holder
            else "a process that has not named itself yet"
        )
        return (
            f"{self.out} is being written by another run ({who}); two runs in one folder overwrite each "
            "other's map: wait for that run to end (or stop it), or give another --out"
        )

    def release(self) -> None:
        if self._fd is None:
            return
        with contextlib.suppress(OSError):
            self.path.unlink()
        os.close(self._fd)  # closing drops the flock
        self._fd = None

    def __enter__(self) -> RunDirLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


@contextlib.contextmanager
def run_directory(out: str | Path, command: str) -> Iterator[Path]:
    """Create ``out`` if needed and hold its :class:`RunDirLock` for the block. A folder created here and
    still empty at the end (a run refused before writing anything: no dataset, a bad option) is removed."""
    out = Path(out)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    lock = RunDirLock(out, command)
    try:
        lock.acquire()
    except BaseException:
        if created:
            with contextlib.suppress(OSError):
                out.rmdir()
        raise
    try:
        yield out
    finally:
        lock.release()
        if created:
            with contextlib.suppress(OSError):  # not empty: the run wrote something, which stays
                out.rmdir()


__all__ = ["RunDirBusyError", "RunDirLock", "run_directory"]
