"""Compressed images of a recording are bounded before they are decoded: a PNG or JPEG whose
header declares a size other than the camera's (a 20,000 x 20,000 px bomb of a few kilobytes)
is refused from its header, naming the topic, the message and both sizes, without the pixels
being decoded; a real image of the camera's size decodes as before (OpenCV's own decode)."""

from __future__ import annotations

import struct
import zlib
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from PIL import Image

from cellsight.recording.images import gray_image
from cellsight.recording.names import COMPRESSED
from cellsight.recording.reader import RecordingError

SIZE = (64, 48)  # the camera's (width, height)


def _png_declaring(width: int, height: int) -> bytes:
    """A PNG whose IHDR declares ``width`` x ``height`` 8-bit gray pixels, followed by one
    kilobyte-sized IDAT of zero rows: what it would decode to is set by the header alone."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    idat = zlib.compress(b"\0" * (width + 1) * 16, 9)  # 16 rows' worth, the rest missing
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat)
            + chunk(b"IEND", b""))


def _jpeg_declaring(width: int, height: int) -> bytes:
    """A JPEG of the camera's size with its frame header (SOF0) rewritten to ``width`` x
    ``height``."""
    ok, buf = cv2.imencode(".jpg", np.full(SIZE[::-1], 128, np.uint8))
    data = bytearray(buf.tobytes())
    sof = data.index(b"\xff\xc0")
    data[sof + 5:sof + 9] = struct.pack(">HH", height, width)
    return bytes(data)


def _message(fmt: str, data: bytes) -> SimpleNamespace:
    return SimpleNamespace(format=fmt, data=data)


@pytest.mark.parametrize("fmt, make", [("png", _png_declaring), ("jpeg", _jpeg_declaring)])
@pytest.mark.parametrize("width, height", [(20000, 20000), (65535, 1), (SIZE[0] + 1, SIZE[1])])
def test_an_image_declaring_another_size_is_refused_from_its_header(fmt, make, width, height):
    data = make(width, height)
    assert len(data) < 100_000
    with pytest.raises(RecordingError) as e:
        gray_image(COMPRESSED, _message(fmt, data), "/cam1/image_raw/compressed, message 3",
                   SIZE)
    declared = (f"a {width}x{height} image" if width * height < 2 * Image.MAX_IMAGE_PIXELS
                else f"a {fmt!r} image declaring over {2 * Image.MAX_IMAGE_PIXELS} px")
    assert str(e.value) == (f"/cam1/image_raw/compressed, message 3: {declared}; the cell's "
                            f"camera takes {SIZE[0]}x{SIZE[1]}")


def test_a_header_that_cannot_be_read_is_refused_naming_the_message():
    with pytest.raises(RecordingError, match=r"^/cam2/x, message 0: 7 bytes with no readable "
                                             r"'png' header"):
        gray_image(COMPRESSED, _message("png", b"\x89PNG\r\n\x1a"), "/cam2/x, message 0", SIZE)


@pytest.mark.parametrize("ext, fmt", [(".png", "png"), (".jpg", "jpeg")])
def test_an_image_of_the_cameras_size_decodes_as_opencv_decodes_it(ext, fmt):
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, SIZE[::-1], dtype=np.uint8)
    ok, buf = cv2.imencode(ext, image)
    got = gray_image(COMPRESSED, _message(fmt, buf.tobytes()), "/cam1, message 0", SIZE)
    np.testing.assert_array_equal(got, cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE))
