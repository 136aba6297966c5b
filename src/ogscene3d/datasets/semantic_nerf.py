"""Replica as Semantic-NeRF rendered it (the sequences SNI-SLAM, SGS-SLAM & co. score 2D semantics on),
and SNI-SLAM's own renders in the same layout.

One sequence folder (``Replica_Dataset/room_0/Sequence_1``) holds, for frames ``i = 0, 1, ...`` (no
zero-padding):

* ``rgb/rgb_<i>.png`` (8-bit colour);
* ``depth/depth_<i>.png`` (uint16 millimetres: metres = value / 1000);
* ``semantic_class/semantic_class_<i>.png`` (uint8 Replica class ids, 0 = void: no object or an object
  without a class); the ``vis_sem_class_<i>.png`` colourisations beside them are not read;
* ``semantic_instance/semantic_instance_<i>.png`` (uint16 object ids; not read);
* ``traj_w_c.txt``: line ``i`` is frame ``i``'s camera-to-world pose, a row-major 4x4 matrix, OpenCV
  camera axes (x right, y down, z forward), world z-up.

SNI-SLAM (``IRMVLab/SNI-SLAM``) renders Replica along NICE-SLAM's trajectories at 1200x680 with vMAP's
habitat-sim script, which writes this same layout, and keeps the poses as ``traj.txt`` (NICE-SLAM's file:
the same row-major OpenCV camera-to-world lines): its scene folder (``data/replica/room_0``) is such a
sequence with ``traj.txt`` for ``traj_w_c.txt``. Its loader reads it as above (depth ``png_depth_scale``
1000, the class maps' raw Replica ids) with fx = fy = 600, cx = 599.5, cy = 339.5: the 90-degree camera
below. A folder is taken as this layout by ``traj.txt`` only when ``rgb/`` holds ``rgb_<i>.png`` frames
(other layouts keep a ``traj.txt`` too); with both files, ``traj_w_c.txt`` is read.

There is no intrinsics file: the renders are habitat-sim pinhole images with a 90-degree horizontal field
of view, and Semantic-NeRF's trainer derives fx = fy = W / 2 / tan(45 deg) = W / 2, cx = (W - 1) / 2,
cy = (H - 1) / 2 from the image size (640x480 -> 320, 320, 319.5, 239.5), casting pixel i's ray through
(i - cx) / fx: its pixel centres lie at integers. ogscene3d's K puts them at +0.5 (:mod:`ogscene3d.camera`),
so the same camera is fx = fy = W / 2, cx = W / 2, cy = H / 2 here (640x480 -> 320, 320, 320, 240; SNI-SLAM's
1200x680 -> 600, 600, 600, 340).

Class names come from the release's ``semantic_info/<scene>/info_semantic.json`` (Replica's own file:
``{"classes": [{"id", "name"}, ...]}``), found beside the scene folders; ``info_semantic.json`` in the
sequence folder, its scene folder or the ``habitat/`` of either is taken too (a folder with ``traj.txt``
is its own scene folder). Without one the class maps are still read, and ``eval`` needs ``--classes``.

A scene folder holding ``Sequence_1/``, ``Sequence_2/`` (the release has two trajectories per scene) is
read as its first sequence, with a log line naming the others.
"""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path

import numpy as np

from ..config import DataConfig
from ..errors import DataError
from .base import FrameRecord, K_from_values, RGBDDataset, numbered_files, read_depth_raw, read_label_png
from .replica import bad_lines_message, beyond_trajectory, read_traj_lines
from .replica_semantic import read_info_semantic

log = logging.getLogger(__name__)

TRAJ_NAME = "traj_w_c.txt"
SNI_TRAJ_NAME = "traj.txt"  # SNI-SLAM's renders: NICE-SLAM's trajectory file, kept under its name
CLASS_DIR = "semantic_class"
INFO_NAME = "info_semantic.json"
HFOV_DEG = 90.0  # habitat-sim's default camera, which Semantic-NeRF rendered with and assumes in training
VOID_ID = 0

_SEQUENCE_DIR = re.compile(r"sequence_(\d+)$", re.IGNORECASE)


def _has_rgb_frame(rgb: Path) -> bool:
    """Whether ``rgb`` holds an ``rgb_<i>.png``; stops at the first one, so a folder of thousands costs
    little."""
    with os.scandir(rgb) as it:
        for e in it:
            n = e.name
            if n.startswith("rgb_") and n[-4:].lower() == ".png" and n[4:-4].isdigit():
                return True
    return False


def trajectory_file(folder: Path) -> Path | None:
    """The pose file of sequence folder ``folder`` (``traj_w_c.txt``, else SNI-SLAM's ``traj.txt``); None
    when ``folder`` is not a sequence."""
    if not ((folder / "rgb").is_dir() and (folder / "depth").is_dir()):
        return None
    if (folder / TRAJ_NAME).is_file():
        return folder / TRAJ_NAME
    # NICE-SLAM's and other layouts keep a traj.txt too: only rgb_<i>.png frames beside it make it this one
    if (folder / SNI_TRAJ_NAME).is_file() and _has_rgb_frame(folder / "rgb"):
        return folder / SNI_TRAJ_NAME
    return None


def is_sequence(folder: Path) -> bool:
    return trajectory_file(folder) is not None


def sequence_dirs(scene: Path) -> list[Path]:
    """The ``Sequence_<n>/`` sub-folders of ``scene`` that are sequences, in order of ``n``."""
    found = []
    for d in scene.iterdir() if scene.is_dir() else ():
        m = _SEQUENCE_DIR.match(d.name)
        if m and d.is_dir() and is_sequence(d):
            found.append((int(m.group(1)), d))
    return [d for _, d in sorted(found)]


