"""Error types. Every message names where the bad input came from and what was expected."""

from __future__ import annotations


class CellsightError(Exception):
    """Base class of every error raised by cellsight on bad input."""


class GeometryError(CellsightError, ValueError):
    """A polygon or solid is malformed: non-planar, degenerate, self-intersecting, mis-oriented."""


class KinematicsError(CellsightError, ValueError):
    """A joint vector has the wrong length, a non-finite value or a value out of its limits."""


class CameraError(CellsightError, ValueError):
    """Camera parameters are malformed (intrinsics, image size, pose, distortion)."""


class CellFileError(CellsightError, ValueError):
    """A cell file is malformed. The message names the file, the field path and the value."""

    def __init__(self, file: str, field: str, value: object, expected: str) -> None:
        self.file, self.field, self.value, self.expected = file, field, value, expected
        shown = repr(value)
        if len(shown) > 120:
            shown = shown[:117] + "..."
        super().__init__(f"{file}: field '{field}': got {shown}; expected {expected}")
