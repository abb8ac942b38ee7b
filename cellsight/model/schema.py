"""The schema of a YAML cell file, written with pydantic: what each field may hold.

A cell file has ``robots``, ``workpieces``, ``static`` objects, ``cameras`` (at least one) and an
optional ``experiments`` section. Solids are given as ``box``, ``prism``, ``segment`` (a box along
a segment, for links), inline ``vertices`` + ``faces`` (CCW seen from outside), or a ``mesh`` file
(STL/OBJ, path relative to the cell file), each with an optional ``pose`` in its parent frame. The
``experiments`` section sets up the paper's experiments: the grasping ``robot`` and ``workpiece``,
the ``conveyor`` path and a ``crossing`` robot's timed joint waypoints. A robot is either a DH
table (``links``) or a URDF file (``urdf: {file, geometry, flange}``, :mod:`cellsight.model.urdf`;
``package://NAME/...`` through the top-level ``packages: {NAME: folder}`` map, folders relative
to the cell file or ``python://MODULE/sub/path`` inside an installed Python package, or an
installed package). A camera's intrinsics may come from a calibration file
(``calibration: FILE`` or ``{file, format: opencv|ros}``) and its pose from an eye-to-hand
hand-eye result (``hand_eye: FILE`` or ``{file, format: opencv|easy_handeye, robot}``),
files relative to the cell file (:mod:`cellsight.model.calibration`). Lengths in metres, angles
in radians.

The schema checks each entry on its own; what needs the whole cell (names that must be unique, a
robot named elsewhere, joint vectors against the chain) is checked by
:mod:`cellsight.model.builders`.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    field_validator,
    model_validator,
)

from cellsight.geometry.transforms import pose_from_xyz_rpy

MIN_CONVEYOR_STEP_M = 1e-6  # m: the shortest leg of a conveyor path
SAFE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}")  # a camera name: part of file names


def _no_bool(value: object) -> object:
    """Refuse ``true``/``false`` where a number is expected (pydantic would read 1.0, 0.0)."""
    if isinstance(value, bool):
        raise ValueError("a number, not a boolean")
    return value


def _safe_name(value: str) -> str:
    """Accept a camera name that is safe as part of a file name (:data:`SAFE_NAME`)."""
    if not SAFE_NAME.fullmatch(value):
        raise ValueError("a name of at most 64 letters, digits, '_', '-' and '.', not starting "
                         "with '.' (it becomes part of output file names)")
    return value


Number = Annotated[float, BeforeValidator(_no_bool)]
Finite = Annotated[Number, Field(allow_inf_nan=False)]
Vec2 = Annotated[list[Finite], Field(min_length=2, max_length=2)]
Vec3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]
Positive = Annotated[Number, Field(gt=0, allow_inf_nan=False)]
Count = Annotated[int, Field(strict=True)]  # an integer: 2.0, "2" and true are refused
Flag = Annotated[bool, Field(strict=True)]  # true or false: 1 and "yes" are refused


class _Strict(BaseModel):
    """A spec that refuses unknown keys (a misspelt field is an error, not ignored)."""

    model_config = ConfigDict(extra="forbid")


class PoseSpec(_Strict):
    """A pose: position (m) and roll-pitch-yaw (rad), R = Rz(yaw) Ry(pitch) Rx(roll)."""

    xyz: Vec3 = [0.0, 0.0, 0.0]
    rpy: Vec3 = [0.0, 0.0, 0.0]

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous transform."""
        return pose_from_xyz_rpy(self.xyz, self.rpy)


class BoxSpec(_Strict):
    """An axis-aligned box: its size (m) and centre."""

    size: Annotated[list[Positive], Field(min_length=3, max_length=3)]
    center: Vec3 = [0.0, 0.0, 0.0]


class PrismSpec(_Strict):
    """A right prism: an x, y polygon in the plane z = ``z0`` extruded by ``height`` along +z."""

    polygon: Annotated[list[Vec2], Field(min_length=3)]
    height: Positive
    z0: Finite = 0.0


class SegmentSpec(_Strict):
    """A box along the segment ``start``-``end`` (a link), ``width`` x ``height`` across."""

    start: Vec3
    end: Vec3
    width: Positive
    height: Positive | None = None


class MeshSpec(_Strict):
    """A mesh file (STL/OBJ, relative to the cell file), scaled by ``scale``."""

    file: str
    scale: Positive = 1.0


class SolidSpec(_Strict):
    """Exactly one of box / prism / segment / mesh / (vertices + faces)."""

    box: BoxSpec | None = None
    prism: PrismSpec | None = None
    segment: SegmentSpec | None = None
    mesh: MeshSpec | None = None
    vertices: list[Vec3] | None = None
    faces: list[Annotated[list[Annotated[Count, Field(ge=0)]], Field(min_length=3)]] | None = None
    closed: Flag = True
    pose: PoseSpec | None = None
    features: list[str] | None = None

    @model_validator(mode="after")
    def _one_kind(self) -> SolidSpec:
        kinds = [k for k in ("box", "prism", "segment", "mesh", "vertices") if getattr(self, k)]
        if len(kinds) != 1:
            raise ValueError(
                "a solid needs exactly one of box, prism, segment, mesh, vertices+faces; "
                f"got {kinds}"
            )
        if (self.vertices is None) != (self.faces is None):
            raise ValueError("inline solids need both 'vertices' and 'faces'")
        return self


