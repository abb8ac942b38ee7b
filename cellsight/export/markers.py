"""``/<camera>/visibility``: the workpiece's feature points as markers, per camera.

One ``visualization_msgs/MarkerArray`` per frame and camera, in the ``world`` frame
(:data:`~cellsight.export.frames.ROOT`), the features at the part's true pose:

- namespace ``predicted`` (id 0): a ``SPHERE_LIST``, one sphere per feature (feature order),
  green where the camera's prediction (``vis_pred``) says visible, red where hidden, grey in a
  frame without a prediction;
- namespace ``truth`` (id 0): a ``LINE_LIST`` of a ring around each feature, facing the
  camera (so that it looks like a circle in that camera's image), coloured by the truth
  (``vis_true``, the simulator's ray casts) the same way: a green sphere in a red ring is a
  feature predicted visible that the camera does not see;
- namespace ``names`` (ids 0..F-1): each feature's name above it (``TEXT_VIEW_FACING``).
"""

from __future__ import annotations

import numpy as np

from cellsight.export import ros
from cellsight.export.frames import ROOT

RING_SEGMENTS = 8


def marker_size(features: np.ndarray) -> float:
    """Diameter (m) of a feature's sphere: a quarter of the closest two features' distance,
    between 2 mm and 2 cm."""
    if len(features) < 2:
        return 0.01
    d = np.linalg.norm(features[:, None] - features[None], axis=-1)
    closest = float(np.min(d[~np.eye(len(features), dtype=bool)]))
    return float(np.clip(0.25 * closest, 0.002, 0.02))


def colours(bits: np.ndarray, present: bool) -> list[tuple]:
    """Green / red per feature, all grey when the frame has no value."""
    if not present:
        return [ros.GREY] * len(bits)
    return [ros.GREEN if b else ros.RED for b in bits]


def rings(points: np.ndarray, eye: np.ndarray, radius: float) -> np.ndarray:
    """(F * RING_SEGMENTS * 2, 3) line-list vertices of a circle of ``radius`` around each
    point, in the plane normal to the line of sight from ``eye``."""
    view = points - eye
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    helper = np.where(np.abs(view[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(view, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(view, u)
    angles = np.linspace(0.0, 2 * np.pi, RING_SEGMENTS + 1)
    circle = (points[:, None] + radius * (np.cos(angles)[None, :, None] * u[:, None]
                                          + np.sin(angles)[None, :, None] * v[:, None]))
    return np.stack([circle[:, :-1], circle[:, 1:]], axis=2).reshape(-1, 3)


def visibility_markers(ns: int, points: np.ndarray, names: tuple[str, ...], eye: np.ndarray,
                       predicted: np.ndarray | None, truth: np.ndarray | None,
                       size: float) -> dict:
    """The ``MarkerArray`` of one camera in one frame (module docstring): ``points`` (F, 3) the
    features in the ``world`` frame, ``eye`` the camera's centre, ``predicted`` / ``truth`` (F,)
    bool (None: the frame has none, drawn grey)."""
    none, stamp = np.zeros(len(points), dtype=bool), ros.header(ns, ROOT)
    ring_colours = [c for c in colours(none if truth is None else truth, truth is not None)
                    for _ in range(2 * RING_SEGMENTS)]
    markers = [
        ros.marker(stamp, ("predicted", 0), ros.SPHERE_LIST, scale=(size, size, size),
                   points=points, colors=colours(none if predicted is None else predicted,
                                                 predicted is not None)),
        ros.marker(stamp, ("truth", 0), ros.LINE_LIST, scale=(0.2 * size, 0.0, 0.0),
                   points=rings(points, eye, 0.9 * size), colors=ring_colours),
    ]
    markers += [ros.marker(stamp, ("names", j), ros.TEXT_VIEW_FACING,
                           scale=(0.0, 0.0, 1.5 * size), text=name,
                           position=p + np.array([0.0, 0.0, 1.2 * size]))
                for j, (name, p) in enumerate(zip(names, points, strict=True))]
    return {"markers": markers}
