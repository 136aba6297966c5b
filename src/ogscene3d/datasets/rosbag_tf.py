"""Rigid transforms over time as ROS records them: /tf and /tf_static edges, pose topics, interpolated to an
image's stamp.

A :class:`Track` is one transform sampled over time (parent -> child: the child frame's pose in the parent
frame), read between samples by linear interpolation of the translation and spherical interpolation of the
rotation, never extrapolated further than a tolerance. A :class:`TfTree` chains tracks from a frame up to
its tree's root, as tf2 does, to give the pose of any frame in any other of the same tree.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from .base import quat_to_matrix

log = logging.getLogger(__name__)


def slerp(q0: np.ndarray, q1: np.ndarray, w: float) -> np.ndarray:
    """The unit quaternion (x, y, z, w order) a fraction ``w`` of the way from ``q0`` to ``q1`` on the
    shorter arc."""
    q0 = q0 / np.linalg.norm(q0)
    q1 = q1 / np.linalg.norm(q1)
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:  # nearly the same rotation: the arc is a line to rounding
        q = q0 + w * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(dot)
    return (np.sin((1.0 - w) * theta) * q0 + np.sin(w * theta) * q1) / np.sin(theta)


def rigid(translation: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """4x4 transform from a translation and an (x, y, z, w) quaternion (normalised)."""
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(np.asarray(quat_xyzw, dtype=np.float64))
    T[:3, 3] = translation
    return T


def invert(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


@dataclass
class Track:
    """One transform over time; ``static``: a single value valid at every time (/tf_static)."""

    parent: str
    child: str
    static: bool = False
    times: list[float] = field(default_factory=list)
    translations: list[np.ndarray] = field(default_factory=list)
    quats: list[np.ndarray] = field(default_factory=list)

    def add(self, t: float, translation: np.ndarray, quat_xyzw: np.ndarray) -> None:
        if self.static:  # a later static message replaces an earlier one, as tf2 does
            self.times, self.translations, self.quats = [t], [translation], [quat_xyzw]
            return
        self.times.append(t)
        self.translations.append(translation)
        self.quats.append(quat_xyzw)

    def finish(self) -> None:
        """Sort the samples by time (bags store messages by receive time, not by stamp)."""
        order = np.argsort(self.times, kind="stable")
        self.times = [self.times[i] for i in order]
        self.translations = [self.translations[i] for i in order]
        self.quats = [self.quats[i] for i in order]

    def at(self, t: float, tolerance: float) -> np.ndarray | None:
        """The 4x4 transform at time ``t``; None when ``t`` lies more than ``tolerance`` seconds outside the
        samples (or there are none)."""
        if not self.times:
            return None
        if self.static:
            return rigid(self.translations[0], self.quats[0])
        times = self.times
        if t <= times[0]:
            return rigid(self.translations[0], self.quats[0]) if times[0] - t <= tolerance else None
        if t >= times[-1]:
            return rigid(self.translations[-1], self.quats[-1]) if t - times[-1] <= tolerance else None
        j = int(np.searchsorted(times, t, side="right"))
        t0, t1 = times[j - 1], times[j]
        w = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        if w == 0.0:
            return rigid(self.translations[j - 1], self.quats[j - 1])
        trans = (1.0 - w) * self.translations[j - 1] + w * self.translations[j]
        return rigid(trans, slerp(self.quats[j - 1], self.quats[j], w))

    def span(self) -> str:
        if self.static:
            return "static"
        if not self.times:
            return "no samples"
        return f"{self.times[0]:.3f}..{self.times[-1]:.3f} s"


class TfTree:
    """The /tf + /tf_static transforms of a recording, each frame with one parent."""

    def __init__(self) -> None:
        self.tracks: dict[str, Track] = {}  # by child frame
        self._warned: set[str] = set()

    def add(self, parent: str, child: str, t: float, translation, quat_xyzw, static: bool) -> None:
        parent, child = parent.lstrip("/"), child.lstrip("/")
        track = self.tracks.get(child)
        if track is None:
            track = self.tracks[child] = Track(parent, child, static)
        elif track.parent != parent:
            if child not in self._warned:
                log.warning(
                    "tf: frame %r has two parents (%r and %r); using %r",
                    child,
                    track.parent,
                    parent,
                    track.parent,
                )
                self._warned.add(child)
            return
        track.add(t, np.asarray(translation, dtype=np.float64), np.asarray(quat_xyzw, dtype=np.float64))

    def finish(self) -> None:
        for track in self.tracks.values():
            track.finish()

    @property
    def frames(self) -> set[str]:
        return set(self.tracks) | {t.parent for t in self.tracks.values()}

    def chain(self, frame: str) -> list[Track]:
        """The tracks from ``frame`` up to its tree's root (empty for a root)."""
        out, seen = [], {frame}
        while frame in self.tracks:
            track = self.tracks[frame]
            out.append(track)
            frame = track.parent
            if frame in seen:  # a loop in the tree: stop at the frame met again
                break
            seen.add(frame)
        return out

    def root(self, frame: str) -> str:
        chain = self.chain(frame)
        return chain[-1].parent if chain else frame

    def _to_root(self, frame: str, t: float, tolerance: float) -> np.ndarray | None:
        T = np.eye(4)
        for track in self.chain(frame):
            step = track.at(t, tolerance)
            if step is None:
                return None
            T = step @ T
        return T

    def lookup(self, target: str, source: str, t: float, tolerance: float) -> np.ndarray | None:
        """The pose of frame ``source`` in frame ``target`` at time ``t`` (T_target_source), chained through
        the common root; None when a transform on the way has no sample within ``tolerance`` of ``t``. The
        caller checks that both frames share a root."""
        a = self._to_root(target, t, tolerance)
        b = self._to_root(source, t, tolerance)
        if a is None or b is None:
            return None
        return invert(a) @ b

    def gap(self, target: str, source: str, t: float, tolerance: float) -> str:
        """Which transform on the chain has no sample near ``t`` (for messages), e.g. ``odom -> base_link
        (1.200..5.000 s)``."""
        for frame in (target, source):
            for track in self.chain(frame):
                if track.at(t, tolerance) is None:
                    return f"{track.parent} -> {track.child} ({track.span()})"
        return "none"