class LinkSpec(_Strict):
    """A DH link (standard convention) and the solids fixed to its frame."""

    a: Finite = 0.0
    alpha: Finite = 0.0
    d: Finite = 0.0
    theta: Finite = 0.0
    kind: Literal["revolute", "prismatic"] = "revolute"
    qlim: Annotated[list[Finite], Field(min_length=2, max_length=2)] = [-math.pi, math.pi]
    solids: list[SolidSpec] = []

    @model_validator(mode="after")
    def _limits(self) -> LinkSpec:
        if self.qlim[0] >= self.qlim[1]:
            raise ValueError(f"qlim must be [lo, hi] with lo < hi, got {self.qlim}")
        return self


class GripperSpec(_Strict):
    """A parallel gripper: its mount on the flange, palm solids, one jaw's solid, the largest
    opening (m) and the tool centre point in the tool frame."""

    mount: PoseSpec = PoseSpec()
    palm: Annotated[list[SolidSpec], Field(min_length=1)]
    jaw: SolidSpec
    max_opening: Positive
    tcp: Vec3 = [0.0, 0.0, 0.0]


URDF_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "tenth-inch": 0.00254}
"""The length units a URDF may be written in (``urdf: {scale: inch}``), in metres."""


class UrdfSpec(_Strict):
    """A URDF robot: the file (relative to the cell file, or ``package://NAME/...``), which
    geometry becomes its solids, the flange link the tool mounts on (default: ``tool0`` when
    it is fixed to the last actuated link, else that link), and ``scale``: the file's length
    unit in metres, a number or a name of :data:`URDF_UNITS` (``inch``: every joint origin,
    prismatic limit and geometry times 0.0254)."""

    file: Annotated[str, Field(min_length=1)]
    geometry: Literal["collision", "visual"] = "collision"
    flange: Annotated[str, Field(min_length=1)] | None = None
    scale: Positive | Literal["m", "cm", "mm", "inch", "tenth-inch"] = 1.0

    @property
    def metres(self) -> float:
        """``scale`` as metres per unit of the file."""
        return float(URDF_UNITS.get(self.scale, self.scale)) if isinstance(
            self.scale, str) else float(self.scale)


class RobotSpec(_Strict):
    """A robot: a DH table (``links``, with ``base_solids``) or a URDF (``urdf``)."""

    name: Annotated[str, Field(min_length=1)]
    base: PoseSpec = PoseSpec()
    base_solids: list[SolidSpec] = []
    links: Annotated[list[LinkSpec], Field(min_length=1)] | None = None
    urdf: UrdfSpec | None = None
    tool: GripperSpec | None = None
    home: list[Finite]
    final: list[Finite] | None = None

    @model_validator(mode="after")
    def _one_model(self) -> RobotSpec:
        if (self.links is None) == (self.urdf is None):
            raise ValueError("exactly one of 'links' (a DH table) or 'urdf' (a URDF file); got "
                             f"{'both' if self.links is not None else 'neither'}")
        if self.urdf is not None and self.base_solids:
            raise ValueError("'base_solids' only with 'links': a URDF robot's solids come "
                             "from its URDF")
        return self


class WorkpieceSpec(_Strict):
    """A workpiece: its solid, its pose and, optionally, where the gripper holds it."""

    name: Annotated[str, Field(min_length=1)]
    solid: SolidSpec
    pose: PoseSpec = PoseSpec()
    grasp: PoseSpec | None = None  # tool centre point in the part frame when held


class StaticSpec(_Strict):
    """A static object: its pose and its solids."""

    name: Annotated[str, Field(min_length=1)]
    pose: PoseSpec = PoseSpec()
    solids: Annotated[list[SolidSpec], Field(min_length=1)]


class LookAtSpec(_Strict):
    """A camera pose from its eye point, the point it looks at and the up direction."""

    eye: Vec3
    target: Vec3
    up: Vec3 = [0.0, 0.0, 1.0]


def _file_entry(value: object) -> object:
    """A bare file name stands for ``{file: NAME}``."""
    if isinstance(value, str):
        return {"file": value}
    if not isinstance(value, dict):
        raise ValueError("a file name, or a mapping {file, format, ...}")
    return value


class CalibrationFileSpec(_Strict):
    """A camera's intrinsics file (relative to the cell file): OpenCV FileStorage YAML/XML or
    ROS camera_info YAML (:mod:`cellsight.model.calibration`), the format guessed if not given."""

    file: Annotated[str, Field(min_length=1)]
    format: Literal["opencv", "ros"] | None = None


