"""TUM RGB-D: ``rgb.txt`` / ``depth.txt`` (``timestamp filename`` lines), ``groundtruth.txt``
(``timestamp tx ty tz qx qy qz qw``: the optical centre's camera-to-world pose, OpenCV axes) and
16-bit depth PNGs at 5000 units per metre.

Frames are the rgb images that have a depth image within ``MAX_DT`` seconds, as in TUM's ``associate.py``:
colour and depth paired one to one, closest pairs first (the images left unpaired are named in a warning);
the 100 Hz poses by nearest stamp, when ``groundtruth.txt`` exists: a frame with no pose within ``MAX_DT``
is named when the dataset opens, an error, or left out under ``data.on_bad_frame: skip``. Intrinsics:
``data.intrinsics`` if given, else the published calibration of the freiburg1/2/3 sensor named in the
folder name (the innermost folder that names one: ``data/freiburg1_runs/rgbd_dataset_freiburg3_office`` is
freiburg3), else the ROS default (525, 525, 319.5, 239.5) with a warning.

Known limitation: TUM's calibration of the freiburg1 and freiburg2 colour cameras has lens distortion
(k1 = 0.26 and 0.23 ...), which is not corrected: a colour pixel lands up to about 24 px (fr1) / 19 px
(fr2) off in the image corners, 5-8 px half-way out, as SplaTAM reads them; NICE-SLAM and MonoGS undistort
the colour image (not the depth, which OpenNI registered to it). freiburg3 images have no distortion. The
reader warns when it uses the fr1/fr2 calibration.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..config import DataConfig
from ..errors import DataError
from .base import FrameRecord, K_from_values, RGBDDataset, quat_to_matrix

log = logging.getLogger(__name__)

MAX_DT = 0.02  # seconds
LISTED = 5  # images left out that a warning names; the rest are counted

TUM_INTRINSICS = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
}
# (k1, k2, p1, p2, k3) of TUM's colour camera calibration; freiburg3's are all 0
TUM_DISTORTION = {
    "freiburg1": (0.2624, -0.9531, -0.0054, 0.0026, 1.1633),
    "freiburg2": (0.2312, -0.7849, -0.0033, -0.0001, 0.9172),
}
ROS_DEFAULT = (525.0, 525.0, 319.5, 239.5)


def tum_sensor(root: Path) -> str | None:
    """The freiburg1/2/3 sensor named by the innermost folder of ``root`` (as given, then resolved) that names
    one, or None."""
    for path in (Path(root), Path(root).resolve()):
        for part in reversed(path.parts):
            found = [key for key in TUM_INTRINSICS if key in part.lower()]
            if found:
                return found[0]
    return None


def read_tum_list(path: Path, columns: int) -> tuple[np.ndarray, list[list[str]]]:
    """(timestamps [N], the remaining columns per line) of a TUM list file; '#' lines are comments."""
    if not path.is_file():
        raise DataError(f"{path}: file is missing")
    stamps, rest = [], []
    for k, line in enumerate(path.read_text().splitlines()):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != columns:
            raise DataError(f"{path}:{k + 1}: expected {columns} columns, found {len(parts)}")
        try:
            stamps.append(float(parts[0]))
        except ValueError as e:
            raise DataError(f"{path}:{k + 1}: bad timestamp {parts[0]!r}") from e
        rest.append(parts[1:])
    if not stamps:
        raise DataError(f"{path}: holds no entries")
    return np.array(stamps), rest


def associate(a: np.ndarray, b: np.ndarray, max_dt: float = MAX_DT, one_to_one: bool = False) -> np.ndarray:
    """For each stamp in ``a`` the index of the nearest stamp in ``b`` within ``max_dt`` (-1: none).

    ``one_to_one``: as the TUM benchmark's ``associate.py`` pairs images: every pair within ``max_dt``,
    closest first, each stamp of either list used at most once (a depth image is never given to two colour
    frames; a colour frame whose nearest depth went to a closer one takes its next within ``max_dt``)."""
    order = np.argsort(b)
    bs = b[order]
    if not one_to_one:
        pos = np.clip(np.searchsorted(bs, a), 1, max(len(bs) - 1, 1))
        lo = np.clip(pos - 1, 0, len(bs) - 1)
        hi = np.clip(pos, 0, len(bs) - 1)
        pick = np.where(np.abs(bs[lo] - a) <= np.abs(bs[hi] - a), lo, hi)
        ok = np.abs(bs[pick] - a) <= max_dt
        return np.where(ok, order[pick], -1)
    first = np.searchsorted(bs, a - max_dt, side="left")
    last = np.searchsorted(bs, a + max_dt, side="right")
    pairs = [(abs(float(bs[j]) - float(t)), i, j) for i, t in enumerate(a) for j in range(first[i], last[i])]
    out = np.full(len(a), -1, dtype=np.int64)
    used = np.zeros(len(bs), dtype=bool)
    for _, i, j in sorted(pairs):
        if out[i] < 0 and not used[j]:
            out[i], used[j] = order[j], True
    return out


def _log_unpaired(root: Path, rgb_files: list, depth_files: list, d_idx: np.ndarray) -> None:
    """Name the colour and depth images that the association paired with none (TUM's streams run at their own
    rates and drop frames: such images are left out, as the benchmark's associate.py leaves them out)."""
    used = set(d_idx[d_idx >= 0].tolist())
    unused = [f for k, (f,) in enumerate(depth_files) if k not in used]
    lonely = (
        ("colour images in rgb.txt have no depth image", [f for (f,), j in zip(rgb_files, d_idx) if j < 0]),
        ("depth images in depth.txt have no colour image", unused),
    )
    for what, files in lonely:
        if files:
            more = f" and {len(files) - LISTED} more" if len(files) > LISTED else ""
            log.warning(
                "%s: %d %s within %s s (paired one to one, closest first); left out: %s%s",
                root, len(files), what, MAX_DT, ", ".join(files[:LISTED]), more,
            )  # fmt: skip


class TUMDataset(RGBDDataset):
    kind = "tum"
    depth_scale_default = 5000.0
    up_axis = (0.0, 0.0, 1.0)
    up_axis_source = "the TUM layout (its motion-capture world is z-up)"

    layout_markers = ("rgb.txt", "depth.txt")

    def __init__(self, root: Path, config: DataConfig, segments_dir: Path | None = None) -> None:
        root = Path(root)
        t_rgb, rgb_files = read_tum_list(root / "rgb.txt", 2)
        t_depth, depth_files = read_tum_list(root / "depth.txt", 2)
        # one depth image per colour frame, as TUM's associate.py pairs them
        d_idx = associate(t_rgb, t_depth, one_to_one=True)
        gt_path = root / "groundtruth.txt"
        poses = None
        if gt_path.is_file():
            t_gt, vals = read_tum_list(gt_path, 8)
            try:
                v = np.array(vals, dtype=np.float64)
            except ValueError as e:
                raise DataError(f"{gt_path}: non-numeric pose values ({e})") from e
            g_idx = associate(t_rgb, t_gt)
            poses = np.tile(np.eye(4), (len(v), 1, 1))
            # Quaternions are printed with 4 decimals: renormalise those that are unit up to rounding,
            # keep the others as they are so that the pose check rejects that frame (non-rigid).
            q = v[:, 3:7]
            norm = np.linalg.norm(q, axis=1, keepdims=True)
            q = np.where(np.abs(norm - 1.0) < 1e-2, q / np.maximum(norm, 1e-12), q)
            poses[:, :3, :3] = quat_to_matrix(q, normalize=False)
            poses[:, :3, 3] = v[:, :3]
        else:
            g_idx = np.zeros(len(t_rgb), dtype=np.int64)
            log.info("%s: no groundtruth.txt; frames have no pose (use tracking.poses=odometry)", root)
        records = []
        for i, (ts, (rgb_name,)) in enumerate(zip(t_rgb, rgb_files)):
            if d_idx[i] < 0:
                continue
            no_pose = poses is not None and g_idx[i] < 0
            records.append(
                FrameRecord(
                    name=Path(rgb_name).stem,
                    rgb_path=root / rgb_name,
                    depth_path=root / depth_files[d_idx[i]][0],
                    pose=None if poses is None or no_pose else poses[g_idx[i]],
                    pose_source=f"{gt_path} (t={ts:.6f})",
                    timestamp=float(ts),
                    # the base class names these with the frames whose files are missing: an error, or a skip
                    lacks=f"no pose in groundtruth.txt within {MAX_DT} s of its stamp {ts:.6f}"
                    if no_pose
                    else None,
                )
            )
        if not records:
            raise DataError(f"{root}: no rgb frame has a depth image within {MAX_DT} s")
        _log_unpaired(root, rgb_files, depth_files, d_idx)
        K = None
        if config.intrinsics is None:
            sensor = tum_sensor(root)
            if sensor is not None:
                K = K_from_values(*TUM_INTRINSICS[sensor])
                if sensor in TUM_DISTORTION:
                    log.warning(
                        "%s: %s colour images have lens distortion %s (TUM's calibration) that is not "
                        "corrected: colour lands up to ~20 px off in the image corners",
                        root,
                        sensor,
                        TUM_DISTORTION[sensor],
                    )
            else:
                log.warning("%s: unknown TUM sensor; using the ROS default intrinsics %s", root, ROS_DEFAULT)
                K = K_from_values(*ROS_DEFAULT)
        super().__init__(root, records, K, config, segments_dir)
