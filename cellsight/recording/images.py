"""Camera images of a recording as the (H, W) uint8 grayscale arrays the tracker takes.

``sensor_msgs/msg/Image`` in ``mono8``, ``mono16`` (its ``bits`` significant bits, the low
ones: value / 2^(bits - 8), rounded down, at most 255; 16 bits when not declared, and then an
image whose values all fit in 12 bits is refused: 12-bit data read as 16-bit would be all but
black),
``rgb8``, ``bgr8``, ``rgba8`` or ``bgra8`` (to gray by OpenCV's weights), rows of ``step``
bytes; ``sensor_msgs/msg/CompressedImage`` in JPEG or PNG (decoded by OpenCV to gray). Any
other encoding, or an image whose size is not the camera's, is a
:class:`~cellsight.recording.reader.RecordingError` naming the topic and the message. A
compressed image's size is read from its header (Pillow reads only the header) and checked
against the camera's before anything is decoded: a few kilobytes that would decode to gigabytes
are refused without allocating them.
"""

from __future__ import annotations

import io
from typing import Any

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from cellsight.recording.names import COMPRESSED
from cellsight.recording.reader import RecordingError

_CHANNELS = {"mono8": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}
_TO_GRAY = {"rgb8": cv2.COLOR_RGB2GRAY, "bgr8": cv2.COLOR_BGR2GRAY,
            "rgba8": cv2.COLOR_RGBA2GRAY, "bgra8": cv2.COLOR_BGRA2GRAY}
ENCODINGS = (*_CHANNELS, "mono16")


SMALL_BITS = 12  # undeclared mono16 images whose values fit in this many bits are refused


def gray_image(kind: str, msg: Any, where: str, size: tuple[int, int],
               bits: int | None = None) -> np.ndarray:
    """The grayscale image of message ``msg`` of type ``kind``; ``where`` names it in errors
    (``/cam1/image_raw, message 12``); ``size``: the camera's (width, height); ``bits``: the
    significant bits of a ``mono16`` image (None: not declared)."""
    image = _compressed(msg, where, size) if kind == COMPRESSED else _raw(msg, where, bits)
    if image.shape != (size[1], size[0]):
        _wrong_size(where, image.shape[1], image.shape[0], size)
    return image


def _wrong_size(where: str, width: int, height: int, size: tuple[int, int]) -> None:
    raise RecordingError(f"{where}: a {width}x{height} image; the cell's camera takes "
                         f"{size[0]}x{size[1]}")


def _buffer(data: Any) -> np.ndarray:
    """A message's ``uint8[]`` as a flat uint8 array (bytes from one reader, arrays or lists
    from others)."""
    if isinstance(data, bytes | bytearray | memoryview):
        return np.frombuffer(data, dtype=np.uint8)
    return np.asarray(data, dtype=np.uint8).ravel()


def _mono16(rows: np.ndarray, big_endian: bool, where: str, bits: int | None) -> np.ndarray:
    """A ``mono16`` image to 8 bits: its ``bits`` significant bits (module docstring)."""
    values = rows.copy().view(">u2" if big_endian else "<u2")
    if bits is None:
        top = int(values.max(initial=0))
        if 0 < top < 2 ** SMALL_BITS:
            raise RecordingError(
                f"{where}: a mono16 image whose values all fit in {SMALL_BITS} bits (largest "
                f"{top}): read as 16-bit it is all but black; declare the camera's bits in a "
                f"topic map (--topics, bits: {{CAMERA: 12}}), or 16 if the data fill 16 bits")
        bits = 16
    return np.minimum(values >> (bits - 8), 255).astype(np.uint8)


def _raw(msg: Any, where: str, bits: int | None = None) -> np.ndarray:
    encoding = str(msg.encoding).lower()
    if encoding not in ENCODINGS:
        raise RecordingError(f"{where}: image encoding {msg.encoding!r} is not supported; "
                             f"expected one of {', '.join(ENCODINGS)}")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = _buffer(msg.data)
    depth = 2 if encoding == "mono16" else _CHANNELS[encoding]
    if step < w * depth or data.size < step * h:
        raise RecordingError(f"{where}: {data.size} bytes for a {w}x{h} {encoding} image "
                             f"with rows of {step} bytes")
    rows = data[:step * h].reshape(h, step)[:, :w * depth]
    if encoding == "mono16":
        return _mono16(rows, bool(int(msg.is_bigendian)), where, bits)
    if encoding == "mono8":
        return np.ascontiguousarray(rows)
    return cv2.cvtColor(np.ascontiguousarray(rows.reshape(h, w, depth)), _TO_GRAY[encoding])


def declared_size(data: bytes, where: str, fmt: str, size: tuple[int, int]) -> tuple[int, int]:
    """The (width, height) in px that a JPEG or PNG's header declares, read without decoding
    its pixels; a header Pillow cannot read, or one over Pillow's own bound (twice
    ``Image.MAX_IMAGE_PIXELS``), is a :class:`RecordingError` (``size``: the camera's)."""
    try:
        with Image.open(io.BytesIO(data)) as header:
            return header.size
    except Image.DecompressionBombError:
        raise RecordingError(f"{where}: a {fmt!r} image declaring over "
                             f"{2 * Image.MAX_IMAGE_PIXELS} px; the cell's camera takes "
                             f"{size[0]}x{size[1]}") from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
        raise RecordingError(f"{where}: {len(data)} bytes with no readable {fmt!r} header "
                             f"({e})") from None


def _compressed(msg: Any, where: str, size: tuple[int, int]) -> np.ndarray:
    fmt = str(msg.format).lower()
    if "jpeg" not in fmt and "jpg" not in fmt and "png" not in fmt:
        raise RecordingError(f"{where}: compressed format {msg.format!r} is not supported; "
                             f"expected JPEG or PNG")
    data = _buffer(msg.data)
    declared = declared_size(data.tobytes(), where, msg.format, size)
    if declared != tuple(size):
        _wrong_size(where, *declared, size)
    image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise RecordingError(f"{where}: {len(data)} bytes that OpenCV cannot decode as "
                             f"{msg.format!r}")
    return image
