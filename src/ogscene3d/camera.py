"""Pinhole camera intrinsics (OpenCV convention: x right, y down, z forward; pixel centres at +0.5)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics of an image of ``width`` x ``height`` pixels (OpenCV axes, pixel centres at +0.5).

    Attributes:
        fx: focal length along x, in pixels (> 0).
        fy: focal length along y, in pixels (> 0).
        cx: principal point's x, in pixels from the image's left edge.
        cy: principal point's y, in pixels from the image's top edge.
        width: image width in pixels.
        height: image height in pixels.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"Camera width/height must be positive, got {self.width}x{self.height}")
        vals = np.array([self.fx, self.fy, self.cx, self.cy], dtype=np.float64)
        if not np.all(np.isfinite(vals)) or self.fx <= 0 or self.fy <= 0:
            raise ValueError(
                f"Camera intrinsics must be finite with positive focal lengths, got {vals.tolist()}"
            )

    @classmethod
    def from_K(cls, K: np.ndarray, width: int, height: int) -> Camera:
        """The camera of a 3x3 intrinsics matrix ``K`` and an image size."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"K must be 3x3, got shape {K.shape}")
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height))

    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsics matrix, float32."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float32)

    def scaled(self, factor: float) -> Camera:
        """The same camera for an image resized by ``factor``."""
        return Camera(
            self.fx * factor,
            self.fy * factor,
            self.cx * factor,
            self.cy * factor,
            max(1, round(self.width * factor)),
            max(1, round(self.height * factor)),
        )

    def backproject(self, depth: np.ndarray) -> np.ndarray:
        """Camera-space points [H, W, 3] for a depth map in metres (pixel centres)."""
        h, w = depth.shape
        u = np.arange(w, dtype=np.float32) + 0.5
        v = np.arange(h, dtype=np.float32) + 0.5
        uu, vv = np.meshgrid(u, v)
        x = (uu - self.cx) / self.fx * depth
        y = (vv - self.cy) / self.fy * depth
        return np.stack([x, y, depth], axis=-1).astype(np.float32)
