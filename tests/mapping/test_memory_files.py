"""Checkpoints keep each memory view in its own file, written once: what a checkpoint writes, what a kill at
any point leaves loadable, the errors for missing or damaged view files, and old inline checkpoints."""

import json
import shutil

import numpy as np
import pytest
import torch

from ogscene3d.config import load_config
from ogscene3d.errors import DataError
from ogscene3d.gaussians import GaussianMap
from ogscene3d.mapping import checkpoint as checkpoint_module
from ogscene3d.mapping.longterm import MemoryEntry
from ogscene3d.mapping.mapper import Mapper
from ogscene3d.mapping.memory_files import views_dir
from ogscene3d.mapping.source import remove_run_temps

W, H = 32, 24
K = np.array([[24.0, 0, W / 2], [0, 24.0, H / 2], [0, 0, 1]], dtype=np.float32)


def _mapper(memory_max: int = 3) -> Mapper:
    m = Mapper(load_config(None, ["graph.enabled=false", f"mapping.longterm.memory_max={memory_max}"]), "cpu")
    m.map.append(
        torch.rand(50, 3), torch.rand(50, 3), torch.full((50,), -3.0), torch.zeros(50, dtype=torch.int32)
    )
    m.keyframe_count = m.frames_seen = m.next_index = 1
    return m


def _add_view(m: Mapper, keyframe: int, segments: str | None = "int32") -> MemoryEntry:
    """A memory view of random content (a new keyframe joins, the oldest goes when the memory is full)."""
    rng = np.random.default_rng(keyframe)
    pose = np.eye(4)
    pose[:3, 3] = rng.normal(size=3)
    seg = None if segments is None else rng.integers(0, 5, (H, W)).astype(segments)
    entry = MemoryEntry(
        keyframe,
        rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
        rng.uniform(1.0, 3.0, (H, W)).astype(np.float32),
        K.copy(),
        pose,
        seg,
        {1: 0.93, 4: 0.5 + keyframe / 100},
    )
    m.memory.restore(entry, m.device)
    m.keyframe_count = keyframe + 1
    return entry


def _files(run) -> dict[str, int]:
    """{view file name: inode} of the run's memory folder."""
    return {p.name: p.stat().st_ino for p in views_dir(run / "map.npz").iterdir()}


def _snapshot(m: Mapper) -> list[tuple]:
    return [
        (e.keyframe, e.rgb.copy(), e.depth.copy(), e.K.copy(), e.pose.copy(), e.segments, dict(e.scores))
        for e in m.memory.entries
    ]


def _assert_memory(m: Mapper, expected: list[tuple]) -> None:
    assert [e.keyframe for e in m.memory.entries] == [x[0] for x in expected]
    for e, (kf, rgb, depth, K_, pose, seg, scores) in zip(m.memory.entries, expected, strict=True):
        for got, want in ((e.rgb, rgb), (e.depth, depth), (e.K, K_), (e.pose, pose)):
            assert got.dtype == want.dtype and np.array_equal(got, want), kf
        if seg is None:
            assert e.segments is None
        else:
            assert e.segments.dtype == seg.dtype and np.array_equal(e.segments, seg)
        assert e.scores == scores


def _loaded(path, memory_max: int = 3) -> Mapper:
    r = _mapper(memory_max)
    r.load_checkpoint(path)
    return r


