"""ATE after Umeyama alignment on trajectories with a known transform."""

import numpy as np
import pytest

from ogscene3d.errors import DataError
from ogscene3d.eval.trajectory import ate, ate_rmse, read_trajectory, umeyama_alignment


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _poses(positions):
    p = np.tile(np.eye(4), (len(positions), 1, 1))
    p[:, :3, 3] = positions
    return p


GT = np.random.default_rng(3).normal(size=(30, 3)).cumsum(axis=0) * 0.1
R = _rot([1.0, 2.0, 0.5], 0.7)
T = np.array([0.3, -1.2, 2.0])


def test_rigidly_transformed_trajectory_has_zero_ate():
    est = (R.T @ (GT - T).T).T  # gt = R est + t
    r, t, s = umeyama_alignment(est, GT)
    np.testing.assert_allclose(r, R, atol=1e-9)
    np.testing.assert_allclose(t, T, atol=1e-9)
    assert s == 1.0
    assert ate_rmse(_poses(est), _poses(GT)) < 1e-9
    assert ate_rmse(est, GT, align="none") > 0.5


def test_scale_needs_sim3():
    est = 0.5 * (R.T @ (GT - T).T).T
    assert ate_rmse(est, GT, align="se3") > 1e-3
    res = ate(est, GT, align="sim3")
    assert res.rmse < 1e-9 and res.scale == pytest.approx(2.0)
    assert res.to_dict()["protocol"].startswith("ATE RMSE")


def test_constant_offset_without_alignment():
    est = GT + np.array([0.0, 0.03, 0.04])
    res = ate(est, GT, align="none")
    assert res.rmse == pytest.approx(0.05) and res.max == pytest.approx(0.05)


def test_reflection_is_not_returned():
    est = GT * np.array([1.0, 1.0, -1.0])  # a mirror image: best proper rotation, not a reflection
    r, _, _ = umeyama_alignment(est, GT)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_bad_input():
    with pytest.raises(ValueError, match="associate"):
        ate(GT[:10], GT)
    with pytest.raises(ValueError, match="at least 3"):
        ate(GT[:2], GT[:2])
    with pytest.raises(ValueError, match="NaN"):
        ate(np.full((5, 3), np.nan), GT[:5])


def test_read_trajectory_formats(tmp_path):
    poses = _poses(GT[:4])
    (tmp_path / "a.txt").write_text("\n".join(" ".join(map(str, p.reshape(-1))) for p in poses))
    np.testing.assert_allclose(read_trajectory(tmp_path / "a.txt"), poses)
    tum = "# timestamp tx ty tz qx qy qz qw\n" + "\n".join(
        f"{i}.0 {x} {y} {z} 0 0 0 1" for i, (x, y, z) in enumerate(GT[:4])
    )
    (tmp_path / "b.txt").write_text(tum)
    np.testing.assert_allclose(read_trajectory(tmp_path / "b.txt"), GT[:4])
    (tmp_path / "c.txt").write_text("1 2 3\n")
    with pytest.raises(DataError, match="16, 12 or 8"):
        read_trajectory(tmp_path / "c.txt")
    with pytest.raises(DataError, match="not found"):
        read_trajectory(tmp_path / "missing.txt")
