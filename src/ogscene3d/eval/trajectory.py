"""Trajectory accuracy: absolute trajectory error (ATE) RMSE after Umeyama/Horn alignment.

The estimated camera positions are aligned to the ground truth with the closed-form least-squares
similarity (Umeyama 1991; Horn's method for the rigid case): ``gt ≈ s R est + t``. ``align="se3"``
fixes s = 1 (RGB-D: metric scale is observable), ``"sim3"`` also fits the scale (monocular),
``"none"`` compares the raw positions. Only positions enter the ATE, as in the TUM benchmark.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..errors import DataError
from .held_out import run_frames
from .views import open_view_dataset

Alignment = Literal["se3", "sim3", "none"]


def _positions(x: Any, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 3 and a.shape[1:] in ((4, 4), (3, 4)):
        a = a[:, :3, 3]
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name}: expected [N, 4, 4] / [N, 3, 4] poses or [N, 3] positions, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or inf")
    return a


def umeyama_alignment(src: Any, dst: Any, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares (R, t, s) with ``dst ≈ s R src + t``.

    Args:
        src: [N, 3] points to move (estimated positions).
        dst: [N, 3] target points (ground truth), N >= 3 and not all collinear for a unique R.
        with_scale: fit s (Sim(3)); otherwise s = 1 (SE(3)).

    Returns:
        R [3, 3] proper rotation (det +1), t [3], s.
    """
    x = _positions(src, "src")
    y = _positions(dst, "dst")
    if x.shape != y.shape:
        raise ValueError(f"src {x.shape} and dst {y.shape} differ")
    if x.shape[0] < 3:
        raise ValueError(f"alignment needs at least 3 positions, got {x.shape[0]}")
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    cov = yc.T @ xc / x.shape[0]
    u, d, vt = np.linalg.svd(cov)
    # Flip the last axis when the best orthogonal map is a reflection.
    sgn = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sgn[2] = -1.0
    r = u @ np.diag(sgn) @ vt
    if with_scale:
        var_x = (xc**2).sum() / x.shape[0]
        if var_x <= 0:
            raise ValueError("src positions are all identical: scale is undefined")
        s = float((d * sgn).sum() / var_x)
    else:
        s = 1.0
    t = my - s * r @ mx
    return r, t, s


@dataclass(frozen=True)
class TrajectoryError:
    """ATE statistics in metres (after alignment) and the alignment that produced them."""

    alignment: str
    rmse: float
    mean: float
    median: float
    max: float
    num_poses: int
    rotation: np.ndarray  # [3, 3]
    translation: np.ndarray  # [3]
    scale: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "protocol": f"ATE RMSE on positions after {self.alignment} alignment",
            "alignment": self.alignment,
            "ate_rmse_m": self.rmse,
            "ate_mean_m": self.mean,
            "ate_median_m": self.median,
            "ate_max_m": self.max,
            "num_poses": self.num_poses,
            "scale": self.scale,
            "rotation": self.rotation.tolist(),
            "translation": self.translation.tolist(),
        }


def ate(est: Any, gt: Any, align: Alignment = "se3") -> TrajectoryError:
    """Absolute trajectory error of time-associated poses.

    Args:
        est: [N, 4, 4] camera-to-world poses (or [N, 3] positions), estimated.
        gt: the same N poses from the ground truth, in the same order.
        align: "se3" (rigid), "sim3" (rigid + scale) or "none".
    """
    e = _positions(est, "est")
    g = _positions(gt, "gt")
    if e.shape != g.shape:
        raise ValueError(f"est has {e.shape[0]} poses, gt has {g.shape[0]}: associate them first")
    if e.shape[0] == 0:
        raise ValueError("no poses given")
    if align == "none":
        r, t, s = np.eye(3), np.zeros(3), 1.0
    elif align in ("se3", "sim3"):
        r, t, s = umeyama_alignment(e, g, with_scale=align == "sim3")
    else:
        raise ValueError(f"align must be 'se3', 'sim3' or 'none', got {align!r}")
    err = np.linalg.norm((s * (r @ e.T)).T + t - g, axis=1)
    return TrajectoryError(
        alignment=align,
        rmse=float(np.sqrt(np.mean(err**2))),
        mean=float(err.mean()),
        median=float(np.median(err)),
        max=float(err.max()),
        num_poses=int(e.shape[0]),
        rotation=r,
        translation=t,
        scale=float(s),
    )


def ate_rmse(est: Any, gt: Any, align: Alignment = "se3") -> float:
    """ATE RMSE in metres; see :func:`ate`."""
    return ate(est, gt, align).rmse


def read_trajectory(path: str | Path) -> np.ndarray:
    """Read camera positions or poses from a text file, one pose per line (``#`` comments skipped).

    Accepted rows: 16 numbers (row-major 4x4 camera-to-world, Replica ``traj.txt``), 12 numbers
    (row-major 3x4), or 8 numbers (TUM: ``timestamp tx ty tz qx qy qz qw``; only the position is
    kept). Returns [N, 4, 4] poses for the matrix formats and [N, 3] positions for TUM.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise DataError(f"{path}: trajectory file not found") from None
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            rows.append([float(x) for x in line.replace(",", " ").split()])
        except ValueError:
            raise DataError(f"{path}:{n}: not a row of numbers") from None
    if not rows:
        raise DataError(f"{path}: no poses")
    widths = {len(r) for r in rows}
    if len(widths) != 1 or widths.pop() not in (16, 12, 8):
        raise DataError(
            f"{path}: every row must have 16, 12 or 8 numbers (got {sorted({len(r) for r in rows})})"
        )
    a = np.asarray(rows, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise DataError(f"{path}: contains NaN or inf")
    if a.shape[1] == 8:
        return a[:, 1:4]
    if a.shape[1] == 12:
        a = np.concatenate([a, np.tile([0.0, 0.0, 0.0, 1.0], (a.shape[0], 1))], axis=1)
    return a.reshape(-1, 4, 4)


def dataset_trajectory(folder: str | Path, run_dir: str | Path) -> list[np.ndarray | None]:
    """The dataset's own c2w poses of the frames the run in ``run_dir`` read from ``folder``, in order (the
    rows of its ``traj.txt`` under odometry); None for a frame whose pose is missing or invalid (lost
    tracking: ScanNet writes -inf)."""
    ds = open_view_dataset(folder, run_dir)
    poses: list[np.ndarray | None] = []
    for i in run_frames(run_dir, ds).mapped:
        try:
            poses.append(ds.pose(i))
        except DataError:
            poses.append(None)
    return poses
