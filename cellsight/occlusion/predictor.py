"""Cell-level occlusion prediction (paper, Section III and Fig. 4): what the back-ends share.

Every object's surfaces are kept in the object's own frame (:class:`.surfaces.CellSurfaces`).
At each sampling time, with each object's current pose (joint measurements for links and
tools, the tracker's predicted pose for workpieces, fixed for static objects), every workpiece
feature point gets a label per camera. :class:`VisibilityPredictor` does what every structure
shares: it projects the features into the cameras, builds the near-occluder ring around each
feature in an image and turns the structure's answers into labels
(:class:`~cellsight.visibility.CameraVisibility`). Which surface hides which point is the
back-end's business, one class per structure (same answers, tests/test_forest.py):

- ``"object-bvh"`` (default; :class:`.object_bvh.ObjectBVH`): a bounding-volume hierarchy of
  each object's surfaces, built once, offline, in the object's frame;
- ``"frame-bsp"`` (the paper's; :class:`.frame_bsp.FrameBSP`): the surfaces are culled, moved
  by the poses, and one BSP tree of them is built and visited back to front from each
  camera's optical centre.

:func:`~cellsight.occlusion.backends.visibility_predictor` ``(cell, structure=...)`` builds the
back-end of a :class:`~cellsight.visibility.Structure`. Adding a back-end is one module (a
subclass with its ``structure``), a member of ``Structure`` and one line in
:mod:`cellsight.occlusion.backends`.

The labels:

- visible: its pixel coordinates are valid and no surface hides it;
- ``behind``: it lies behind the camera (depth <= 0);
- ``outside``: it projects outside the image;
- ``self``: hidden by a surface of its own workpiece (self-occlusion);
- an object label (``R7AX.gripper``, ``R6AX.link3``, ``table``): hidden by that object
  (mutual occlusion); the nearest occluder along the line of sight is named.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.model.cell import Cell, Snapshot
from cellsight.occlusion._frame_kernel import Answer, label_answers, project_points
from cellsight.occlusion.surfaces import CellSurfaces
from cellsight.visibility import (
    STATUS_INSIDE,
    CameraVisibility,
    Structure,
    Views,
)

NEAR_SAMPLES = 8  # points on the ring around a feature for the near-occluder test
NEAR_DEPTH = 0.01  # m: a silhouette counts when at least this much nearer than the feature
NEAR_BEHIND = 20.0  # m: how far behind a feature its ring looks for the background's edges
CONTAIN_MARGIN = 1e-3  # m: growth of a solid's box in the camera-inside test (any >= 0 is exact)

#: Per camera: the features' pixels (N, 2) and projection status (N,) (``STATUS_*``).
Projection = list[tuple[np.ndarray, np.ndarray]]


class VisibilityPredictor(ABC):
    """Predicts, for a cell snapshot, which workpiece features each camera sees.

    The base of the cell-level back-ends (module doc);
    :func:`~cellsight.occlusion.backends.visibility_predictor` ``(cell, structure, **options)``
    builds one (default ``"object-bvh"``) with its options. Per frame (:meth:`predict`):
    project the features, then the back-end's answers for the features in each image and their
    rings, then labels (:meth:`stage_times` times each stage). ``cameras`` restricts the
    prediction to some cameras (a non-empty list of indices into ``cell.cameras``; None: all).
    ``surface_tolerance`` (m): a feature within this distance of a surface's plane is not hidden
    by it, so that features resting on a support (the part's bottom corners on the conveyor)
    stay visible although the tracker's pose is off by a fraction of a millimetre.
    ``near_px`` (px): a visible feature whose ring of points this far around it is partly
    hidden by another object is flagged ``near_occluder``: its image corner is a junction with
    that object's silhouette, a few pixels off (0 disables the test). The ring is tested twice:
    moved ``NEAR_DEPTH`` towards the camera, where any other object in front counts (not the
    surface the feature rests on), and moved ``NEAR_BEHIND`` away from it, where the feature is
    flagged when the ring meets a robot (the jaws touching a held part, an arm behind it: a
    robot never supports a part) or more than one background beside its own part (two objects,
    or an object and nothing: a table's edge): such a silhouette runs past the corner and makes
    a junction with it at any depth. Both must be finite and >= 0 (else
    :class:`CellsightError`). A back-end does not share one predictor between threads (it may
    reuse buffers from frame to frame).
    """

    #: The back-end's structure, given in its class statement.
    structure: ClassVar[Structure]

    def __init__(self, cell: Cell, *, cameras: list[int] | None = None,
                 surface_tolerance: float = 2e-3, near_px: float = 5.0) -> None:
        """The options: class doc."""
        self.cell = cell
        self.surface_tolerance = _non_negative("surface_tolerance", surface_tolerance, "m")
        self.near_px = _non_negative("near_px", near_px, "px")
        n_cam = len(cell.cameras)
        if cameras is not None and (not len(cameras) or not all(
                isinstance(k, int | np.integer) and 0 <= k < n_cam for k in cameras)):
            raise CellsightError(f"VisibilityPredictor: cameras must be indices 0..{n_cam - 1} "
                                 f"of cell.cameras (None: all), got {cameras!r}")
        self.cameras = [cell.cameras[k] for k in (range(n_cam) if cameras is None else cameras)]
        self.surfaces = CellSurfaces(cell)
        self.part_objects = [cell.object_index(p.name) for p in cell.workpieces]
        self.part_features = [p.feature_points for p in cell.workpieces]
        self._feature_owner = np.repeat(self.part_objects, [len(f) for f in self.part_features])
        self._robot_owned = np.array([o.robot is not None for o in cell.objects])
        self.labels = [o.label for o in cell.objects]
        self._ring_offsets: dict[str, np.ndarray] = {}  # camera name -> (K, 3) ring directions

    def recalibrate(self, index: int, camera: Camera) -> None:
        """Predict for the predictor's camera ``index`` with ``camera`` from now on (its
        calibration refined: :mod:`cellsight.tracking.registration`)."""
        self._ring_offsets.pop(self.cameras[index].name, None)
        self.cameras[index] = camera

    def predict(self, joints: Mapping[str, np.ndarray] | None = None,
                part_poses: Mapping[str, np.ndarray] | None = None,
                openings: Mapping[str, float] | None = None) -> Views:
        """Visibility of every workpiece feature in every camera (the
        :class:`~cellsight.visibility.VisibilitySource` call); see :meth:`predict_snapshot`."""
        return self.predict_snapshot(self.cell.snapshot(joints, part_poses, openings))

    def predict_snapshot(self, snapshot: Snapshot) -> Views:
        """Workpiece name -> one :class:`CameraVisibility` per camera (``cell.cameras`` order,
        or the predictor's ``cameras``)."""
        points, views = self._project(snapshot)
        return self._labelled(points, views, self._answers(snapshot, points, views))

    @abstractmethod
    def stage_times(self, snapshot: Snapshot) -> dict[str, float]:
        """One prediction, timed by stage (s): ``cull`` (projecting the features and what the
        back-end prepares per frame), ``build`` (a per-frame structure; 0 when none),
        ``visit`` (queries and labels), ``total``; ``kept``: the surfaces queried (a count)."""

    @abstractmethod
    def _answers(self, snapshot: Snapshot, points: np.ndarray,
                 views: Projection) -> list[Answer | None]:
        """Per camera, the answers for its features in the image and their rings (the points
        of :meth:`_queries`), or None when it has none; ``points`` (N, 3): every feature (base
        frame, m), ``views``: :meth:`_project`'s."""

    def _project(self, snapshot: Snapshot) -> tuple[np.ndarray, Projection]:
        """The features (N, 3) (base frame, m) and, per camera, their pixels (N, 2) and
        status (N,)."""
        points = np.concatenate([
            local @ snapshot.poses[k][:3, :3].T + snapshot.poses[k][:3, 3]
            for k, local in zip(self.part_objects, self.part_features, strict=True)
        ])
        n = len(points)
        views = []
        for cam in self.cameras:
            px, status, box = np.empty((n, 2)), np.empty(n, dtype=np.int8), np.empty(5)
            project_points(points, cam.T_cam_base, cam.K, cam.dist5, cam.width, cam.height,
                           px, status, box)
            views.append((px, status))
        return points, views

    def _queries(self, points: np.ndarray,
                 views: Projection) -> list[tuple[np.ndarray, np.ndarray, int]]:
        """Per camera: the features in its image (indices), their points followed by their
        near-occluder rings (base frame, m), and the ring size."""
        out = []
        for cam, (_, status) in zip(self.cameras, views, strict=True):
            query = np.flatnonzero(status == STATUS_INSIDE)
            ring = self._ring(cam, points[query])
            out.append((query, np.concatenate([points[query], ring.reshape(-1, 3)]),
                        ring.shape[1]))
        return out

    def _ring(self, cam: Camera, points: np.ndarray) -> np.ndarray:
        """Per point (N, 3): ``NEAR_SAMPLES`` points around it, ``near_px`` pixels away in the
        image plane at its depth, each moved ``NEAR_DEPTH`` m towards the camera (so that only
        a silhouette at least that much in front hides one, not the surface the feature rests
        on), then the same points moved ``NEAR_BEHIND`` m away from it: (N, 2K, 3)."""
        if self.near_px <= 0:
            return np.zeros((len(points), 0, 3))
        R = cam.T_base_cam[:3, :3]
        depth = (points - cam.center) @ R[:, 2]
        offsets = self._ring_offsets.get(cam.name)
        if offsets is None:  # unit directions in the image plane, once per camera
            angles = np.linspace(0.0, 2 * np.pi, NEAR_SAMPLES, endpoint=False)
            offsets = np.cos(angles)[:, None] * R[:, 0] + np.sin(angles)[:, None] * R[:, 1]
            self._ring_offsets[cam.name] = offsets
        ring = points[:, None, :] + (self.near_px * depth / cam.focal_px)[:, None, None] * offsets
        towards = cam.center - ring
        towards /= np.linalg.norm(towards, axis=2, keepdims=True)
        return np.concatenate([ring + NEAR_DEPTH * towards, ring - NEAR_BEHIND * towards],
                              axis=1)

    def _labelled(self, points: np.ndarray, views: Projection,
                  answers: list[Answer | None]) -> Views:
        """Per workpiece, one :class:`CameraVisibility` per camera from each camera's answers
        (:meth:`_answers`)."""
        n = len(points)
        result = {part.name: [] for part in self.cell.workpieces}
        for cam, (px, status), answer in zip(self.cameras, views, answers, strict=True):
            visible = np.zeros(n, dtype=bool)
            near = np.zeros(n, dtype=bool)
            occluder = np.full(n, -1, dtype=np.int32)
            if answer is not None:
                label_answers(*answer, self.surfaces.poly_owner, self._feature_owner,
                              self._robot_owned, visible, occluder, near)
            start = 0
            for k, f in zip(self.part_objects, self.part_features, strict=True):
                sl = slice(start, start + len(f))
                start += len(f)
                result[self.cell.objects[k].name].append(CameraVisibility(
                    cam.name, visible[sl], px[sl], occluder[sl], status[sl], self.labels, k,
                    near[sl]))
        return result


def _non_negative(name: str, value: float, unit: str) -> float:
    """``value`` as a float, or a :class:`CellsightError` naming ``name`` unless finite, >= 0."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not (np.isfinite(number) and number >= 0.0):
        raise CellsightError(f"VisibilityPredictor: {name} must be a finite number >= 0 "
                             f"({unit}), got {value!r}")
    return number
