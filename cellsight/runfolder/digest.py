"""Which cell a run used, as one digest (:func:`cell_digest`): the cell file and every file it
points to (meshes, URDFs and their meshes, calibration files), so that a sweep reuses a run
only for the same cell, even when a file the cell file names was rewritten since."""

from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path

from cellsight.model.cell import Cell


def is_regular_file(path: str | Path) -> bool:
    """``path`` is a regular file (through links): not missing, not a folder, and not a FIFO,
    a socket or a device, which could block a reader for ever (a FIFO with no writer) or never
    end (``/dev/zero``)."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except (OSError, ValueError):  # missing, a broken link, a NUL in the name
        return False


def file_digest(path: str | Path) -> str | None:
    """SHA-256 (hex) of a file's bytes; None when it cannot be read or is not a regular file
    (:func:`is_regular_file`)."""
    if not is_regular_file(path):
        return None
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def cell_digest(cell: Cell) -> str | None:
    """SHA-256 (hex) over the bytes of ``cell.source`` then of each of ``cell.files`` (in the
    loader's order, each with its name); None when the cell is not from a file or a file
    cannot be read."""
    digest = hashlib.sha256()
    try:
        digest.update(Path(cell.source).read_bytes())
        for path in cell.files:
            digest.update(str(Path(path).name).encode())
            digest.update(Path(path).read_bytes())
    except OSError:
        return None
    return digest.hexdigest()
