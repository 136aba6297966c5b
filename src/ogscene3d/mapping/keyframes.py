"""Keyframe selection: every k-th frame and/or when the camera moved or turned enough since the last one."""

from __future__ import annotations

import math

import numpy as np


def pose_delta(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(translation in metres, rotation angle in degrees) between two c2w poses."""
    rel = np.linalg.inv(a) @ b
    t = float(np.linalg.norm(rel[:3, 3]))
    cos = (np.trace(rel[:3, :3]) - 1.0) / 2.0
    return t, math.degrees(math.acos(max(-1.0, min(1.0, cos))))


class KeyframeSelector:
    """Decides per frame whether it is a keyframe.

    The first frame always is. After that a frame is a keyframe when ``every`` > 0 and at least ``every``
    frames were seen since the last keyframe, or when ``translation`` (m) / ``rotation_deg`` (deg) is > 0
    and the pose moved at least that much from the last keyframe's pose. Frames are counted as they
    arrive (a dataset stride is already applied), not by their index.
    """

    def __init__(self, every: int = 1, translation: float = 0.0, rotation_deg: float = 0.0) -> None:
        if every < 0 or translation < 0 or rotation_deg < 0:
            raise ValueError("keyframe rule parameters must be >= 0")
        if every == 0 and translation == 0 and rotation_deg == 0:
            raise ValueError("keyframe rule: set keyframe_every > 0 or a translation/rotation threshold")
        self.every = int(every)
        self.translation = float(translation)
        self.rotation_deg = float(rotation_deg)
        self.since_last = 0
        self.last_pose: np.ndarray | None = None

    def __call__(self, pose: np.ndarray) -> bool:
        self.since_last += 1
        if self.last_pose is None:
            return self._take(pose)
        if self.every > 0 and self.since_last >= self.every:
            return self._take(pose)
        if self.translation > 0 or self.rotation_deg > 0:
            t, r = pose_delta(self.last_pose, pose)
            if (self.translation > 0 and t >= self.translation) or (
                self.rotation_deg > 0 and r >= self.rotation_deg
            ):
                return self._take(pose)
        return False

    def _take(self, pose: np.ndarray) -> bool:
        self.since_last = 0
        self.last_pose = np.array(pose, dtype=np.float64)
        return True

    def state(self) -> dict[str, np.ndarray]:
        return {
            "kf_since_last": np.array(self.since_last),
            "kf_last_pose": self.last_pose if self.last_pose is not None else np.zeros((0, 4, 4)),
        }

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        self.since_last = int(state["kf_since_last"])
        lp = np.asarray(state["kf_last_pose"])
        self.last_pose = lp if lp.shape == (4, 4) else None
