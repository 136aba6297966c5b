import numpy as np
import pytest
import torch

from ogscene3d.errors import ConfigError, DataError
from ogscene3d.gaussians import SH_C0, GaussianMap
from ogscene3d.runs.map_npz import NPZ_VERSION


def _random_rows(m: int, seed: int = 0, device: str = "cpu") -> dict:
    g = torch.Generator().manual_seed(seed)
    return {
        "means": torch.randn(m, 3, generator=g).to(device),
        "colors": torch.rand(m, 3, generator=g).to(device),
        "log_scales": (torch.rand(m, 3, generator=g) * -3 - 2).to(device),
        "labels": torch.randint(-1, 5, (m,), generator=g).to(device),
        "confidences": torch.rand(m, generator=g).to(device),
        "opacity_logits": torch.randn(m, generator=g).to(device),
    }


def test_append_grows_with_amortised_capacity(device):
    gm = GaussianMap(device, capacity=4)
    caps = []
    total = 0
    for i in range(20):
        rows = _random_rows(3, seed=i, device=device)
        sl = gm.append(**rows, origin_kf=i)
        total += 3
        assert sl == slice(total - 3, total)
        caps.append(gm.capacity)
        torch.testing.assert_close(gm.means[sl], rows["means"])
        assert bool((gm.origin_kf[sl] == i).all())
    assert len(gm) == 60
    # doubling: far fewer reallocations than appends
    assert len(set(caps)) <= 6
    assert gm.capacity >= 60
    # identity quaternions by default
    torch.testing.assert_close(gm.quats, torch.tensor([[1.0, 0, 0, 0]], device=device).expand(60, 4))
    assert gm.next_label == 5


def test_append_isotropic_scales_and_defaults():
    gm = GaussianMap()
    gm.append(torch.zeros(2, 3), torch.full((2, 3), 0.5), torch.tensor([-3.0, -4.0]))
    assert gm.log_scales.tolist() == [[-3.0] * 3, [-4.0] * 3]
    assert gm.labels.tolist() == [-1, -1]
    assert gm.next_label == 0


def test_append_rejects_bad_input():
    gm = GaussianMap()
    with pytest.raises(ValueError, match="means"):
        gm.append(torch.zeros(2, 2), torch.zeros(2, 3), torch.zeros(2, 3))
    with pytest.raises(ValueError, match="NaN"):
        gm.append(torch.tensor([[0.0, float("nan"), 0.0]]), torch.zeros(1, 3), torch.zeros(1, 3))
    with pytest.raises(ValueError, match="colors"):
        gm.append(torch.zeros(2, 3), torch.zeros(3, 3), torch.zeros(2, 3))
    for wide in (2**31, -(2**31) - 1):  # as int32 it would become another label (or -1, unlabelled)
        with pytest.raises(ValueError, match="labels must fit in int32"):
            gm.append(torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(2, 3), labels=torch.tensor([7, wide]))
    zeros = torch.zeros(2, 3)
    with pytest.raises(ValueError, match=r"confidences must lie in \[0, 1\]"):
        gm.append(zeros, zeros, zeros, confidences=torch.tensor([0.5, 1.5]))
    assert len(gm) == 0


def test_device_is_checked():
    with pytest.raises(ConfigError, match="not supported"):
        GaussianMap("bogus")
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="no CUDA GPU"):
            GaussianMap("cuda")


def test_prune_transparent_and_oversized(device):
    gm = GaussianMap(device)
    logits = torch.tensor([-10.0, 2.0, 2.0, 2.0])
    log_scales = torch.log(torch.tensor([[0.01] * 3, [0.01] * 3, [1.0, 0.01, 0.01], [0.02] * 3]))
    gm.append(
        torch.arange(12.0).reshape(4, 3),
        torch.zeros(4, 3),
        log_scales,
        labels=torch.arange(4),
        opacity_logits=logits,
    )
    removed = gm.prune(min_opacity=0.005, max_scale=0.5)
    assert removed == 2
    assert gm.labels.tolist() == [1, 3]
    torch.testing.assert_close(gm.means, torch.tensor([[3.0, 4, 5], [9.0, 10, 11]], device=device))