def test_a_checkpoint_writes_only_the_new_views_and_removes_the_evicted_ones(tmp_path):
    m = _mapper()
    for kf in range(3):
        _add_view(m, kf)
    m.save_checkpoint(tmp_path / "map.npz")
    first = _files(tmp_path)
    assert sorted(n.split("_")[1] for n in first) == ["000000", "000001", "000002"]
    with np.load(tmp_path / "map.npz") as z:
        assert "mem_rgb" not in z.files and "mem_depth" not in z.files  # the images are not in map.npz
        # relative to map.npz's folder: a copied run directory still finds them
        assert all(n.startswith("map_memory/view_") for n in z["mem_file"].tolist())
        assert z["mem_pose"].shape == (3, 4, 4) and z["mem_keyframe"].tolist() == [0, 1, 2]  # the viewer's
    _add_view(m, 3)  # evicts keyframe 0
    m.save_checkpoint(tmp_path / "map.npz")
    second = _files(tmp_path)
    assert sorted(n.split("_")[1] for n in second) == ["000001", "000002", "000003"]
    kept = set(first) & set(second)
    assert len(kept) == 2 and all(first[n] == second[n] for n in kept)  # not written again
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.npz", "map_memory"]  # no temporaries left


def test_a_resume_restores_the_memory_exactly(tmp_path):
    m = _mapper(memory_max=4)
    _add_view(m, 0)
    _add_view(m, 1, segments=None)  # a view without segments stays one (not zeros)
    _add_view(m, 2, segments="uint16")  # segment PNGs load as uint16
    m.memory._cursor = 2
    before = _snapshot(m)
    m.save_checkpoint(tmp_path / "map.npz")
    r = _loaded(tmp_path / "map.npz", memory_max=4)
    _assert_memory(r, before)
    assert r.memory._cursor == 2
    for a, b in zip(r.memory.entries, m.memory.entries, strict=True):
        assert torch.equal(a.points, b.points)
    torch.testing.assert_close(r.map.means, m.map.means)


def test_a_copied_run_directory_resumes_and_its_views_are_not_written_again(tmp_path):
    m = _mapper()
    for kf in range(3):
        _add_view(m, kf)
    before = _snapshot(m)
    m.save_checkpoint(tmp_path / "a" / "map.npz")
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    shutil.rmtree(tmp_path / "a")
    r = _loaded(tmp_path / "b" / "map.npz")
    _assert_memory(r, before)
    files = _files(tmp_path / "b")
    r.save_checkpoint(tmp_path / "b" / "map.npz")
    assert _files(tmp_path / "b") == files
    r.save_checkpoint(tmp_path / "c" / "map.npz")  # another folder gets its own copies
    assert sorted(_files(tmp_path / "c")) == sorted(files)


def test_killed_before_map_npz_the_previous_checkpoint_loads(tmp_path, monkeypatch):
    m = _mapper()
    for kf in range(3):
        _add_view(m, kf)
    ckpt = tmp_path / "map.npz"
    m.save_checkpoint(ckpt)
    before = _snapshot(m)
    _add_view(m, 3)  # evicts keyframe 0, which the checkpoint on disk still names

    def killed(self, path, extra=None):
        raise KeyboardInterrupt  # killed once the new view is written, before map.npz is

    monkeypatch.setattr(GaussianMap, "save_npz", killed)
    with pytest.raises(KeyboardInterrupt):
        m.save_checkpoint(ckpt)
    monkeypatch.undo()
    assert any(n.startswith("view_000003_") for n in _files(tmp_path))  # written, not yet named
    _assert_memory(_loaded(ckpt), before)
    # a killed view write's temporary file too; the next run removes both, and keeps what map.npz names
    (views_dir(ckpt) / ".view_000004_0badf00d.k3wvhg1h.npz").write_bytes(b"x" * 100)
    remove_run_temps(tmp_path)
    assert sorted(n.split("_")[1] for n in _files(tmp_path)) == ["000000", "000001", "000002"]
    _assert_memory(_loaded(ckpt), before)


def test_killed_after_map_npz_the_new_checkpoint_loads_and_the_next_save_cleans_up(tmp_path, monkeypatch):
    m = _mapper()
    for kf in range(3):
        _add_view(m, kf)
    ckpt = tmp_path / "map.npz"
    m.save_checkpoint(ckpt)
    _add_view(m, 3)
    after = _snapshot(m)

    def killed(checkpoint, keep):
        raise KeyboardInterrupt  # killed once the new map.npz is in place, before the evicted view goes

    monkeypatch.setattr(checkpoint_module, "remove_unreferenced", killed)
    with pytest.raises(KeyboardInterrupt):
        m.save_checkpoint(ckpt)
    monkeypatch.undo()
    assert len(_files(tmp_path)) == 4  # keyframe 0's file is left over
    r = _loaded(ckpt)
    _assert_memory(r, after)
    r.save_checkpoint(ckpt)
    assert sorted(n.split("_")[1] for n in _files(tmp_path)) == ["000001", "000002", "000003"]


