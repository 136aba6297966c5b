"""The lazy RGB-D dataset base class and the image/pose readers every layout shares.

A reader lists its frames once (file paths, poses, timestamps: cheap) as :class:`FrameRecord` s and
reads pixels only when a frame is asked for. Everything that can go wrong with a file raises
:class:`~ogscene3d.errors.DataError` naming the file and the problem; iteration turns that into a
logged warning and a skipped frame when ``on_bad_frame == "skip"``. What can be checked cheaply is checked
when the dataset is opened, for every selected frame, all at once: its files exist, are not empty, hold their
name's format and are not cut short (their first and last bytes, :mod:`.headers`), and its images have the
size of the other frames' (colour that of its depth, unless the layout resamples it), so that a broken folder
fails in seconds naming the files instead of when mapping reaches them.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..camera import Camera
from ..config import DataConfig
from ..errors import DataError
from ..frame import Frame, check_pose, implausible_median_depth
from ..segmentation.base import Segmentation
from ..segmentation.precomputed import has_segments, read_segmentation
from .headers import JPEG_END, PNG_END, ImageHeader, read_header

log = logging.getLogger(__name__)

DEPTH_FORMATS = ("linear", "shift3")

MISSING_LISTED = 5  # missing files named in the error; the rest are counted


# --------------------------------------------------------------------------------------- file readers


def _read_bytes(path: Path, what: str) -> bytes:
    if not path.is_file():
        raise DataError(f"{path}: {what} file is missing")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise DataError(f"{path}: cannot read {what} file ({e})") from e
    if not data:
        raise DataError(f"{path}: {what} file is empty")
    return data


def _check_complete(path: Path, data: bytes, what: str) -> None:
    """Reject truncated PNG/JPEG files (OpenCV would silently return a partly grey image)."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        if not data.rstrip(b"\x00").endswith(PNG_END):
            raise DataError(f"{path}: {what} PNG is truncated (no IEND chunk)")
    elif data[:2] == b"\xff\xd8":
        # Some encoders pad after the end-of-image marker; look for it near the end.
        if JPEG_END not in data[-64:]:
            raise DataError(f"{path}: {what} JPEG is truncated (no end-of-image marker)")


def _decode_image(path: Path, what: str) -> np.ndarray:
    """The image file ``path`` decoded as stored (any bit depth and channel count), after the checks every
    image reader makes: missing, unreadable, empty, truncated, undecodable."""
    data = _read_bytes(path, what)
    _check_complete(path, data, what)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DataError(f"{path}: cannot decode {what} image (corrupt or unsupported format)")
    return img