def hfov_intrinsics(width: int, height: int, hfov_deg: float = HFOV_DEG) -> np.ndarray:
    """K (pixel centres at +0.5) of Semantic-NeRF's camera: square pixels, horizontal field of view
    ``hfov_deg``, principal point at the image centre."""
    f = width / 2.0 / np.tan(np.radians(hfov_deg / 2.0))
    # Semantic-NeRF's cx = (W - 1) / 2 counts pixel centres from 0; ours count from 0.5: the same ray.
    return K_from_values(f, f, width / 2.0, height / 2.0)


def find_class_info(seq: Path) -> Path | None:
    """Replica's ``info_semantic.json`` for sequence ``seq``: ``semantic_info/<scene>/`` beside the scene
    folder (the release's place), else in the sequence folder, the scene folder or the ``habitat/`` of
    either."""
    scene = seq.parent
    candidates = [
        scene.parent / "semantic_info" / scene.name / INFO_NAME,
        seq / INFO_NAME,
        scene / INFO_NAME,
        scene / "habitat" / INFO_NAME,
        seq / "habitat" / INFO_NAME,  # a folder with traj.txt is its scene's own folder
    ]
    return next((p for p in candidates if p.is_file()), None)


def read_class_names(path: Path) -> dict[int, str]:
    """Class id -> name from ``info_semantic.json``'s ``classes``, without id 0: the renderer writes 0 for
    pixels of no class, and Semantic-NeRF scores 0 as void."""
    classes, _ = read_info_semantic(path)
    classes.pop(VOID_ID, None)
    if not classes:
        raise DataError(f"{path}: its 'classes' list names no class besides {VOID_ID} (void)")
    return classes


class SemanticNeRFDataset(RGBDDataset):
    kind = "semantic_nerf"
    void_class_id = VOID_ID
    up_axis = (0.0, 0.0, 1.0)
    up_axis_source = "the Semantic-NeRF layout (Replica's world, z-up)"
    depth_scale_default = 1000.0
    # the K derived from the field of view (hfov_intrinsics) is already ogscene3d's
    pixel_centers_default = "half"

    @staticmethod
    def detect(root: Path) -> bool:
        return is_sequence(root) or bool(sequence_dirs(root))

    def __init__(self, root: Path, config: DataConfig, segments_dir: Path | None = None) -> None:
        root = Path(root)
        if not is_sequence(root):
            seqs = sequence_dirs(root)
            if not seqs:
                raise DataError(
                    f"{root}: not a Semantic-NeRF sequence (rgb/, depth/ and {TRAJ_NAME}, or SNI-SLAM's "
                    f"{SNI_TRAJ_NAME} beside rgb/rgb_<i>.png) nor a scene folder holding Sequence_<n>/ ones"
                )
            if len(seqs) > 1:
                log.info(
                    "%s holds %s: reading %s (give %s as the data path for that one)",
                    root,
                    ", ".join(d.name for d in seqs),
                    seqs[0].name,
                    seqs[1],
                )
            root = seqs[0]
        rgbs = numbered_files(root / "rgb", prefix="rgb_")
        if not rgbs:
            raise DataError(f"{root / 'rgb'}: no rgb_<i>.png images")
        depths = numbered_files(root / "depth", prefix="depth_")
        labels = numbered_files(root / CLASS_DIR, prefix="semantic_class_")
        traj = trajectory_file(root)
        assert traj is not None  # root is a sequence
        poses, bad_lines = read_traj_lines(traj)
        if bad_lines and config.on_bad_frame != "skip":
            raise DataError(
                f"{bad_lines_message(bad_lines)}; set data.on_bad_frame: skip to leave those frames out"
            )
        # a frame is every number rgb/ or depth/ has; a missing file gets the name it should have, which the
        # base class reports
        numbers = sorted(set(rgbs) | set(depths))
        records = [
            FrameRecord(
                name=f"rgb_{n}" if n not in rgbs else rgbs[n].stem,
                rgb_path=rgbs.get(n, root / "rgb" / f"rgb_{n}.png"),
                depth_path=depths.get(n, root / "depth" / f"depth_{n}.png"),
                pose=poses[n] if n < len(poses) else None,
                pose_error=bad_lines.get(n),
                pose_source=f"{traj}:{n + 1}",
                timestamp=float(n),
                lacks=beyond_trajectory(traj, len(poses), n),
                extras={"label": labels[n]} if n in labels else {},
            )
            for n in numbers
        ]
        K = None
        if config.intrinsics is None:
            first = next((r for r in records if r.depth_path.is_file()), None)
            if first is not None:  # none at all: the base class reports the missing files
                h, w = read_depth_raw(first.depth_path).shape
                K = hfov_intrinsics(w, h)
                if self.read_pixel_centers(config) == "integer":
                    # the field of view fixes the camera: a convention asked for only says how to write it
                    K[:2, 2] -= 0.5
        info = find_class_info(root)
        self._class_names = read_class_names(info) if info is not None and labels else None
        self.class_info = info
        super().__init__(root, records, K, config, segments_dir)

    @property
    def has_class_maps(self) -> bool:
        return any("label" in rec.extras for rec in self.records)

    @property
    def class_names(self) -> dict[int, str] | None:
        return dict(self._class_names) if self._class_names is not None and self.has_class_maps else None

    def _load_gt(
        self, rec: FrameRecord, shape: tuple[int, int]
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        path = rec.extras.get("label")
        if path is None:
            return None, None
        return None, read_label_png(path, shape, "Semantic-NeRF class")