def test_a_missing_or_damaged_view_file_is_a_clean_error(tmp_path):
    m = _mapper()
    for kf in range(3):
        _add_view(m, kf)
    ckpt = tmp_path / "map.npz"
    m.save_checkpoint(ckpt)
    files = sorted(views_dir(ckpt).iterdir())
    good = files[1].read_bytes()
    files[1].unlink()
    with pytest.raises(DataError, match=f"{files[1].name}: memory view of keyframe 1 .* does not exist"):
        _loaded(ckpt)
    files[1].write_bytes(good[: len(good) // 2])  # truncated
    with pytest.raises(DataError, match=f"{files[1].name}: .* is damaged or another file"):
        _loaded(ckpt)
    shutil.copyfile(files[2], files[1])  # whole, but another view's
    with pytest.raises(DataError, match=f"{files[1].name}: .* is damaged or another file"):
        _loaded(ckpt)
    files[1].write_bytes(good)
    assert len(_loaded(ckpt).memory) == 3


def test_map_npz_names_only_view_files_beside_it(tmp_path):
    m = _mapper()
    _add_view(m, 0)
    ckpt = tmp_path / "run" / "map.npz"
    m.save_checkpoint(ckpt)
    with np.load(ckpt) as z:
        arrays = dict(z)
    name = str(arrays["mem_file"][0])
    for bad in (f"../elsewhere/{name.split('/')[1]}", f"/abs/{name}", "map_memory/notes.txt"):
        arrays["mem_file"] = np.array([bad])
        np.savez(ckpt, **arrays)
        with pytest.raises(DataError, match="is not a view file in a folder beside it"):
            _loaded(ckpt)


def test_a_smaller_memory_max_reads_only_the_newest_views(tmp_path):
    m = _mapper()
    for kf in range(3):
        _add_view(m, kf)
    ckpt = tmp_path / "map.npz"
    m.save_checkpoint(ckpt)
    newest = _snapshot(m)[1:]
    oldest = next(p for p in views_dir(ckpt).iterdir() if p.name.startswith("view_000000_"))
    oldest.unlink()  # never read: the resumed memory holds 2 views
    r = _loaded(ckpt, memory_max=2)
    _assert_memory(r, newest)
    r.save_checkpoint(ckpt)
    assert sorted(n.split("_")[1] for n in _files(tmp_path)) == ["000001", "000002"]


def _legacy_checkpoint(m: Mapper, path) -> None:
    """map.npz as checkpoints were written before the views had their own files: every view inline."""
    mem = m.memory.entries
    inline = {
        "mem_keyframe": np.array([e.keyframe for e in mem]),
        "mem_rgb": np.stack([e.rgb for e in mem]),
        "mem_depth": np.stack([e.depth for e in mem]),
        "mem_K": np.stack([e.K for e in mem]),
        "mem_pose": np.stack([e.pose for e in mem]),
        "mem_segments": np.stack(
            [e.segments if e.segments is not None else np.zeros(e.depth.shape, np.int32) for e in mem]
        ),
        "mem_scores": np.array(json.dumps([{str(k): v for k, v in e.scores.items()} for e in mem])),
    }
    state = m.state()
    del state["mapper_recent"]  # not written then either
    arrays = {**m.map.state_dict(), **state, **inline, "version": np.array(1)}  # the format then
    np.savez(path, **arrays)


def test_an_old_checkpoint_with_inline_views_loads_and_is_saved_in_files(tmp_path):
    m = _mapper()
    for kf in range(3):
        _add_view(m, kf)
    m.memory._cursor = 1
    ckpt = tmp_path / "map.npz"
    _legacy_checkpoint(m, ckpt)
    before = _snapshot(m)
    remove_run_temps(tmp_path)  # the start of a resumed run
    r = _loaded(ckpt)
    _assert_memory(r, before)
    assert r.memory._cursor == 1
    r.save_checkpoint(ckpt)
    with np.load(ckpt) as z:
        assert "mem_rgb" not in z.files and len(z["mem_file"]) == 3
    _assert_memory(_loaded(ckpt), before)


def test_an_unreadable_checkpoint_keeps_its_views_at_the_next_run(tmp_path):
    m = _mapper()
    _add_view(m, 0)
    ckpt = tmp_path / "map.npz"
    m.save_checkpoint(ckpt)
    files = _files(tmp_path)
    data = ckpt.read_bytes()
    ckpt.write_bytes(data[: len(data) // 2])
    temp = views_dir(ckpt) / ".view_000001_0badf00d.abc.npz"
    temp.write_bytes(b"x")
    remove_run_temps(tmp_path)
    assert _files(tmp_path) == files  # the temporary went, the view a repaired map.npz needs stayed


def _wall_frame(i: int):
    """Frame i of a camera moving 0.1 m per frame along a two-segment wall 2 m ahead."""
    from ogscene3d.frame import Frame

    pose = np.eye(4)
    pose[0, 3] = 0.1 * i
    seg = np.full((H, W), 2, np.int32)
    seg[:, : W // 2] = 1
    rng = np.random.default_rng(i)
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    depth = np.full((H, W), 2.0, np.float32)
    return Frame(i, rgb, depth, K, pose, name=f"f{i}", segments=seg, segment_scores={1: 0.97, 2: 0.97})


def test_a_resume_optimizes_with_the_same_recent_keyframes_as_an_uninterrupted_run(tmp_path):
    """The keyframes the optimisation pairs with the next one (mapping.optimize.memory_frames) are in the
    checkpoint too, also those that never joined the memory: a resume maps exactly as if uninterrupted."""
    settings = ["graph.enabled=false", "mapping.optimize.iters=2", "mapping.optimize.memory_frames=2"]
    cfg = load_config(None, [*settings, "mapping.ablation=local"])

    def run(split: int | None) -> Mapper:
        m = Mapper(cfg, "cpu")
        for i in range(6):
            m.process(_wall_frame(i))
            if i == split:
                m.save_checkpoint(tmp_path / "map.npz")
                m = Mapper(cfg, "cpu")
                m.load_checkpoint(tmp_path / "map.npz")
        return m

    whole, resumed = run(None), run(3)
    at_split = Mapper(cfg, "cpu")
    at_split.load_checkpoint(tmp_path / "map.npz")
    # the wall's later views overlap the first: only keyframe 0 is in the memory, keyframes 2 and 3 are not
    assert [e.keyframe for e in at_split.memory.entries] == [0]
    assert [e.keyframe for e in at_split.recent] == [2, 3]
    assert torch.equal(whole.map.means, resumed.map.means)
    assert torch.equal(whole.map.confidences, resumed.map.confidences)
    # their files stay through the next run's clean-up; a smaller opt_memory_frames keeps the newest
    with np.load(tmp_path / "map.npz") as z:
        assert z["recent_keyframe"].tolist() == [2, 3] and z["mapper_recent"].tolist() == [2, 3]
    names = sorted(_files(tmp_path))
    assert [n.split("_")[1] for n in names] == ["000000", "000002", "000003"]
    remove_run_temps(tmp_path)
    assert sorted(_files(tmp_path)) == names
    fewer = Mapper(load_config(None, [*settings, "mapping.optimize.memory_frames=1"]), "cpu")
    fewer.load_checkpoint(tmp_path / "map.npz")
    assert [e.keyframe for e in fewer.recent] == [3]
