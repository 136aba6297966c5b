"""A dataset whose frames are decoded from a container (a ROS bag, a Record3D capture) rather than read from
one image file each.

Such a reader lists :class:`FrameRecord` s as the folder layouts do (their ``rgb_path`` is the container
path joined with the frame name: a name to look segments up by and to record in a run, not a file) and
implements :meth:`DecodedDataset._read_arrays`; selection, depth checks, poses, segments and
``on_bad_frame`` work as for every other layout.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..camera import Camera
from ..errors import DataError
from ..frame import Frame
from .base import FrameRecord, RGBDDataset, _read_pose


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

    @property
    def camera(self) -> Camera:
        h, w = self._image_size()
        return Camera.from_K(self.K, w, h)

    def _load(self, i: int) -> Frame:
        rec = self.records[i]
        rgb, depth = self._read_arrays(rec)
        depth = np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
        depth[depth < 0] = 0.0
        where = self.root / rec.name
        if not self._depth_checked:
            self._depth_checked = self._check_depth_range(depth, where)
        if not self._size_checked:
            self._size_checked = True
            self._check_principal_point(depth.shape, where)
        if self.min_depth > 0:
            depth[depth < self.min_depth] = 0.0
        if self.max_depth > 0:
            depth[depth > self.max_depth] = 0.0
        if not rgb.flags.writeable:  # a view of a message's buffer: the frame owns its pixels
            rgb = rgb.copy()
        rgb_shape = rgb.shape[:2]
        if rgb_shape != depth.shape:
            if not self.resize_rgb_to_depth:
                raise DataError(
                    f"{where}: rgb is {rgb.shape[1]}x{rgb.shape[0]}, "
                    f"depth is {depth.shape[1]}x{depth.shape[0]}"
                )
            rgb = cv2.resize(rgb, (depth.shape[1], depth.shape[0]), interpolation=cv2.INTER_AREA)
        pose = _read_pose(rec)
        segments, scores, names = None, {}, {}
        if self.segments_dir is not None:
            seg = self._read_segments(rec, depth.shape, rgb_shape)
            if seg is not None:
                segments, scores, names = seg.ids, seg.scores, seg.names
        return Frame(
            index=i,
            rgb=np.ascontiguousarray(rgb),
            depth=depth,
            K=self.K,
            pose=pose,
            timestamp=rec.timestamp,
            name=rec.name,
            segments=segments,
            segment_scores=scores,
            segment_names=names,
            depth_scale_checked=True,
        )
