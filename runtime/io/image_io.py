"""Safe decoding of PNG and JPEG files: check the header and the file's end before decoding.

Why not just ``cv2.imread``: it returns None without saying why, some builds decode a truncated
file partially (a grey or black bottom), and it decodes whatever size the header claims (a
small file can claim 60000 x 60000 pixels: a decompression bomb). Here the header is parsed
first (PNG ``IHDR``, JPEG ``SOFn``), the size is checked against ``MAX_IMAGE_SIDE`` and
``MAX_IMAGE_PIXELS``, the file's structure is checked to its end (PNG: every chunk complete up to
``IEND``; JPEG: ends with the ``EOI`` marker), and only then is the image decoded. Every problem
is an ``InputError("PATH: problem")``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from a3d.runtime.errors import InputError

MAX_IMAGE_SIDE = 8192
"""Largest accepted width or height, pixels."""
MAX_IMAGE_PIXELS = 4096 * 4096
"""Largest accepted width x height (16.8 MP); a depth ``.npy`` is held to the same limit."""

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_SOI = b"\xff\xd8"
_JPEG_EOI = b"\xff\xd9"
# SOFn markers that carry the frame size (C4 = DHT, C8 = JPG, CC = DAC are not frames).
_JPEG_SOF = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF})
# Markers without a length field.
_JPEG_STANDALONE = frozenset({0x01, *range(0xD0, 0xD8)})
# PNG colour type -> channels (0 grey, 2 RGB, 3 palette, 4 grey + alpha, 6 RGBA).
_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}


@dataclass(frozen=True)
class ImageHeader:
    """What a PNG or JPEG header says: format, size, bits per sample and channels."""

    kind: str  # "png" or "jpeg"
    height: int
    width: int
    bit_depth: int  # bits per sample (PNG palette images: bits per index)
    channels: int  # as stored: 1 grey, 2 grey + alpha, 3 colour (palette included), 4 colour + alpha

    @property
    def size(self) -> tuple[int, int]:
        """(height, width)."""
        return self.height, self.width


def read_bytes(path: Path) -> bytes:
    """The whole file; an unreadable or empty file is an InputError."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as error:
        raise InputError(f"{path}: cannot read: {error.strerror or error}") from None
    if not data:
        raise InputError(f"{path}: file is empty (0 bytes)")
    return data


def parse_header(data: bytes, path: Path) -> ImageHeader:
    """Parse the PNG or JPEG header of ``data`` and check its size limits (nothing is decoded)."""
    if data.startswith(_PNG_SIGNATURE):
        header = _png_header(data, path)
    elif data.startswith(_JPEG_SOI):
        header = _jpeg_header(data, path)
    else:
        raise InputError(f"{path}: not a PNG or JPEG file (unknown signature {data[:8]!r})")
    if header.width <= 0 or header.height <= 0:
        raise InputError(f"{path}: header gives an empty image ({header.height}x{header.width})")
    if max(header.width, header.height) > MAX_IMAGE_SIDE or header.width * header.height > MAX_IMAGE_PIXELS:
        raise InputError(
            f"{path}: image is {header.height}x{header.width}, above the limit "
            f"({MAX_IMAGE_SIDE} px a side, {MAX_IMAGE_PIXELS} pixels); not decoded"
        )
    return header


def check_complete(data: bytes, header: ImageHeader, path: Path) -> None:
    """Raise if the file is cut short: PNG chunks must be whole up to IEND, a JPEG must end in EOI."""
    if header.kind == "png":
        pos = len(_PNG_SIGNATURE)
        while True:
            if pos + 8 > len(data):
                raise InputError(f"{path}: PNG is truncated (no IEND chunk; file ends at byte {len(data)})")
            length, kind = struct.unpack(">I4s", data[pos : pos + 8])
            end = pos + 12 + length
            if end > len(data):
                raise InputError(
                    f"{path}: PNG is truncated ({kind.decode('latin-1')} chunk needs {end} bytes, "
                    f"file has {len(data)})"
                )
            if kind == b"IEND":
                return
            pos = end
    elif not data.rstrip(b"\x00").endswith(_JPEG_EOI):
        raise InputError(f"{path}: JPEG is truncated (no end-of-image marker)")


def decode_image(data: bytes, path: Path, flags: int) -> np.ndarray:
    """Decode ``data`` (already checked) with ``cv2.imdecode``; a failure is an InputError."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if image is None:
        raise InputError(f"{path}: cannot decode the image (corrupt data)")
    return image


def read_uint16_png(path: Path, what: str = "depth") -> np.ndarray:
    """A 1-channel 16-bit PNG (a data set's depth map) as uint16 (H, W), checked before decoding."""
    data = read_bytes(path)
    header = parse_header(data, path)
    if header.kind != "png" or header.channels != 1 or header.bit_depth != 16:
        raise InputError(
            f"{path}: {what} must be a 1-channel 16-bit PNG, this is a {header.bit_depth}-bit "
            f"{header.kind.upper()} with {header.channels} channel(s)"
        )
    check_complete(data, header, path)
    return decode_image(data, path, cv2.IMREAD_UNCHANGED)


def read_image_header(path: Path) -> ImageHeader:
    """Header of an image file, checked for size limits and truncation, without decoding it."""
    data = read_bytes(path)
    header = parse_header(data, path)
    check_complete(data, header, path)
    return header


def _png_header(data: bytes, path: Path) -> ImageHeader:
    start = len(_PNG_SIGNATURE)
    if len(data) < start + 8 + 13 or data[start + 4 : start + 8] != b"IHDR":
        raise InputError(f"{path}: PNG is truncated or malformed (no IHDR header)")
    width, height, bit_depth, color_type = struct.unpack(">IIBB", data[start + 8 : start + 18])
    if color_type not in _PNG_CHANNELS:
        raise InputError(f"{path}: PNG has an invalid colour type {color_type}")
    return ImageHeader("png", height, width, bit_depth, _PNG_CHANNELS[color_type])


def _jpeg_header(data: bytes, path: Path) -> ImageHeader:
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            raise InputError(f"{path}: JPEG is malformed (no marker at byte {pos})")
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in _JPEG_STANDALONE:
            pos += 2
            continue
        (length,) = struct.unpack(">H", data[pos + 2 : pos + 4])
        if marker in _JPEG_SOF:
            if pos + 10 > len(data):
                break
            precision, height, width, components = struct.unpack(">BHHB", data[pos + 4 : pos + 10])
            if height == 0:
                raise InputError(f"{path}: JPEG without a height in its header (DNL) is not supported")
            return ImageHeader("jpeg", height, width, precision, components)
        if marker in (0xDA, 0xD9):  # scan data or end of image before any frame header
            break
        pos += 2 + length
    raise InputError(f"{path}: JPEG is truncated or malformed (no frame header)")