def read_rgb(path: str | Path) -> np.ndarray:
    """Read a colour image as uint8 [H, W, 3] RGB (grey images are replicated, alpha is dropped)."""
    path = Path(path)
    img = _decode_image(path, "rgb")
    if img.dtype != np.uint8:
        raise DataError(f"{path}: rgb image must be 8-bit, got {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    elif img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    else:
        raise DataError(f"{path}: rgb image has {img.shape[2]} channels, expected 3")
    return np.ascontiguousarray(img)


def read_depth_raw(path: str | Path) -> np.ndarray:
    """Read a single-channel 16-bit depth PNG as raw uint16 [H, W] (no scaling)."""
    path = Path(path)
    img = _decode_image(path, "depth")
    if img.ndim != 2:
        raise DataError(f"{path}: depth image must be single-channel, got shape {img.shape}")
    if img.dtype != np.uint16:
        raise DataError(f"{path}: depth image must be 16-bit, got {img.dtype}")
    return img


def decode_depth(raw: np.ndarray, depth_format: str, scale: float) -> np.ndarray:
    """Raw uint16 depth -> float32 metres (0 stays invalid).

    ``linear``: metres = raw / scale (Replica 6553.5, TUM 5000, ScanNet/7-Scenes 1000).
    ``shift3``: the APC/label-fusion bit-shifted format, metres = (raw >> 3) / scale with scale 1e4.
    """
    if depth_format == "linear":
        out = raw.astype(np.float32) / np.float32(scale)
    elif depth_format == "shift3":
        out = (raw >> 3).astype(np.float32) / np.float32(scale)
    else:
        raise DataError(f"unknown depth format {depth_format!r}; expected one of {DEPTH_FORMATS}")
    return out


def read_matrix(path: str | Path, shape: tuple[int, int], what: str = "matrix") -> np.ndarray:
    """Read a whitespace-separated text matrix (e.g. a 4x4 pose or 3x3 intrinsics) as float64."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: {what} file is missing")
    try:
        vals = np.array(path.read_text().split(), dtype=np.float64)
    except ValueError as e:
        raise DataError(f"{path}: {what} file holds non-numeric text ({e})") from e
    n = shape[0] * shape[1]
    if vals.size != n:
        # intrinsics are sometimes stored as 4x4 (ScanNet); take the upper-left block.
        if shape == (3, 3) and vals.size == 16:
            return vals.reshape(4, 4)[:3, :3]
        raise DataError(f"{path}: expected {n} numbers for a {shape[0]}x{shape[1]} {what}, found {vals.size}")
    return vals.reshape(shape)


def K_from_values(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float32)


PIXEL_CENTERS = ("integer", "half")


def to_half_pixel_K(K: np.ndarray, pixel_centers: str) -> np.ndarray:
    """``K`` in ogscene3d's convention (pixel (0, 0)'s centre at (0.5, 0.5), :mod:`ogscene3d.camera`) from
    one whose ``pixel_centers`` are ``"integer"`` (OpenCV: (0, 0)) or already ``"half"``."""
    if pixel_centers == "half":
        return K
    K = K.copy()
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    return K


def check_K(K: np.ndarray, source: str) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise DataError(
            f"{source}: intrinsics must be a finite 3x3 matrix with positive focal lengths, got {K}"
        )
    return K.astype(np.float32)


def quat_to_matrix(q_xyzw: np.ndarray, normalize: bool = True) -> np.ndarray:
    """Rotation matrices [..., 3, 3] from quaternions [..., 4] in (x, y, z, w) order (TUM).

    With ``normalize=False`` a non-unit quaternion gives a non-orthonormal matrix (so that a
    pose check can reject it instead of silently accepting a corrupt value).
    """
    q = np.asarray(q_xyzw, dtype=np.float64)
    if normalize:
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )  # fmt: skip
    return R.reshape(q.shape[:-1] + (3, 3))


# --------------------------------------------------------------------------------------- dataset


@dataclass
class FrameRecord:
    """What a reader knows about a frame before reading pixels.

    ``pose`` is the raw c2w matrix, or ``pose_path`` a 4x4 text file read with the frame; either is
    validated when the frame is read, so that one bad pose fails (or skips) one frame only.
    ``pose_source`` names where the pose came from for error messages.
    """

    name: str
    rgb_path: Path
    depth_path: Path
    pose: np.ndarray | None = None
    pose_source: str = ""
    pose_path: Path | None = None
    pose_error: str | None = None  # why the layout's pose of this frame could not be read (file:line ...)
    # why the frame cannot be mapped though its files are there (a TUM frame without a pose near its stamp):
    # named with the frames whose files are missing or broken when the dataset opens
    lacks: str | None = None
    timestamp: float = 0.0
    extras: dict[str, Path] = field(default_factory=dict)


class RGBDDataset:
    """A lazy, indexable sequence of :class:`~ogscene3d.frame.Frame`.

    ``len(ds)`` is the number of selected frames, ``ds[i]`` reads frame ``i`` (raising
    :class:`DataError` if it is bad, whatever ``on_bad_frame`` says), and iterating yields the
    frames in order, skipping bad ones with a warning when ``on_bad_frame == "skip"``.
    ``Frame.index`` is the position in this selection; ``Frame.name`` the rgb file stem. ``K`` is in
    ogscene3d's convention (pixel (0, 0)'s centre at (0.5, 0.5)): intrinsics the layout reads in the
    OpenCV one (``pixel_centers`` "integer") are shifted by half a pixel.
    """

    kind = "base"
    # the class id a layout's class maps use for "no class", which no class table names (None: every id may)
    void_class_id: int | None = None
    depth_scale_default = 1000.0
    # the convention of the intrinsics a layout reads (see DataConfig.pixel_centers): the calibrated-sensor
    # layouts' files count pixel centres from 0, as OpenCV calibrations do; Replica, synthetic and
    # Semantic-NeRF read theirs as they are ("half")
    pixel_centers_default = "integer"
    depth_format_default = "linear"
    min_depth_default = 0.0
    invalid_raw: int | None = None  # a raw depth value that means "no measurement" (7-Scenes: 65535)
    # the world up direction of the format's poses (graph.up_axis auto, ogscene3d.up_axis), and what says so;
    # None: the format defines none (7-Scenes' world is its first camera's, pitched as it was)
    up_axis: tuple[float, float, float] | None = None
    up_axis_source = ""
    # the files (a trailing "/": folders) whose presence marks a folder as this layout, for detect()
    layout_markers: tuple[str, ...] = ()

    @classmethod
    def detect(cls, root: Path) -> bool:
        """Whether ``root`` holds this layout: every one of ``layout_markers`` is there (none: never)."""
        return bool(cls.layout_markers) and all(
            (root / m).is_dir() if m.endswith("/") else (root / m).is_file() for m in cls.layout_markers
        )

    def __init__(
        self,
        root: Path,
        records: list[FrameRecord],
        K: np.ndarray | None,
        config: DataConfig,
        segments_dir: Path | None = None,
        resize_rgb_to_depth: bool = False,
    ) -> None:
        self.root = Path(root)
        self.config = config
        if not records:
            raise DataError(f"{self.root}: no frames found for the {self.kind} layout")
        if config.start < 0 or config.stride < 1:
            raise DataError(
                f"data.start must be >= 0 and data.stride >= 1, got {config.start}, {config.stride}"
            )
        if config.max_frames is not None and config.max_frames < 1:
            raise DataError(f"data.max_frames must be >= 1 or null, got {config.max_frames}")
        if config.on_bad_frame not in ("error", "skip"):
            raise DataError(f"data.on_bad_frame must be 'error' or 'skip', got {config.on_bad_frame!r}")
        selected = records[config.start :: config.stride]
        if config.max_frames is not None:
            selected = selected[: config.max_frames]
        if not selected:
            raise DataError(
                f"{self.root}: frame range start={config.start} stride={config.stride} selects none of "
                f"{len(records)} frames"
            )
        # frames of the selection left out when opened (files missing or broken, under on_bad_frame: skip): a
        # run's count of skipped frames starts from this; frames skipped while iterating come on top
        self.frames_left_out = 0
        self.resize_rgb_to_depth = resize_rgb_to_depth
        self._header_size: tuple[int, int] | None = None  # (h, w) of the depth images, from their headers
        self.records = self._drop_incomplete(selected)
        if config.intrinsics is not None:
            if len(config.intrinsics) != 4:
                raise DataError(f"data.intrinsics must be [fx, fy, cx, cy], got {config.intrinsics}")
            K = K_from_values(*config.intrinsics)
        if K is None:
            raise DataError(
                f"{self.root}: no camera intrinsics found; give data.intrinsics = [fx, fy, cx, cy]"
            )
        self.pixel_centers = self.read_pixel_centers(config)
        self.K = to_half_pixel_K(check_K(K, str(self.root)), self.pixel_centers)
        self._scaled_size: tuple[int, int] | None = None  # (h, w) of the frames under data.scale
        self.depth_scale = float(
            config.depth_scale if config.depth_scale is not None else self.depth_scale_default
        )
        if not np.isfinite(self.depth_scale) or self.depth_scale <= 0:
            raise DataError(f"depth scale must be a positive number, got {self.depth_scale}")
        self.depth_format = (
            config.depth_format if config.depth_format != "auto" else self.depth_format_default
        )
        if self.depth_format not in DEPTH_FORMATS:
            raise DataError(
                f"data.depth_format must be 'auto' or one of {DEPTH_FORMATS}, got {config.depth_format!r}"
            )
        self.min_depth = config.min_depth if config.min_depth > 0 else self.min_depth_default
        self.max_depth = config.max_depth
        self.segments_dir = Path(segments_dir) if segments_dir is not None else None
        if self.segments_dir is not None and not self.segments_dir.is_dir():
            raise DataError(f"{self.segments_dir}: segments folder does not exist")
        self._depth_checked = False
        self._size_checked = False
        self._warned_no_segments = False
        if self._header_size is not None:  # K against the images' size, now rather than at the first frame
            self._size_checked = True
            self._check_principal_point(self._header_size, self.records[0].depth_path)
        self._apply_scale(config.scale)

    def _apply_scale(self, scale: float) -> None:
        """Frames resized by ``scale`` (``data.scale``): K scaled to the new size (exact with pixel centres
        at +0.5: a resize maps pixel edges onto pixel edges)."""
        if not (0 < scale <= 1):
            raise DataError(f"data.scale must be in (0, 1], got {scale}")
        if scale == 1:
            return
        h, w = self._native_size()
        sh, sw = max(1, round(h * scale)), max(1, round(w * scale))
        self._scaled_size = (sh, sw)
        K = self.K.astype(np.float64).copy()
        K[0] *= sw / w
        K[1] *= sh / h
        self.K = K.astype(np.float32)

    def _native_size(self) -> tuple[int, int]:
        """(h, w) of the frames as stored (the depth images')."""
        if self._header_size is not None:
            return self._header_size
        return read_depth_raw(self.records[0].depth_path).shape
    def read_pixel_centers(self, config: DataConfig) -> str:
        """The convention of the intrinsics this dataset reads: ``data.pixel_centers`` or the layout's."""
        conv = self.pixel_centers_default if config.pixel_centers == "auto" else config.pixel_centers
        if conv not in PIXEL_CENTERS:
            raise DataError(
                f"data.pixel_centers must be 'auto' or one of {PIXEL_CENTERS}, got {config.pixel_centers!r}"
            )
        return conv

    def _drop_incomplete(self, selected: list[FrameRecord]) -> list[FrameRecord]:
        """``selected`` less the frames that cannot be mapped, found now rather than when mapping reaches them
        (maybe hours in): a file missing, empty, not of its name's format or cut short, an image of another
        size than the other frames' (colour than its depth, where the layout does not resample it), or what
        the reader found lacking (:attr:`FrameRecord.lacks`). They are a :class:`DataError` naming them all,
        or, when ``on_bad_frame == "skip"``, one warning and those frames left out. Reads each image file's
        first and last bytes only (:mod:`.headers`), a few hundred bytes a file."""
        missing: dict[int, list[Path]] = {}
        broken: dict[int, list[str]] = {}
        unusable: dict[int, str] = {}
        depth_heads: dict[int, ImageHeader] = {}
        rgb_heads: dict[int, ImageHeader] = {}
        for k, rec in enumerate(selected):
            gone = _missing_files(rec)
            if gone:
                missing[k] = gone
            files = ((rec.rgb_path, "rgb", rgb_heads), (rec.depth_path, "depth", depth_heads))
            for path, what, heads in files:
                if path in gone:
                    continue
                try:
                    head = read_header(path, what)
                except DataError as e:
                    broken.setdefault(k, []).append(self._relative_message(e, path))
                    continue
                problem = _format_problem(head, what) if head is not None else None
                if problem is not None:
                    broken.setdefault(k, []).append(f"{self._relative(path)}: {problem}")
                elif head is not None:
                    heads[k] = head
            if rec.lacks is not None:
                unusable[k] = f"{self._relative(rec.rgb_path)}: {rec.lacks}"
        self._check_sizes(selected, depth_heads, rgb_heads, broken)
        bad = set(missing) | set(broken) | set(unusable)
        if not bad:
            return selected
        msg = self._bad_frames_message(len(bad), len(selected), missing, broken, unusable)
        kept = [rec for k, rec in enumerate(selected) if k not in bad]
        if self.config.on_bad_frame == "skip" and kept:
            log.warning("%s; leaving those frames out (data.on_bad_frame: skip)", msg)
            self.frames_left_out = len(bad)
            return kept
        if self.config.on_bad_frame == "skip":
            raise DataError(f"{msg}; no selected frame is left")
        raise DataError(f"{msg}; set data.on_bad_frame: skip to leave those frames out")

    def _check_sizes(
        self,
        selected: list[FrameRecord],
        depth_heads: dict[int, ImageHeader],
        rgb_heads: dict[int, ImageHeader],
        broken: dict[int, list[str]],
    ) -> None:
        """Add to ``broken`` the frames whose depth image has another size than most frames' (the size the
        intrinsics are for), or whose colour image has another size than its depth (than most colour images,
        where the layout resamples colour to depth); sets ``_header_size``."""
        if not depth_heads:
            return
        sizes = Counter(h.size for h in depth_heads.values())
        size = sizes.most_common(1)[0][0]
        self._header_size = size
        rgb_size = Counter(h.size for h in rgb_heads.values()).most_common(1)[0][0] if rgb_heads else None
        for k, head in depth_heads.items():
            if head.size != size:
                broken.setdefault(k, []).append(
                    f"{self._relative(selected[k].depth_path)}: depth is {head.width}x{head.height}, the "
                    f"other frames' {size[1]}x{size[0]}"
                )
        for k, head in rgb_heads.items():
            want = rgb_size if self.resize_rgb_to_depth else getattr(depth_heads.get(k), "size", None)
            if want is not None and head.size != want:
                whose = "the other frames'" if self.resize_rgb_to_depth else "its depth image"
                broken.setdefault(k, []).append(
                    f"{self._relative(selected[k].rgb_path)}: rgb is {head.width}x{head.height}, {whose} "
                    f"{want[1]}x{want[0]}"
                )

    def _bad_frames_message(
        self,
        bad: int,
        selected: int,
        missing: dict[int, list[Path]],
        broken: dict[int, list[str]],
        unusable: dict[int, str],
    ) -> str:
        """The message naming the frames that cannot be mapped: the missing files, the broken ones, then the
        frames that lack something else."""
        files = [p for paths in missing.values() for p in paths]
        problems = [p for k in sorted(broken) for p in broken[k]]
        parts = []
        if files:
            parts.append(f"{len(files)} missing: {_listed([self._relative(p) for p in files])}")
        if problems:
            parts.append(f"{len(problems)} broken: {_listed(problems)}")
        if unusable:
            parts.append(f"{len(unusable)} unusable: {_listed([unusable[k] for k in sorted(unusable)])}")
        what = "lack files" if not problems and not unusable else "cannot be mapped"
        head = f"{self.root}: {bad} of the {selected} selected frames {what} ({self.kind} layout)"
        return head + "; " + "; ".join(parts)

    def _relative_message(self, e: DataError, path: Path) -> str:
        """A file's error with the file named below the dataset folder."""
        text = str(e)
        return self._relative(path) + text[len(str(path)) :] if text.startswith(str(path)) else text

    def _relative(self, path: Path) -> str:
        """``path`` below the dataset folder (named at the start of messages), else in full."""
        try:
            return str(path.relative_to(self.root))
        except ValueError:
            return str(path)

    # -- sequence protocol

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, i: int) -> Frame:
        if not isinstance(i, int | np.integer):
            raise TypeError(f"dataset indices must be integers, got {type(i).__name__}")
        n = len(self.records)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"frame index {i} out of range for {n} frames")
        return self._load(int(i))

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def frames(self, start: int = 0) -> Iterator[Frame]:
        """The frames from position ``start`` on (a resumed run), in order; a bad frame raises its
        :class:`DataError`, or is skipped with a warning when ``on_bad_frame == "skip"``."""
        for i in range(start, len(self.records)):
            try:
                frame = self._load(i)
            except DataError as e:
                if self.config.on_bad_frame == "skip":
                    log.warning("skipping frame %d (%s): %s", i, self.records[i].name, e)
                    continue
                raise
            yield frame

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.root)!r}, {len(self)} frames)"

    @property
    def camera(self) -> Camera:
        """Camera of the first frame (reads its depth image for the size)."""
        h, w = self._scaled_size or read_depth_raw(self.records[0].depth_path).shape
        return Camera.from_K(self.K, w, h)

    # -- reading

    def _load(self, i: int) -> Frame:
        rec = self.records[i]
        raw = read_depth_raw(rec.depth_path)
        depth = decode_depth(raw, self.depth_format, self.depth_scale)
        if self.invalid_raw is not None:
            depth[raw == self.invalid_raw] = 0.0
        return self._frame(
            i,
            rec,
            depth,
            rec.depth_path,
            lambda: read_rgb(rec.rgb_path),
            sizes=f"{rec.rgb_path}: rgb is {{rgb}}, depth {rec.depth_path.name} is {{depth}}",
            name=rec.rgb_path.stem,
        )

    def _frame(
        self,
        i: int,
        rec: FrameRecord,
        depth: np.ndarray,
        where: Path,
        read_rgb_image: Callable[[], np.ndarray],
        sizes: str,
        name: str,
    ) -> Frame:
        """The frame of ``rec`` from its depth in metres (``where``: named in the depth checks' warnings) and
        its colour, read by ``read_rgb_image`` after the depth checks: depth range, min/max depth, colour at
        the depth size (``sizes``: the mismatch message, with ``{rgb}`` and ``{depth}`` as WxH), pose,
        segments, ground truth. Every layout's reader ends here."""
        if not self._depth_checked:
            self._depth_checked = self._check_depth_range(depth, where)
        if not self._size_checked:
            self._size_checked = True
            self._check_principal_point(depth.shape, where)
        if self.min_depth > 0:
            depth[depth < self.min_depth] = 0.0
        if self.max_depth > 0:
            depth[depth > self.max_depth] = 0.0
        rgb = read_rgb_image()
        rgb_shape = rgb.shape[:2]
        if rgb_shape != depth.shape:
            if not self.resize_rgb_to_depth:
                raise DataError(
                    sizes.format(
                        rgb=f"{rgb.shape[1]}x{rgb.shape[0]}", depth=f"{depth.shape[1]}x{depth.shape[0]}"
                    )
                )
            rgb = cv2.resize(rgb, (depth.shape[1], depth.shape[0]), interpolation=cv2.INTER_AREA)
        pose = _read_pose(rec)
        segments, scores, names = None, {}, {}
        if self.segments_dir is not None:
            seg = self._read_segments(rec, depth.shape, rgb_shape)
            if seg is not None:
                segments, scores, names = seg.ids, seg.scores, seg.names
        gt_instances, gt_classes = self._load_gt(rec, depth.shape)
        if self._scaled_size is not None:
            depth, rgb, segments, gt_instances, gt_classes = _resized(
                self._scaled_size, depth, rgb, segments, gt_instances, gt_classes
            )
            if segments is not None:
                present = {int(i) for i in np.unique(segments) if i != 0}
                scores = {i: v for i, v in scores.items() if i in present}
                names = {i: v for i, v in names.items() if i in present}
        return Frame(
            index=i,
            rgb=np.ascontiguousarray(rgb),
            depth=depth,
            K=self.K,
            pose=pose,
            timestamp=rec.timestamp,
            name=name,
            segments=segments,
            segment_scores=scores,
            segment_names=names,
            gt_instances=gt_instances,
            gt_classes=gt_classes,
            depth_scale_checked=True,  # _check_depth_range warns: the mapper need not warn again
        )

    def pose(self, i: int) -> np.ndarray | None:
        """Frame ``i``'s camera-to-world pose, read without its pixels; None where the layout gives none.

        Raises:
            DataError: the pose is unreadable, non-finite or not rigid (naming its file).
        """
        return _read_pose(self.records[i])

    def has_valid_pose(self, i: int) -> bool:
        """Whether frame ``i`` has a finite rigid camera pose, reading its pose only (no pixels): real
        sequences mark lost tracking with a non-finite pose (ScanNet writes -inf), and a caller choosing
        frames to render must pass over those without reading every image."""
        try:
            return self.pose(i) is not None
        except DataError:
            return False

    def _read_segments(
        self, rec: FrameRecord, shape: tuple[int, int], rgb_shape: tuple[int, int] | None = None
    ) -> Segmentation | None:
        """The frame's precomputed segments, or None when it has no segments file: the mapper's
        segmentation.backend then segments it live (frames may be segmented in part, e.g. while
        ``ogscene3d segment`` is still running). A corrupt or wrong-size file is an error.

        ``shape`` is the frame's size; ``rgb_shape`` the RGB file's, where colour is resampled to the depth
        size (ScanNet): segments of the RGB file's size (a SAM run on the colour images, as the design's
        "same size as the RGB image" has them) are resampled with it by nearest neighbour, and segments of
        the frame's size (what ``ogscene3d segment`` writes) are read as they are."""
        assert self.segments_dir is not None
        stem = rec.rgb_path.stem
        if self._scaled_size is not None and has_segments(self.segments_dir, stem):
            seg = read_segmentation(self.segments_dir, stem)
            if seg.ids.shape == self._scaled_size:  # segmented at data.scale (`ogscene3d segment` with it)
                return seg
        if not has_segments(self.segments_dir, stem):
            if not self._warned_no_segments:
                log.warning(
                    "%s: no segments file for frame %s (%s.png); frames without one are segmented live by "
                    "segmentation.backend (warned once)",
                    self.segments_dir,
                    rec.name,
                    stem,
                )
                self._warned_no_segments = True
            return None
        if rgb_shape is None or tuple(rgb_shape) == tuple(shape):
            return read_segmentation(self.segments_dir, stem, shape)
        seg = read_segmentation(self.segments_dir, stem)
        if seg.ids.shape == tuple(shape):
            return seg
        if seg.ids.shape != tuple(rgb_shape):
            raise DataError(
                f"{self.segments_dir / (stem + '.png')}: segments are {seg.ids.shape[1]}x{seg.ids.shape[0]}, "
                f"the RGB image is {rgb_shape[1]}x{rgb_shape[0]} and the frame (resampled to the depth "
                f"size) {shape[1]}x{shape[0]}"
            )
        # nearest neighbour at pixel centres, as read_label_png resamples ScanNet's label images
        ids = cv2.resize(seg.ids, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST_EXACT)
        present = {int(i) for i in np.unique(ids) if i != 0}
        return Segmentation(
            ids=ids,
            scores={i: v for i, v in seg.scores.items() if i in present},
            names={i: v for i, v in seg.names.items() if i in present},
        )

    def _check_depth_range(self, depth: np.ndarray, path: Path) -> bool:
        """Warn once when the first frame with depth has a median outside what an RGB-D camera sees (a wrong
        depth scale or format maps a room to kilometres or millimetres). -> whether a frame was checked."""
        if not np.any(depth > 0):
            return False
        median = implausible_median_depth(depth)
        if median is not None:
            log.warning(
                "%s: median depth %.3g m is implausible for an RGB-D camera; check data.depth_scale "
                "(now %g raw units per metre) and data.depth_format (now %s)",
                path,
                median,
                self.depth_scale,
                self.depth_format,
            )
        return True

    def check_image_size(self, size: tuple[int, int], source: Path) -> None:
        """Check the (width, height) that ``source`` (a camera file) gives against the images: the first
        frame whose depth image reads (a bad frame is the frames' business, not the camera file's).

        Raises:
            DataError: the sizes differ, naming ``source``, both sizes and the image; the intrinsics in
                ``source`` are then most likely another image size's.
        """
        for rec in self.records:
            try:
                h, w = read_depth_raw(rec.depth_path).shape
            except DataError:
                continue
            if (w, h) != tuple(size):
                raise DataError(
                    f"{source}: the camera is {size[0]}x{size[1]} (w x h), but the images are {w}x{h} "
                    f"({self._relative(rec.depth_path)}); fix w and h (and the intrinsics, most likely "
                    "another image size's), or give data.intrinsics = [fx, fy, cx, cy] for these images"
                )
            return

    def _check_principal_point(self, shape: tuple[int, int], path: Path) -> None:
        """Warn once when K's principal point is far from the centre of the first frame's depth image: K is
        then most likely another image size's (e.g. a colour camera's K with depth of a smaller size, which
        nothing else would notice), and every back-projected point is off."""
        h, w = shape
        cx, cy = float(self.K[0, 2]), float(self.K[1, 2])
        if abs(cx - w / 2) > 0.25 * w or abs(cy - h / 2) > 0.25 * h:
            log.warning(
                "%s: the intrinsics' principal point (%.1f, %.1f) is far from the centre of the %dx%d depth "
                "image: are they another image size's (e.g. the colour camera's)? Frames are back-projected "
                "with K of the depth image (colour is resampled to it); give data.intrinsics for that size",
                path,
                cx,
                cy,
                w,
                h,
            )

    def _load_gt(
        self, rec: FrameRecord, shape: tuple[int, int]
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Ground-truth (instance map, class map) for layouts that have them; None otherwise."""
        return None, None

    @property
    def class_names(self) -> dict[int, str] | None:
        """Class id -> name of the ids in ``Frame.gt_classes``, when the layout defines them (None: the
        data set's own table must be given, e.g. label-fusion's)."""
        return None

    @property
    def has_class_maps(self) -> bool:
        """Whether frames come with ground-truth class maps (``Frame.gt_classes``), as far as the files
        say (nothing is read): what eval's rendered-view scores need."""
        return False


def numbered_files(folder: Path, suffixes: tuple[str, ...] = (".png",), prefix: str = "") -> dict[int, Path]:
    """{frame number: file} for the files ``<prefix><digits><suffix>`` in ``folder``, whatever the
    zero-padding (``0.png`` and ``000000.png`` are both frame 0; ``rgb_`` matches ``rgb_12.png``, not
    ``vis_rgb_12.png``); two files with one number are an error."""
    out: dict[int, Path] = {}
    if not folder.is_dir():
        return out
    for p in sorted(folder.iterdir()):
        digits = p.stem[len(prefix) :]
        if p.suffix.lower() not in suffixes or not p.stem.startswith(prefix) or not digits.isdigit():
            continue
        n = int(digits)
        if n in out:
            raise DataError(f"{folder}: {out[n].name} and {p.name} are both frame {n}; remove one")
        out[n] = p
    return out


def _read_pose(rec: FrameRecord) -> np.ndarray | None:
    """The frame's c2w pose, checked (a finite rigid 4x4; DataError naming its source otherwise), or None
    when the layout gives the frame none."""
    if rec.pose_error is not None:
        raise DataError(rec.pose_error)
    raw = read_matrix(rec.pose_path, (4, 4), "pose") if rec.pose_path is not None else rec.pose
    if raw is None:
        return None
    try:
        return check_pose(raw, rec.pose_source or str(rec.pose_path or f"pose of frame {rec.name}"))
    except ValueError as e:
        raise DataError(str(e)) from e


def _resized(size: tuple[int, int], depth, rgb, segments, gt_instances, gt_classes) -> tuple:
    """The frame's images at ``size`` (h, w) (``data.scale``): colour by area, depth and every id map by the
    nearest pixel (a depth between two surfaces, or an id between two segments, is neither); those already at
    ``size`` as they are."""
    h, w = size

    def nearest(img):
        if img is None or img.shape[:2] == (h, w):
            return img
        return cv2.resize(img, (w, h), interpolation=cv2.INTER_NEAREST_EXACT)

    colour = rgb if rgb.shape[:2] == (h, w) else cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)
    return nearest(depth), colour, nearest(segments), nearest(gt_instances), nearest(gt_classes)


