"""Atomic writes: the final file gets the mode a plain open() gives (not mkstemp's 0600), nothing is left
behind, and a failed write keeps the old file."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from ogscene3d import atomic
from ogscene3d.atomic import atomic_path, atomic_write_bytes, atomic_write_text, current_umask


@pytest.fixture
def umask():
    """Set the process umask for one test, restoring it afterwards."""
    saved = os.umask(0o022)
    os.umask(saved)

    def set_mask(mask: int) -> None:
        os.umask(mask)

    yield set_mask
    os.umask(saved)


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_new_file_mode_follows_umask(tmp_path, umask, mask):
    umask(mask)
    assert current_umask() == mask
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    out = tmp_path / "sub" / "metrics.json"
    atomic_write_text(out, "{}")
    assert out.read_text() == "{}"
    assert _mode(out) == 0o666 & ~mask == _mode(plain)
    assert sorted(p.name for p in out.parent.iterdir()) == ["metrics.json"]  # no temporary file left


def test_umask_without_proc(tmp_path, umask, monkeypatch):
    """Where /proc does not report it, the umask is read by setting it (and put back)."""
    monkeypatch.setattr(atomic, "_PROC_STATUS", tmp_path / "no-such-file")
    umask(0o027)
    assert current_umask() == 0o027
    assert current_umask() == 0o027  # restored by the first read
    atomic_write_bytes(tmp_path / "a.bin", b"1")
    assert _mode(tmp_path / "a.bin") == 0o640


def test_replacing_keeps_the_existing_mode(tmp_path, umask):
    umask(0o022)
    out = tmp_path / "map.npz"
    out.write_bytes(b"old")
    out.chmod(0o664)  # e.g. a group-writable shared output
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as f:  # how GaussianMap.save_npz writes
            f.write(b"new")
    assert out.read_bytes() == b"new" and _mode(out) == 0o664


def test_failed_write_keeps_the_old_file(tmp_path):
    out = tmp_path / "traj.txt"
    out.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(out) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash mid-write")
    assert out.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["traj.txt"]
