"""Pose-jump check: a camera that moves implausibly far between two frames (``mapping.max_pose_step`` /
``mapping.max_pose_step_deg``).

A dataset pose glitch (a row of another frame's pose, an identity written for a lost frame) or a tracker
failure puts a frame's depth in the wrong place: the map gets a smeared copy of the scene there and every
later association near it is ambiguous. Each frame the mapper is given a pose for is compared with the
last frame it accepted; the limits are per step between consecutive frames of the folder, times
``data.stride`` and the number of selected frames since that one, so a frame after skipped or untracked
ones, or a strided run's next frame, may have moved proportionally further. The per-step limits still
have to cover sample folders that hold every n-th frame already (7-Scenes here), which the loader cannot
tell from a 1:1 recording.

Defaults 0.5 m and 30 deg per step, about twice the largest steps of the sample sequences here (7-Scenes
every 20th frame; the steps of each sample: docs/results.md, "Dataset checks"). A hand-held camera at 30 fps
would have to move at 15 m/s or turn at 900 deg/s to reach them.

``mapping.on_pose_jump`` decides what follows: ``warn`` maps the frame (it becomes the new reference),
``skip`` leaves it out (the reference stays the last accepted frame), ``error`` stops the run with a
:class:`PoseJumpError` (``ogscene3d run`` saves the map first; the frame is not counted as read, so a
``--resume`` retries it under the setting then in force).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..config import choices
from ..errors import ConfigError, DataError
from .keyframes import pose_delta
from .timings import Timings

log = logging.getLogger(__name__)

ACTIONS = choices("mapping.on_pose_jump")


class PoseJumpError(DataError):
    """A frame's pose jumped beyond the configured limits under ``mapping.on_pose_jump: error``."""


@dataclass
class PoseJump:
    """One frame's implausible motion since the last accepted frame."""

    index: int
    name: str
    previous: int  # the last accepted frame's index
    translation: float  # metres
    rotation_deg: float
    limit_translation: float  # the limits for this gap (per-step limits x steps)
    limit_rotation_deg: float
    steps: int = 1  # folder frames since the last accepted one (selected frames x data.stride)

    def describe(self) -> str:
        times = f"{self.steps} x " if self.steps > 1 else ""
        return (
            f"frame {self.index} ({self.name}): the camera pose jumped {self.translation:.3f} m and "
            f"{self.rotation_deg:.1f} deg from frame {self.previous} (limits {self.limit_translation:g} m, "
            f"{self.limit_rotation_deg:g} deg: {times}mapping.max_pose_step, max_pose_step_deg)"
        )


class PoseJumpCheck:
    """Compares each frame's pose with the last accepted one (see the module docstring).

    ``max_translation`` (m) and ``max_rotation_deg`` are per step between consecutive frames of the
    folder, ``stride`` the selection's (``data.stride``); 0 turns a limit off. ``check`` judges a frame
    (``index``: its position in the selection), ``accept`` makes it the reference."""

    def __init__(self, max_translation: float, max_rotation_deg: float, action: str, stride: int = 1) -> None:
        if not (max_translation >= 0 and max_rotation_deg >= 0):  # also catches NaN
            raise ConfigError(
                "mapping.max_pose_step and mapping.max_pose_step_deg must be >= 0 (0 = no limit), got "
                f"{max_translation}, {max_rotation_deg}"
            )
        if action not in ACTIONS:
            raise ConfigError(f"mapping.on_pose_jump must be one of {ACTIONS}, got {action!r}")
        self.max_translation = float(max_translation)
        self.max_rotation_deg = float(max_rotation_deg)
        self.action = action
        self.stride = max(1, int(stride))
        self.last_pose: np.ndarray | None = None
        self.last_index = -1

    def check(self, index: int, pose: np.ndarray, name: str = "unnamed") -> PoseJump | None:
        """The jump of frame ``index`` (dataset position) with c2w ``pose`` [4,4], or None when it is within
        the limits (or there is no reference yet)."""
        if self.last_pose is None:
            return None
        # positions go up within a run; a smaller one (a caller restarting a sequence) counts as one step
        steps = max(1, int(index) - self.last_index) * self.stride
        t, r = pose_delta(self.last_pose, np.asarray(pose, dtype=np.float64))
        lt, lr = self.max_translation * steps, self.max_rotation_deg * steps
        if (lt > 0 and t > lt) or (lr > 0 and r > lr):
            return PoseJump(int(index), name, self.last_index, t, r, lt, lr, steps)
        return None

    def leave_out(self, index: int, pose: np.ndarray, name: str, timings: Timings) -> bool:
        """Judge a frame the mapper is given (``index``, c2w ``pose``, ``name``) by :attr:`action`: True,
        leave it out (``skip``); else it becomes the reference (``warn``, or no jump). Jumps are counted in
        ``timings``.

        Raises:
            PoseJumpError: a jump under ``on_pose_jump: error``.
        """
        jump = self.check(index, pose, name)
        if jump is not None:
            if self.action == "error":
                raise PoseJumpError(
                    f"{jump.describe()}; fix the pose, or set mapping.on_pose_jump to skip (leave the frame "
                    "out) or warn (map it anyway)"
                )
            timings.add("pose_jumps")
            if self.action == "skip":
                log.warning("%s: frame left out (mapping.on_pose_jump: skip)", jump.describe())
                timings.add("frames_skipped_pose_jump")
                return True
            log.warning("%s: mapped anyway (mapping.on_pose_jump: warn)", jump.describe())
        self.accept(index, pose)
        return False

    def accept(self, index: int, pose: np.ndarray) -> None:
        self.last_pose = np.array(pose, dtype=np.float64)
        self.last_index = int(index)

    def state(self) -> dict[str, np.ndarray]:
        return {
            "posecheck_last_pose": self.last_pose if self.last_pose is not None else np.zeros((0, 4, 4)),
            "posecheck_last_index": np.array(self.last_index),
        }

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore ``state()``; an empty dict (a checkpoint from before the check) leaves no reference."""
        lp = np.asarray(state.get("posecheck_last_pose", np.zeros((0, 4, 4))))
        self.last_pose = lp.astype(np.float64) if lp.shape == (4, 4) else None
        self.last_index = int(state.get("posecheck_last_index", -1))