class HandEyeSpec(_Strict):
    """A fixed camera's pose from an eye-to-hand calibration file (relative to the cell file):
    easy_handeye YAML or OpenCV FileStorage with ``R_base_camera``/``t_base_camera``. The pose
    is in ``robot``'s base frame when given (composed with the robot's ``base``), else in the
    cell's base frame."""

    file: Annotated[str, Field(min_length=1)]
    format: Literal["opencv", "easy_handeye"] | None = None
    robot: Annotated[str, Field(min_length=1)] | None = None


CalibrationFile = Annotated[CalibrationFileSpec, BeforeValidator(_file_entry)]
HandEyeFile = Annotated[HandEyeSpec, BeforeValidator(_file_entry)]
INTRINSIC_KEYS = ("width", "height", "fx", "fy", "lens_mm", "pixel_mm", "cx", "cy", "dist")


class CameraSpec(_Strict):
    """OpenCV pinhole camera. Intrinsics either from a ``calibration`` file or given: image
    size and the focal length in pixels (fx, fy) or as a lens (mm) with the pixel pitch (mm);
    the pose as xyz/rpy of T_base_cam (``pose``), ``look_at`` or a ``hand_eye`` file."""

    name: Annotated[str, AfterValidator(_safe_name)]
    calibration: CalibrationFile | None = None
    width: Annotated[Count, Field(gt=0)] | None = None
    height: Annotated[Count, Field(gt=0)] | None = None
    fx: Positive | None = None
    fy: Positive | None = None
    lens_mm: Positive | None = None
    pixel_mm: Positive | None = None
    cx: Finite | None = None
    cy: Finite | None = None
    dist: Annotated[list[Finite], Field(min_length=4, max_length=5)] | None = None
    pose: PoseSpec | None = None
    look_at: LookAtSpec | None = None
    hand_eye: HandEyeFile | None = None

    @model_validator(mode="after")
    def _complete(self) -> CameraSpec:
        given = [k for k in INTRINSIC_KEYS if getattr(self, k) is not None]
        if self.calibration is not None and given:
            raise ValueError(f"'calibration' gives the image size, K and distortion: drop "
                             f"{', '.join(given)} (or the calibration file)")
        if self.calibration is None:
            if self.width is None or self.height is None:
                raise ValueError("width and height (px), or a calibration file")
            if (self.fx is None) == (self.lens_mm is None):
                raise ValueError("give either fx (and optionally fy) in pixels, or lens_mm + "
                                 "pixel_mm, or a calibration file")
            if self.lens_mm is not None and self.pixel_mm is None:
                raise ValueError("lens_mm needs pixel_mm")
        poses = [k for k in ("pose", "look_at", "hand_eye") if getattr(self, k) is not None]
        if len(poses) != 1:
            raise ValueError(f"give exactly one of pose, look_at or hand_eye; got "
                             f"{', '.join(poses) or 'none'}")
        return self


class ConveyorSpec(_Strict):
    """The conveyor's path of the part in experiments 2 and 3: x, y points (m), speed (m/s)."""

    points: Annotated[list[Vec2], Field(min_length=2)]
    speed: Positive
    t_start: Annotated[Number, Field(ge=0, allow_inf_nan=False)] = 0.0

    @field_validator("points")
    @classmethod
    def _distinct(cls, points: list[Vec2]) -> list[Vec2]:
        for i in range(1, len(points)):
            if math.dist(points[i - 1], points[i]) < MIN_CONVEYOR_STEP_M:
                raise ValueError(f"points {i - 1} and {i} coincide ({list(points[i])}): each "
                                 f"point must be at least {MIN_CONVEYOR_STEP_M:g} m from the last")
        return points


class WaypointSpec(_Strict):
    """A timed joint waypoint: time (s) and joint vector."""

    t: Positive
    q: Annotated[list[Finite], Field(min_length=1)]


class CrossingSpec(_Strict):
    """Experiment 3: a robot's own timed joint waypoints (absolute times, s)."""

    robot: Annotated[str, Field(min_length=1)]
    waypoints: Annotated[list[WaypointSpec], Field(min_length=1)]


class ExperimentsSpec(_Strict):
    """The experiments' setup: the grasping robot and workpiece, conveyor, crossing robot."""

    robot: str | None = None
    workpiece: str | None = None
    conveyor: ConveyorSpec | None = None
    crossing: CrossingSpec | None = None


class CellSpec(_Strict):
    """A whole cell file."""

    name: str = "cell"
    packages: dict[Annotated[str, Field(min_length=1)], str] = {}
    robots: list[RobotSpec] = []
    workpieces: list[WorkpieceSpec] = []
    static: list[StaticSpec] = []
    cameras: Annotated[list[CameraSpec], Field(min_length=1)]
    experiments: ExperimentsSpec | None = None
