"""A recording's ``CameraInfo`` against the cell's cameras.

The first ``sensor_msgs/msg/CameraInfo`` of each camera that has one is compared with the
cell's camera (the later ones must repeat it; a calibration that changes mid-recording is
refused): image size exactly, ``K`` within :data:`K_TOLERANCE_PX`, the distortion
coefficients (OpenCV's order, zeros appended to 8) within :data:`D_TOLERANCE`. A
disagreement is one :class:`~cellsight.recording.reader.RecordingError` naming the topic, the
field and both values; with ``from_bag`` the recording's ``K``, ``D`` and ``P`` replace the
cell's instead (the pose stays the cell's, and the size must still agree). Only the ``plumb_bob``
and ``rational_polynomial`` models are read: a fisheye (``equidistant``) camera is refused in
one line, never read as another model.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from cellsight.camera import Camera
from cellsight.model.cell import Cell
from cellsight.recording.reader import Recording, RecordingError

K_TOLERANCE_PX = 0.5
D_TOLERANCE = 1e-3
MODELS = ("plumb_bob", "rational_polynomial")
_K_NAMES = ("fx", "skew", "cx", "0", "fy", "cy", "0", "0", "1")


def first_infos(recording: Recording, topics: list[str | None]) -> list[Any | None]:
    """The first message of each camera-info topic (None where there is no topic); every
    later one must say the same (size, model, ``K``, ``D``, ``P``): one that changes
    mid-recording is a :class:`RecordingError` naming the topic, the message and the field."""
    wanted = [t for t in topics if t is not None]
    first: dict[str, Any] = {}
    count: dict[str, int] = {}
    if wanted:
        for topic, _, msg in recording.messages(wanted):
            count[topic] = count.get(topic, 0) + 1
            if topic not in first:
                first[topic] = msg
            else:
                _same_info(first[topic], msg, f"{topic}, message {count[topic]}")
    return [first.get(t) if t is not None else None for t in topics]


def _same_info(a: Any, b: Any, where: str) -> None:
    for name in ("width", "height", "distortion_model", "k", "d", "p"):
        x, y = getattr(a, name), getattr(b, name)
        same = (x == y) if isinstance(x, int | str) else (
            np.shape(x) == np.shape(y) and np.array_equal(np.asarray(x, dtype=float),
                                                       np.asarray(y, dtype=float)))
        if not same:
            raise RecordingError(f"{where}: field {name!r} = {_shown(y)}, not the first "
                                 f"message's {_shown(x)}: a camera_info that changes "
                                 f"mid-recording is not supported; track each part of the "
                                 f"recording on its own")


def _shown(value: Any) -> str:
    if isinstance(value, int | str):
        return repr(value)
    return str(np.round(np.asarray(value, dtype=float), 4).tolist())


def _padded(d: Any) -> np.ndarray:
    d = np.asarray(d, dtype=float).ravel()
    return np.concatenate([d, np.zeros(max(8 - d.size, 0))])[:max(8, d.size)]


def _projection(info: Any, K: np.ndarray) -> np.ndarray | None:
    """The message's P (3x4), None where it is empty or [K | 0]."""
    P = np.asarray(info.p, dtype=float).reshape(3, 4)
    plain = np.hstack([K, np.zeros((3, 1))])
    return None if not np.any(P) or np.allclose(P, plain) else P


def _recorded(camera: Camera, topic: str, info: Any) -> tuple[np.ndarray, np.ndarray]:
    """The recording's K and D for ``camera`` (size and model checked)."""
    model = str(info.distortion_model)
    if model not in MODELS:
        raise RecordingError(f"{topic}: distortion model {model!r} is not supported (fisheye "
                             f"and other models are not modelled by cellsight's cameras); "
                             f"expected {' or '.join(MODELS)}")
    size = (int(info.width), int(info.height))
    if size != (camera.width, camera.height):
        raise RecordingError(f"{topic}: image size {size[0]}x{size[1]}; the cell's camera "
                             f"{camera.name} is {camera.width}x{camera.height}")
    return np.asarray(info.k, dtype=float).reshape(3, 3), _padded(info.d)


def checked_cell(cell: Cell, recording: Recording, topics: list[str | None],
                 from_bag: bool) -> tuple[Cell, list[str]]:
    """The cell to track with (its cameras replaced by the recording's calibration with
    ``from_bag``), and a line per camera saying what was checked or replaced."""
    cameras, notes = [], []
    for camera, topic, info in zip(cell.cameras, topics, first_infos(recording, topics),
                                   strict=True):
        if info is None:
            cameras.append(camera)
            notes.append(f"{camera.name}: no camera_info in the recording; the cell's "
                         f"calibration is used")
            continue
        K, D = _recorded(camera, topic, info)
        if from_bag:
            dist = D if np.any(D) else None
            cameras.append(replace(camera, K=K, dist=dist, P=_projection(info, K)))
            notes.append(f"{camera.name}: calibration from {topic} (fx {K[0, 0]:.2f} px)")
            continue
        _compare(camera, topic, K, D)
        cameras.append(camera)
        notes.append(f"{camera.name}: {topic} agrees with the cell")
    if all(a is b for a, b in zip(cameras, cell.cameras, strict=True)):
        return cell, notes
    return Cell(cell.name, cell.robots, cell.workpieces, cell.static, cameras, cell.source,
                cell.experiments, cell.files), notes


def _compare(camera: Camera, topic: str, K: np.ndarray, D: np.ndarray) -> None:
    hint = "; pass --calibration-from-bag to use the recording's calibration"
    diff = np.abs(K - camera.K).ravel()
    worst = int(np.argmax(diff))
    if diff[worst] > K_TOLERANCE_PX:
        raise RecordingError(f"{topic}: K {_K_NAMES[worst]} = {K.ravel()[worst]:.6g} px; the "
                             f"cell's camera {camera.name} has {camera.K.ravel()[worst]:.6g} px "
                             f"(tolerance {K_TOLERANCE_PX} px){hint}")
    own = _padded([] if camera.dist is None else camera.dist)
    n = max(own.size, D.size)
    own, D = np.pad(own, (0, n - own.size)), np.pad(D, (0, n - D.size))
    if np.any(np.abs(D - own) > D_TOLERANCE):
        raise RecordingError(f"{topic}: distortion D = {np.round(D, 6).tolist()}; the cell's "
                             f"camera {camera.name} has {np.round(own, 6).tolist()} (tolerance "
                             f"{D_TOLERANCE}){hint}")