def _listed(items: list[str]) -> str:
    """The first :data:`MISSING_LISTED` of ``items``, and how many more there are."""
    named = ", ".join(items[:MISSING_LISTED])
    return named + (f" and {len(items) - MISSING_LISTED} more" if len(items) > MISSING_LISTED else "")


def _format_problem(head: ImageHeader, what: str) -> str | None:
    """What the header of an image says is wrong for its use (None: nothing), as decoding would say it."""
    if what == "depth":
        if head.channels != 1:
            return f"depth image must be single-channel, got {head.channels} channels"
        if head.bit_depth != 16:
            return f"depth image must be 16-bit, got {head.bit_depth}-bit"
        return None
    if head.bit_depth != 8:
        return f"rgb image must be 8-bit, got {head.bit_depth}-bit"
    if head.channels not in (1, 3, 4):
        return f"rgb image has {head.channels} channels, expected 3"
    return None


def _missing_files(rec: FrameRecord) -> list[Path]:
    """The files ``rec`` needs that do not exist (a stat each; nothing is read)."""
    paths = [rec.rgb_path, rec.depth_path]
    if rec.pose_path is not None:
        paths.append(rec.pose_path)
    return [p for p in paths if not p.is_file()]


def read_label_png(
    path: Path,
    shape: tuple[int, int],
    what: str,
    transform: Callable | None = None,
    resize: bool = False,
) -> np.ndarray:
    """Read an 8/16-bit single-channel label PNG as int32 [H, W], checking its size.

    ``resize``: a label image of another size but the same aspect ratio (within 2%) is resampled to
    ``shape`` by nearest neighbour (ScanNet's label images have the colour camera's size, and colour is
    resampled to depth's); otherwise the size must be ``shape``.
    """
    img = _decode_image(path, what)
    if img.ndim != 2:
        raise DataError(f"{path}: {what} image must be single-channel, got shape {img.shape}")
    if img.shape != tuple(shape):
        aspect, target = img.shape[1] / img.shape[0], shape[1] / shape[0]
        if not resize or abs(aspect / target - 1.0) > 0.02:
            raise DataError(
                f"{path}: {what} is {img.shape[1]}x{img.shape[0]}, the depth image is {shape[1]}x{shape[0]}"
            )
        # Nearest neighbour, so that label ids are not blended; the _EXACT variant samples at the pixel
        # centres as INTER_AREA does for colour (INTER_NEAREST takes each block's top-left source pixel:
        # at ScanNet's 1296 -> 640 the labels would sit half a pixel up and left of the colour).
        img = cv2.resize(img, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST_EXACT)
    out = img.astype(np.int32)
    return transform(out) if transform is not None else out


def frame_number(stem: str) -> int:
    """The trailing integer of a file stem (``frame000012`` -> 12, ``frame-000012.color`` -> 12)."""
    digits = ""
    for ch in reversed(stem.split(".")[0]):
        if ch.isdigit():
            digits = ch + digits
        elif digits:
            break
    if not digits:
        raise DataError(f"file name {stem!r} holds no frame number")
    return int(digits)
