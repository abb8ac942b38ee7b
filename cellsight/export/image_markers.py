"""``/<camera>/annotations``: the tracker's windows and measured corners on the camera's image.

Per frame and camera, two ``visualization_msgs/ImageMarker`` (Foxglove's Image panel draws
them over the image of the same camera), in the camera's optical frame, in pixels as in the
image (x right, y down), from the log (``windows_c*``, ``corners_c*`` of
:mod:`cellsight.runfolder.framelog`):

- namespace ``windows`` (id 0): a ``LINE_LIST`` of every window's four edges, blue;
- namespace ``corners`` (id 0): ``POINTS``, each measured corner, cyan, orange where the
  EKF's gate rejected it.

Both are sent every frame (empty where there is nothing), so each frame's replace the last.
"""

from __future__ import annotations

import numpy as np

from cellsight.export import ros

WINDOW = (0.2, 0.45, 1.0, 1.0)
CORNER = (0.0, 0.9, 0.9, 1.0)
REJECTED = (1.0, 0.55, 0.0, 1.0)
LINE_LIST, POINTS = 2, 4  # ImageMarker types


def image_marker(ns: int, frame_id: str, namespace: str, kind: int, points: list,
                 colours: list, scale: float) -> dict:
    """One ``visualization_msgs/ImageMarker`` to add: ``points`` (u, v) px, a colour each."""
    return {"header": ros.header(ns, frame_id), "ns": namespace, "id": 0, "type": kind,
            "action": 0, "position": ros.point((0.0, 0.0, 0.0)), "scale": float(scale),
            "outline_color": ros.color(colours[0] if colours else WINDOW), "filled": 0,
            "fill_color": ros.color((0.0, 0.0, 0.0, 0.0)),
            "lifetime": {"sec": 0, "nanosec": 0},
            "points": [ros.point((u, v, 0.0)) for u, v in points],
            "outline_colors": [ros.color(c) for c in colours]}


def window_edges(boxes: np.ndarray) -> list[tuple[float, float]]:
    """The four edges of each half-open box ``(u0, v0, u1, v1)`` as point pairs, on the
    outer pixels' centres' outline (u0 .. u1 - 1)."""
    points = []
    for u0, v0, u1, v1 in np.asarray(boxes, dtype=float).reshape(-1, 4):
        a, b, c, d = (u0, v0), (u1 - 1, v0), (u1 - 1, v1 - 1), (u0, v1 - 1)
        points += [a, b, b, c, c, d, d, a]
    return points


def annotations(ns: int, frame_id: str, boxes: np.ndarray, corners: np.ndarray,
                rejected: np.ndarray) -> list[dict]:
    """The frame's two markers: windows ``boxes`` (n, 4), ``corners`` (F, 2) px (NaN where
    none measured) and ``rejected`` (F,) bool."""
    edges = window_edges(boxes)
    measured = np.flatnonzero(np.all(np.isfinite(corners), axis=1))
    return [image_marker(ns, frame_id, "windows", LINE_LIST, edges, [WINDOW] * len(edges), 1.0),
            image_marker(ns, frame_id, "corners", POINTS,
                         [tuple(corners[j]) for j in measured],
                         [REJECTED if rejected[j] else CORNER for j in measured], 4.0)]
