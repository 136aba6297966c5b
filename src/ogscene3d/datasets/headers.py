"""What an image file's first and last bytes tell without decoding it: its format, size, bit depth and
channels, and whether it ends where its format ends (a file cut short by a copy or a download does not).

A dataset reads this for every selected frame when it opens (a few hundred bytes a file), so that a broken
folder fails in seconds, naming the file, instead of when mapping reaches the frame; decoding
(:mod:`.base`) later checks the pixels themselves.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

from ..errors import DataError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_END = b"IEND\xaeB`\x82"
JPEG_START = b"\xff\xd8"
JPEG_END = b"\xff\xd9"
TAIL = 256  # bytes read from a file's end: its end marker, and the padding some encoders add after it

# PNG colour type -> channels as OpenCV decodes the file unchanged (a palette is expanded to 3 channels)
_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}
# JPEG start-of-frame markers (baseline, extended, progressive, lossless; not DHT 0xC4, JPG 0xC8, DAC 0xCC)
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
# markers without a length field: TEM, RSTn, SOI, EOI
_NO_LENGTH = {0x01, *range(0xD0, 0xDA)}


@dataclass(frozen=True)
class ImageHeader:
    """An image file's format ("png" or "jpeg"), size in pixels, bits per sample and channels."""

    kind: str
    width: int
    height: int
    bit_depth: int
    channels: int

    @property
    def size(self) -> tuple[int, int]:
        """(height, width), as a NumPy image's shape starts."""
        return self.height, self.width


def expected_kind(path: Path) -> str | None:
    """The format a file's name says it holds ("png", "jpeg"), None for another suffix (not checked)."""
    suffix = path.suffix.lower()
    return "png" if suffix == ".png" else "jpeg" if suffix in (".jpg", ".jpeg") else None


def read_header(path: Path, what: str) -> ImageHeader | None:
    """The header of the PNG or JPEG file ``path`` (``what``: "rgb", "depth", ... for messages), checked
    against its name's format and for completeness; None for a file of another format (whose name says so),
    which only decoding can check.

    Raises:
        DataError: the file is missing, empty, not of its name's format, or cut short, naming it.
    """
    path = Path(path)
    kind = expected_kind(path)
    try:
        with path.open("rb") as f:
            head = f.read(32)
            if not head:
                raise DataError(f"{path}: {what} file is empty")
            if kind is None:
                return None
            if kind == "png":
                header = _png_header(path, head, what)
                end_ok = _tail(f).rstrip(b"\x00").endswith(PNG_END)
            else:
                header = _jpeg_header(path, head, f, what)
                end_ok = JPEG_END in _tail(f)[-64:]
    except FileNotFoundError:
        raise DataError(f"{path}: {what} file is missing") from None
    except OSError as e:
        raise DataError(f"{path}: cannot read {what} file ({e})") from e
    if not end_ok:
        marker = "no IEND chunk" if kind == "png" else "no end-of-image marker"
        raise DataError(f"{path}: {what} {kind.upper()} is truncated ({marker})")
    return header


def _tail(f) -> bytes:
    size = f.seek(0, 2)
    f.seek(max(0, size - TAIL))
    return f.read()


def _png_header(path: Path, head: bytes, what: str) -> ImageHeader:
    if not head.startswith(PNG_SIGNATURE):
        raise DataError(f"{path}: {what} file is not a PNG image (its first bytes are {head[:8]!r})")
    if len(head) < 29 or head[12:16] != b"IHDR":
        raise DataError(f"{path}: {what} PNG is truncated (no IHDR header)")
    width, height, bit_depth, colour_type = struct.unpack(">IIBB", head[16:26])
    if colour_type not in _PNG_CHANNELS or not width or not height:
        raise DataError(
            f"{path}: {what} PNG has a corrupt header ({width}x{height}, colour type {colour_type})"
        )
    return ImageHeader("png", width, height, bit_depth, _PNG_CHANNELS[colour_type])


def _jpeg_header(path: Path, head: bytes, f, what: str) -> ImageHeader:
    """Walk the JPEG's marker segments (seeking over their payloads) to its start-of-frame segment."""
    if not head.startswith(JPEG_START):
        raise DataError(f"{path}: {what} file is not a JPEG image (its first bytes are {head[:8]!r})")
    f.seek(2)
    while True:
        marker = f.read(2)
        while marker[:1] == b"\xff" and marker[1:2] == b"\xff":  # fill bytes before a marker
            marker = marker[1:] + f.read(1)
        if len(marker) < 2 or marker[0] != 0xFF:
            raise DataError(f"{path}: {what} JPEG is truncated or corrupt (no frame header)")
        code = marker[1]
        if code in _NO_LENGTH:
            continue
        if code == 0xDA:  # start of scan before any frame header
            raise DataError(f"{path}: {what} JPEG is corrupt (no frame header before its image data)")
        length_bytes = f.read(2)
        if len(length_bytes) < 2:
            raise DataError(f"{path}: {what} JPEG is truncated (in its headers)")
        (length,) = struct.unpack(">H", length_bytes)
        if code in _SOF:
            body = f.read(6)
            if len(body) < 6:
                raise DataError(f"{path}: {what} JPEG is truncated (in its frame header)")
            bit_depth, height, width, channels = struct.unpack(">BHHB", body)
            if not width or not height:
                raise DataError(f"{path}: {what} JPEG has a corrupt frame header ({width}x{height})")
            return ImageHeader("jpeg", width, height, bit_depth, channels)
        f.seek(length - 2, 1)
