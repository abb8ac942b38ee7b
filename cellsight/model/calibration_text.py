"""Calibration files' text read safely (for :mod:`.calibration`): size and nesting bounded, the
format guessed, numbers, matrices and poses checked one key at a time, OpenCV FileStorage and
YAML mappings opened; every failure one :class:`CalibrationError` naming the file, the key and
the value."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from cellsight.errors import CellFileError, CellsightError, short_repr
from cellsight.model.yaml_input import load_yaml

MAX_CALIBRATION_BYTES = 2**20  # bytes: a calibration file is a few kilobytes
MAX_NESTING = 64  # brackets / XML elements nested in a calibration file
ROTATION_TOL = 1e-3  # largest |R^T R - I| entry, or |1 - |q||, of a rotation read from a file


class CalibrationError(CellsightError, ValueError):
    """A calibration file is missing, unreadable or malformed: ``file``, ``key`` (the key in
    the file, ``<file>`` for the whole file), ``value`` and what was ``expected``."""

    def __init__(self, file: str, key: str, value: object, expected: str) -> None:
        self.file, self.key, self.value, self.expected = file, key, value, expected
        super().__init__(f"{file}: key '{key}': got {short_repr(value)}; expected {expected}")


def _nesting(text: str) -> int:
    """Deepest nesting of ``[``/``{`` and XML elements (a cheap upper bound: quotes ignored)."""
    depth = deepest = 0
    for token in re.finditer(r"[\[{]|[\]}]|<[A-Za-z_][^<>]*?(/?)>|</", text):
        t = token.group()
        if t in "[{" or (t.startswith("<") and t != "</" and not token.group(1)):
            depth += 1
            deepest = max(deepest, depth)
        elif t in "]}" or t == "</":
            depth = max(depth - 1, 0)
    return deepest


def read_text(path: Path) -> str:
    """A calibration file's text: an existing, readable UTF-8 file of at most
    ``MAX_CALIBRATION_BYTES``, nested at most ``MAX_NESTING`` deep."""
    file = str(path)
    try:
        size = path.stat().st_size if path.is_file() else None
        if size is not None and size <= MAX_CALIBRATION_BYTES:
            data = path.read_bytes()
    except OSError as exc:
        raise CalibrationError(file, "<file>", file, f"a readable file ({exc.strerror})") from exc
    except ValueError as exc:  # a NUL byte in the name
        raise CalibrationError(file, "<file>", file, f"a usable file name ({exc})") from exc
    if size is None:
        raise CalibrationError(file, "<file>", file, "an existing calibration file")
    if size > MAX_CALIBRATION_BYTES:
        raise CalibrationError(file, "<file>", f"{size} bytes", "a calibration file of at "
                               f"most {MAX_CALIBRATION_BYTES} bytes")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CalibrationError(file, "<file>", data[exc.start:exc.start + 4],
                               f"UTF-8 text (byte {exc.start} is not UTF-8)") from exc
    if not text.strip():
        raise CalibrationError(file, "<file>", "", "a calibration file (it is empty)")
    if (depth := _nesting(text)) > MAX_NESTING:
        raise CalibrationError(file, "<file>", f"nesting {depth} deep",
                               f"brackets and elements nested at most {MAX_NESTING} deep")
    return text


def guess_format(path: Path, text: str, kinds: tuple[str, str]) -> str:
    """``kinds[0]`` (``opencv``) for an ``.xml``/``.json`` name, XML text, a ``%YAML:`` header
    or an ``!!opencv-matrix`` tag; else ``kinds[1]`` (the ROS layout)."""
    head = text.lstrip()
    if (path.suffix.lower() in (".xml", ".json") or head.startswith(("<", "%YAML:"))
            or "!!opencv-matrix" in text):
        return kinds[0]
    return kinds[1]


def _format(path: Path, text: str, fmt: str | None, kinds: tuple[str, str]) -> str:
    if fmt is None:
        return guess_format(path, text, kinds)
    if fmt not in kinds:
        raise CalibrationError(str(path), "<format>", fmt, f"one of {', '.join(kinds)}")
    return fmt


def _finite(file: str, key: str, values, shape: tuple[int, ...]) -> np.ndarray:
    """``values`` as finite floats of ``shape`` (numbers only: no booleans, no strings)."""
    flat = values if isinstance(values, list) else [values]
    if any(isinstance(v, bool) or not isinstance(v, int | float) for v in flat):
        raise CalibrationError(file, key, values, "numbers")
    array = np.array(flat, dtype=float)
    if array.size != int(np.prod(shape)):
        raise CalibrationError(file, key, values, f"{int(np.prod(shape))} numbers "
                               f"(a {'x'.join(map(str, shape))} matrix)")
    if not np.all(np.isfinite(array)):
        raise CalibrationError(file, key, values, "finite numbers")
    return array.reshape(shape)


def _size(file: str, key: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise CalibrationError(file, key, value, "a positive integer (px)")
    return int(value)


def _camera_matrix(file: str, key: str, K: np.ndarray) -> np.ndarray:
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[2, 2] != 1 or K[1, 0] or K[2, 0] or K[2, 1]:
        raise CalibrationError(file, key, K.tolist(), "a camera matrix [[fx, s, cx], [0, fy, "
                               "cy], [0, 0, 1]] with fx, fy > 0")
    return K


def _projection(file: str, key: str, P: np.ndarray, K: np.ndarray) -> np.ndarray | None:
    """A camera_info's ``P = [[fx', s, cx', Tx], [0, fy', cy', Ty], [0, 0, 1, 0]]`` (px;
    ``Tx``, ``Ty``: px m, a stereo pair's right camera's), or None for all zeros (none) and for
    ``[K | 0]`` (what None stands for)."""
    if not np.any(P) or np.array_equal(P, np.hstack([K, np.zeros((3, 1))])):
        return None
    if P[0, 0] <= 0 or P[1, 1] <= 0 or P[1, 0] or np.any(P[2] != [0.0, 0.0, 1.0, 0.0]):
        raise CalibrationError(file, key, P.tolist(), "a projection matrix [[fx', s, cx', Tx], "
                               "[0, fy', cy', Ty], [0, 0, 1, 0]] with fx', fy' > 0 (all zeros: "
                               "none)")
    return P


def _lens(file: str, key: str, dist: np.ndarray) -> np.ndarray:
    """The ``k1 k2 p1 p2 k3`` of a distortion vector whose further coefficients are zero."""
    if dist.size > 5 and np.any(dist[5:]):
        raise CalibrationError(file, key, dist.tolist(), "a distortion model cellsight can use: "
                               "k1 k2 p1 p2 k3 (OpenCV's 5 coefficients, ROS plumb_bob); the "
                               "coefficients after the fifth (k4 k5 k6 ...) must be zero")
    out = np.zeros(5)
    out[:min(dist.size, 5)] = dist[:5]
    return out


def _rotation(file: str, key: str, R: np.ndarray) -> np.ndarray:
    """The nearest rotation to ``R``, which must be one within ``ROTATION_TOL`` (``R`` itself
    when it is one to 1e-12: a file written by cellsight reads back exactly)."""
    off = np.abs(R.T @ R - np.eye(3)).max()
    if off > ROTATION_TOL or np.linalg.det(R) <= 0:
        raise CalibrationError(file, key, R.tolist(), "a rotation matrix (orthonormal, det +1, "
                               f"within {ROTATION_TOL})")
    if off <= 1e-12:
        return R
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


class _Missing:
    """The value of a key a file does not have."""

    def __repr__(self) -> str:
        return "<missing>"


def _entry(file: str, mapping: dict, key: str, prefix: str = "") -> object:
    """``mapping[key]``, or an error naming the missing key (``prefix``: the parent's keys)."""
    if key not in mapping:
        raise CalibrationError(file, prefix + key, MISSING, f"a key '{key}' (the file has "
                               f"{short_repr(sorted(map(str, mapping)))})")
    return mapping[key]


def _first(file: str, mapping: dict, keys: tuple[str, ...], what: str) -> str:
    """The first of ``keys`` the mapping has; an error naming them all otherwise."""
    for key in keys:
        if key in mapping:
            return key
    raise CalibrationError(file, keys[0], MISSING, f"{what} under one of the keys "
                           f"{', '.join(keys)}")


def _dims(file: str, key: str, value) -> tuple[int, int, list]:
    """``rows``, ``cols`` and ``data`` of a matrix written as ``{rows, cols, [dt,] data}``
    (an OpenCV ``opencv-matrix``, a ROS matrix) or ``{sizes: [n] or [rows, cols], dt, data}``
    (an ``opencv-nd-matrix``: ``cv2.FileStorage`` writes a 1-D array so)."""
    if not isinstance(value, dict):
        raise CalibrationError(file, key, value, "a matrix {rows, cols, data} (an OpenCV "
                               "opencv-matrix, a ROS matrix)")
    if "sizes" in value and "rows" not in value:
        sizes = value["sizes"] if isinstance(value["sizes"], list) else [value["sizes"]]
        if len(sizes) not in (1, 2):
            raise CalibrationError(file, f"{key}.sizes", value["sizes"], "one or two sizes")
        value = {"rows": sizes[0], "cols": sizes[1] if len(sizes) == 2 else 1, **value}
    rows, cols, data = (_entry(file, value, k, f"{key}.") for k in ("rows", "cols", "data"))
    for name, n in (("rows", rows), ("cols", cols)):
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise CalibrationError(file, f"{key}.{name}", n, "a count (an integer >= 0)")
    if not isinstance(data, list):
        data = [data]  # one number: OpenCV writes a 1x1 matrix's data as a scalar
    if len(data) != rows * cols:
        raise CalibrationError(file, f"{key}.data", data, f"rows x cols = {rows * cols} numbers")
    return rows, cols, data


def _matrix(file: str, key: str, value, shape: tuple[int, int]) -> np.ndarray:
    """A matrix of exactly ``shape`` and finite numbers."""
    rows, cols, data = _dims(file, key, value)
    if (rows, cols) != shape:
        raise CalibrationError(file, key, f"a {rows}x{cols} matrix", f"a {shape[0]}x{shape[1]} "
                               "matrix")
    return _finite(file, f"{key}.data", data, shape)


def _vector(file: str, key: str, value, sizes: tuple[int, ...]) -> np.ndarray:
    """A row or column of ``sizes`` finite numbers, flat."""
    rows, cols, data = _dims(file, key, value)
    if min(rows, cols) != 1 or rows * cols not in sizes:
        raise CalibrationError(file, key, f"a {rows}x{cols} matrix", "a row or column of "
                               f"{' or '.join(map(str, sizes))} numbers")
    return _finite(file, f"{key}.data", data, (rows * cols,))


def _cv_problem(exc: Exception) -> str:
    """The useful part of an OpenCV parser error: ``line N: problem``."""
    text = " ".join(str(exc.__cause__ or exc).split())
    if found := re.search(r"\((\d+)\): ([^']*)'?$", text):
        return f"line {found.group(1)}: {found.group(2)}"
    if found := re.search(r"error: \(-?\d+:[^)]*\) (.*)$", text):
        return found.group(1)
    return text


def _python(node: cv2.FileNode, depth: int = 0) -> object:
    """A FileStorage node as Python values (int, float, str, list, dict; None when empty);
    deeper than a matrix's ``data`` is shown as ``'<nested>'``."""
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    if depth > 4 and (node.isSeq() or node.isMap()):
        return "<nested>"
    if node.isSeq():
        return [_python(node.at(i), depth + 1) for i in range(node.size())]
    if node.isMap():
        return {k: _python(node.getNode(k), depth + 1) for k in node.keys()}
    return None


def opencv_storage(file: str, text: str) -> dict[str, object]:
    """The top-level keys of an OpenCV FileStorage text (YAML or XML), read by
    ``cv2.FileStorage`` from memory, as Python values."""
    if text.lstrip().startswith("<") and not text.lstrip().startswith("<?xml"):
        text = '<?xml version="1.0"?>\n' + text  # cv2 tells XML in memory by its declaration
    elif not text.lstrip().startswith(("<", "%YAML", "{")):
        text = "%YAML:1.0\n" + text  # OpenCV 4 reads YAML from memory only after this header
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        root = fs.root()
        if root.isNone() or root.empty():
            return {}
        if not root.isMap():
            raise CalibrationError(file, "<file>", "a sequence", "a mapping of keys (an OpenCV "
                                   "FileStorage file)")
        return {key: _python(root.getNode(key)) for key in root.keys()}
    except CalibrationError:
        raise
    except Exception as exc:  # cv2.error, or a SystemError wrapping one
        raise CalibrationError(file, "<file>", _cv_problem(exc), "an OpenCV FileStorage file "
                               "(YAML or XML) that cv2.FileStorage reads") from exc


def _yaml_mapping(file: str, text: str) -> dict:
    """A YAML mapping read safely (bounded, no repeated keys: :func:`load_yaml`)."""
    try:
        raw = load_yaml(text, file)
    except CellFileError as exc:
        raise CalibrationError(file, exc.field, exc.value, exc.expected) from exc
    if not isinstance(raw, dict):
        raise CalibrationError(file, "<file>", raw, "a YAML mapping of keys")
    return raw


MISSING = _Missing()
