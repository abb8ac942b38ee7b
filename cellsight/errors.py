"""Error types. Every message names where the bad input came from and what was expected.

Values are shown by :func:`short_repr`: numpy scalars and small arrays as plain numbers, and
never more than about 60 characters, whatever the size of the value (a hostile cell file can
expand to gigabytes; its repr is never built).
"""

from __future__ import annotations

import reprlib

import numpy as np

SHOWN_CHARS = 60  # longest value shown in a message, characters


class _PlainRepr(reprlib.Repr):
    """A bounded repr (a few items per container, a few levels) with numpy values as plain
    Python numbers: ``0.5``, not ``np.float64(0.5)``."""

    def __init__(self) -> None:
        super().__init__()
        self.maxlevel, self.maxlist, self.maxtuple, self.maxdict = 3, 6, 6, 4
        self.maxset = self.maxfrozenset = self.maxdeque = 6
        self.maxstring = self.maxother = SHOWN_CHARS

    def repr1(self, x: object, level: int) -> str:
        if isinstance(x, np.generic):
            x = x.item()
        elif isinstance(x, np.ndarray):
            if x.size > 4 * self.maxlist:
                return f"<array of shape {x.shape}>"
            x = x.tolist()
        if isinstance(x, float):
            return repr(x)
        return super().repr1(x, level)


_REPR = _PlainRepr()


def short_repr(value: object, limit: int = SHOWN_CHARS) -> str:
    """``repr`` of ``value`` cut to ``limit`` characters (``...`` marks the cut); built with a
    bounded cost, numpy scalars and arrays shown as plain numbers and lists."""
    shown = _REPR.repr(value)
    return shown if len(shown) <= limit else shown[: limit - 3] + "..."


class CellsightError(Exception):
    """Base class of every error raised by cellsight on bad input."""


class GeometryError(CellsightError, ValueError):
    """A polygon or solid is malformed: non-planar, degenerate, self-intersecting, mis-oriented."""


class KinematicsError(CellsightError, ValueError):
    """A joint vector has the wrong length, a non-finite value or a value out of its limits."""


class CameraError(CellsightError, ValueError):
    """Camera parameters are malformed (intrinsics, image size, pose, distortion)."""


class CellFileError(CellsightError, ValueError):
    """A cell file (or a mesh it names) is malformed. The message names the file, the field
    path, the value (:func:`short_repr`, at most ``SHOWN_CHARS`` characters) and what was
    expected (at most 400 characters)."""

    def __init__(self, file: str, field: str, value: object, expected: str) -> None:
        self.file, self.field, self.value, self.expected = file, field, value, expected
        expected = expected if len(expected) <= 400 else expected[:397] + "..."
        super().__init__(f"{file}: field '{field}': got {short_repr(value)}; expected {expected}")
