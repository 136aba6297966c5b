"""A dataset whose frames are decoded from a container (a ROS bag, a Record3D capture) rather than read from
one image file each.

Such a reader lists :class:`FrameRecord` s as the folder layouts do (their ``rgb_path`` is the container
path joined with the frame name: a name to look segments up by and to record in a run, not a file) and
implements :meth:`DecodedDataset._read_arrays`; selection, depth checks, poses, segments and
``on_bad_frame`` work as for every other layout.
"""

from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..frame import Frame
from .base import FrameRecord, RGBDDataset


class DecodedDataset(RGBDDataset):
    """:class:`RGBDDataset` over frames that a subclass decodes to arrays."""

    def _read_arrays(self, rec: FrameRecord) -> tuple[np.ndarray, np.ndarray]:
        """(rgb uint8 [H, W, 3], depth float32 [h, w] in metres, 0 = invalid) of ``rec``; DataError naming
        the container and the frame when it cannot be decoded."""
        raise NotImplementedError

    def _image_size(self) -> tuple[int, int]:
        """(height, width) of the frames' depth images, known without decoding a frame."""
        raise NotImplementedError

    def _drop_incomplete(self, selected: list[FrameRecord]) -> list[FrameRecord]:
        return selected  # no per-frame files: what a container lacks its reader reports when it opens

    def _native_size(self) -> tuple[int, int]:
        return self._image_size()

    @property
    def camera(self) -> Camera:
        h, w = self._scaled_size or self._image_size()
        return Camera.from_K(self.K, w, h)

    def _load(self, i: int) -> Frame:
        rec = self.records[i]
        rgb, depth = self._read_arrays(rec)
        depth = np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
        depth[depth < 0] = 0.0
        where = self.root / rec.name
        # a view of a message's buffer: the frame owns its pixels
        colour = rgb if rgb.flags.writeable else rgb.copy()
        sizes = f"{where}: rgb is {{rgb}}, depth is {{depth}}"
        return self._frame(i, rec, depth, where, lambda: colour, sizes=sizes, name=rec.name)
