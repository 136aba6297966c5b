"""map.npz's format version is read, and one upgrade gives a version-1 checkpoint's missing arrays their
old meaning (mapping/checkpoint.py)."""

import numpy as np
import pytest
from mapping_scenes import _config, _frame

from ogscene3d.errors import DataError
from ogscene3d.mapping.checkpoint import REQUIRED, read_checkpoint
from ogscene3d.mapping.mapper import Mapper
from ogscene3d.runs.map_npz import NPZ_VERSION


def _mapped(tmp_path, frames: int = 2) -> tuple[Mapper, dict]:
    m = Mapper(_config(), "cpu")
    for i in range(frames):
        m.process(_frame(i))
    m.save_checkpoint(tmp_path / "map.npz")
    with np.load(tmp_path / "map.npz") as z:
        return m, {k: z[k] for k in z.files}


def test_a_checkpoint_holds_its_parts_states_and_todays_version(tmp_path):
    m, arrays = _mapped(tmp_path)
    assert int(arrays["version"]) == NPZ_VERSION == 2
    assert set(REQUIRED) <= set(arrays)
    state = read_checkpoint(tmp_path / "map.npz")
    assert "version" not in state and "means" not in state  # the Gaussians are GaussianMap.load_npz's
    assert int(state["kf_since_last"]) == m.keyframes.state()["kf_since_last"]


def test_a_newer_checkpoint_is_refused_and_a_damaged_one_named(tmp_path):
    _, arrays = _mapped(tmp_path)
    path = tmp_path / "map.npz"
    np.savez(path, **{**arrays, "version": np.array(NPZ_VERSION + 1)})
    with pytest.raises(DataError, match="written by a newer ogscene3d"):
        Mapper(_config(), "cpu").load_checkpoint(path)
    del arrays["mapper_rng"]
    np.savez(path, **arrays)  # today's version lacks nothing: a missing array is damage, not age
    with pytest.raises(DataError, match="not a mapper checkpoint \\(missing 'mapper_rng'\\)"):
        Mapper(_config(), "cpu").load_checkpoint(path)


def test_a_version_1_checkpoint_lacking_what_was_added_since_resumes(tmp_path):
    m, arrays = _mapped(tmp_path, frames=3)
    legacy = ("mapper_next_index", "mapper_finalized", "mapper_source", "mapper_timings", "mapper_rng",
              "mapper_trajectory", "mapper_memory_cursor", "mapper_recent", "posecheck_last_pose",
              "posecheck_last_index")  # fmt: skip
    for key in legacy:
        del arrays[key]
    path = tmp_path / "map.npz"
    np.savez(path, **{**arrays, "version": np.array(1)})
    r = Mapper(_config(), "cpu")
    r.load_checkpoint(path)
    assert r.next_index == r.frames_seen == 3 and not r.finalized and r.source == {}
    assert r.pose_check.last_pose is None and len(r.recent) == 0
    assert r.rng.random() == Mapper(_config(), "cpu").rng.random()  # the config's seed
    assert len(r.memory) == len(m.memory)
    assert r.process(_frame(3))  # and maps on
    r.save_checkpoint(path)
    with np.load(path) as z:
        assert int(z["version"]) == NPZ_VERSION and set(REQUIRED) <= set(z.files)
