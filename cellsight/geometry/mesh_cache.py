"""On-disk cache of prepared mesh solids, so that a large mesh file is merged once, not on
every command.

An entry holds what :func:`cellsight.geometry.meshes.load_mesh_solid` prepares from a file
(:class:`PreparedMesh`: vertices in metres, polygon faces, closed or not), keyed by the
SHA-256 digest of the file's bytes, the loader's parameters (scale, tolerances), trimesh's
version and ``CACHE_VERSION``: a changed file, parameter or loader is never served an old
entry. Entries are ``.npz`` files (plain numpy arrays, read without pickle) named by the
SHA-256 of that key, in ``$CELLSIGHT_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/cellsight``,
else ``~/.cache/cellsight``. Each is written to a temporary file in the same folder and moved
into place (``os.replace``), so a reader sees a whole entry or none. An entry that cannot be
read (truncated, not an ``.npz``, pickled objects), holds another key or fails the checks of
:func:`_checked` is ignored and rewritten by the load, silently, as is one with a face of no
area (checked by the loader); a folder that cannot be written leaves the load uncached,
silently. An entry's form is checked, not each face again (planarity, simplicity, closedness
are the loader's when it wrote the entry). Entries are never evicted: delete the folder to
reclaim the space.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import tempfile
from pathlib import Path
from typing import NamedTuple

import numpy as np

CACHE_VERSION = 1  # bump when what an entry holds, or how it is made, changes


class PreparedMesh(NamedTuple):
    """A mesh file's solid before it is named: ``vertices`` (n, 3) float64 in metres, every one
    used by a face; face ``k`` is ``indices[offsets[k]:offsets[k + 1]]`` (int64 vertex ids,
    counter-clockwise seen from outside); ``closed`` as in :class:`Polyhedron`."""

    vertices: np.ndarray
    indices: np.ndarray
    offsets: np.ndarray
    closed: bool


def cache_dir() -> Path:
    """The cache folder: ``$CELLSIGHT_CACHE_DIR``, ``$XDG_CACHE_HOME/cellsight`` or
    ``~/.cache/cellsight`` (the first set and non-empty)."""
    if os.environ.get("CELLSIGHT_CACHE_DIR"):
        return Path(os.environ["CELLSIGHT_CACHE_DIR"])
    if os.environ.get("XDG_CACHE_HOME"):
        return Path(os.environ["XDG_CACHE_HOME"]) / "cellsight"
    return Path.home() / ".cache" / "cellsight"


def entry_key(data: bytes, params: dict) -> str:
    """The key of a mesh file's entry: its bytes' SHA-256, ``params`` (JSON-able, the
    loader's), trimesh's version (from its package metadata: trimesh is not imported) and
    ``CACHE_VERSION``, as one JSON string."""
    return json.dumps({"file_sha256": hashlib.sha256(data).hexdigest(), "params": params,
                       "trimesh": importlib.metadata.version("trimesh"),
                       "version": CACHE_VERSION},
                      sort_keys=True)


def _entry_path(key: str) -> Path:
    return cache_dir() / f"{hashlib.sha256(key.encode()).hexdigest()}.npz"


def _checked(vertices, indices, offsets, closed) -> PreparedMesh | None:
    """The entry's arrays as a :class:`PreparedMesh` if they are well formed: vertices (n >= 3,
    3) finite, faces of at least 3 vertex ids in range, every vertex used; else None."""
    v, idx, off = np.asarray(vertices), np.asarray(indices), np.asarray(offsets)
    if (v.dtype != np.float64 or v.ndim != 2 or v.shape[1] != 3 or len(v) < 3
            or not np.isfinite(v).all()):
        return None
    if idx.dtype != np.int64 or off.dtype != np.int64 or idx.ndim != 1 or off.ndim != 1:
        return None
    if len(off) < 2 or off[0] != 0 or off[-1] != len(idx) or np.any(np.diff(off) < 3):
        return None
    if idx.min() < 0 or idx.max() >= len(v) or not np.bincount(idx, minlength=len(v)).all():
        return None
    if np.asarray(closed).shape != () or np.asarray(closed).dtype != bool:
        return None
    return PreparedMesh(v, idx, off, bool(closed))


def read(key: str) -> PreparedMesh | None:
    """The entry for ``key``, or None when there is none or it is unreadable, of another key
    or malformed."""
    try:
        with np.load(_entry_path(key), allow_pickle=False) as npz:
            if str(npz["key"]) != key:
                return None
            return _checked(npz["vertices"], npz["indices"], npz["offsets"], npz["closed"])
    except Exception:  # a missing, truncated or foreign file: rebuilt by the caller
        return None


def write(key: str, prepared: PreparedMesh) -> None:
    """Store ``prepared`` under ``key`` atomically; does nothing when the folder cannot be
    written (the next load rebuilds it)."""
    folder = cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, temp = tempfile.mkstemp(dir=folder, prefix=".entry-", suffix=".npz")
    except OSError:
        return
    try:
        with os.fdopen(fd, "wb") as out:
            np.savez(out, key=np.array(key), vertices=prepared.vertices,
                     indices=prepared.indices, offsets=prepared.offsets,
                     closed=np.array(prepared.closed))
        os.replace(temp, _entry_path(key))
    except OSError:
        Path(temp).unlink(missing_ok=True)