def test_keep_validates_mask():
    gm = GaussianMap()
    gm.append(**_random_rows(5))
    with pytest.raises(ValueError, match="mask"):
        gm.keep(torch.ones(4, dtype=torch.bool))
    gm.keep(torch.tensor([True, False, True, False, True]))
    assert len(gm) == 3


def test_npz_roundtrip(tmp_path, device):
    gm = GaussianMap(device)
    gm.append(**_random_rows(7, device=device), origin_kf=3)
    gm.new_labels(4)
    gm.save_npz(tmp_path / "map.npz", extra={"mapper_keyframes": np.array(9)})
    back = GaussianMap.load_npz(tmp_path / "map.npz", device=device)
    assert len(back) == 7 and back.next_label == gm.next_label
    for name in [
        "means",
        "quats",
        "log_scales",
        "opacity_logits",
        "colors",
        "labels",
        "confidences",
        "origin_kf",
    ]:
        torch.testing.assert_close(back.field(name), gm.field(name))
    assert int(np.load(tmp_path / "map.npz")["mapper_keyframes"]) == 9


def test_npz_corrupt_and_missing(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        GaussianMap.load_npz(tmp_path / "nope.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(DataError, match="bad.npz"):
        GaussianMap.load_npz(bad)
    np.savez(tmp_path / "partial.npz", means=np.zeros((2, 3), np.float32))
    with pytest.raises(DataError, match="missing"):
        GaussianMap.load_npz(tmp_path / "partial.npz")


def test_npz_of_a_newer_or_damaged_format_version(tmp_path):
    gm = GaussianMap()
    gm.append(**_random_rows(3))
    state = gm.state_dict()
    np.savez(tmp_path / "newer.npz", **{**state, "version": np.array(NPZ_VERSION + 1)})
    with pytest.raises(DataError, match=rf"newer ogscene3d \(map format {NPZ_VERSION + 1};.*to read it"):
        GaussianMap.load_npz(tmp_path / "newer.npz")
    np.savez(tmp_path / "odd.npz", **{**state, "version": np.array("two")})
    with pytest.raises(DataError, match="odd.npz: not a readable map npz"):
        GaussianMap.load_npz(tmp_path / "odd.npz")
    np.savez(tmp_path / "old.npz", **{k: v for k, v in state.items() if k != "version"})
    assert len(GaussianMap.load_npz(tmp_path / "old.npz")) == 3  # no version: format 1, read as it is


def test_ply_layout_plyfile_and_open3d(tmp_path):
    from plyfile import PlyData

    gm = GaussianMap()
    rows = _random_rows(6)
    gm.append(**rows)
    path = tmp_path / "g.ply"
    gm.export_ply(path)
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    v = PlyData.read(str(path))["vertex"].data
    names = list(v.dtype.names)
    assert names[:17] == [
        "x",
        "y",
        "z",
        "nx",
        "ny",
        "nz",
        "f_dc_0",
        "f_dc_1",
        "f_dc_2",
        "opacity",
        "scale_0",
        "scale_1",
        "scale_2",
        "rot_0",
        "rot_1",
        "rot_2",
        "rot_3",
    ]
    assert v.dtype["label"] == np.dtype("<i4") and v.dtype["confidence"] == np.dtype("<f4")
    np.testing.assert_allclose(v["f_dc_0"], (rows["colors"][:, 0].numpy() - 0.5) / SH_C0, rtol=1e-6)
    np.testing.assert_array_equal(v["label"], rows["labels"].numpy())
    back = GaussianMap.read_ply(path)
    torch.testing.assert_close(back.colors, rows["colors"])
    torch.testing.assert_close(back.opacity_logits, rows["opacity_logits"])
    torch.testing.assert_close(back.labels, rows["labels"].int())

    o3d = pytest.importorskip("open3d")  # a dependency; absent only on bare benchmark machines
    pcd = o3d.io.read_point_cloud(str(path))
    np.testing.assert_allclose(np.asarray(pcd.points), rows["means"].numpy(), rtol=1e-6)


def test_read_ply_errors(tmp_path):
    p = tmp_path / "x.ply"
    p.write_bytes(b"garbage")
    with pytest.raises(DataError, match="x.ply"):
        GaussianMap.read_ply(p)
