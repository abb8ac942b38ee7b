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
from typing import Annotated, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BeforeValidator,
    Field,
    model_validator,
)

from cellsight.fields import about
from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.model.experiments_schema import ExperimentsSpec
from cellsight.model.spec_types import (
    JOINT_UNIT,
    Count,
    Finite,
    Flag,
    Positive,
    Vec2,
    Vec3,
    _safe_name,
    _Strict,
)


class PoseSpec(_Strict):
    """A pose: position (m) and roll-pitch-yaw (rad), R = Rz(yaw) Ry(pitch) Rx(roll)."""

    xyz: Vec3 = about([0.0, 0.0, 0.0], "Position of the frame's origin in its parent frame (the "
                      "frame named where the pose is used); default: the parent's origin.", "m")
    rpy: Vec3 = about([0.0, 0.0, 0.0], "Roll, pitch and yaw of the frame's axes in its parent "
                      "frame, R = Rz(yaw) Ry(pitch) Rx(roll); default: the parent's axes.", "rad")

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous transform."""
        return pose_from_xyz_rpy(self.xyz, self.rpy)


class BoxSpec(_Strict):
    """An axis-aligned box: its size (m) and centre."""

    size: Annotated[list[Positive], Field(min_length=3, max_length=3)] = about(
        ..., "The box's edge lengths along the x, y and z axes of the solid's frame, each > 0.",
        "m")
    center: Vec3 = about([0.0, 0.0, 0.0], "The box's centre in the solid's frame; default: the "
                         "frame's origin.", "m")


class PrismSpec(_Strict):
    """A right prism: an x, y polygon in the plane z = ``z0`` extruded by ``height`` along +z."""

    polygon: Annotated[list[Vec2], Field(min_length=3)] = about(
        ..., "The x, y vertices of the simple base polygon in the solid's frame (at least 3, "
        "either orientation); the prism's vertices are these at z0, then these at z0 + height.",
        "m")
    height: Positive = about(..., "The extrusion's length along +z of the solid's frame, > 0.",
                             "m")
    z0: Finite = about(0.0, "The z of the base polygon's plane in the solid's frame; default 0.",
                       "m")


class SegmentSpec(_Strict):
    """A box along the segment ``start``-``end`` (a link), ``width`` x ``height`` across."""

    start: Vec3 = about(..., "One end of the segment (a link's axis) in the solid's frame.", "m")
    end: Vec3 = about(..., "The other end of the segment in the solid's frame; the box reaches "
                      "half the width beyond each end, so that consecutive links overlap.", "m")
    width: Positive = about(..., "The box's size across the segment (> 0); half of it is its "
                            "reach past each end.", "m")
    height: Positive | None = about(None, "The box's other size across the segment (> 0); "
                                    "default: the width (a square section).", "m")


class MeshSpec(_Strict):
    """A mesh file (STL/OBJ, relative to the cell file), scaled by ``scale``."""

    file: str = about(..., "The mesh file (STL, OBJ or COLLADA .dae), relative to the cell "
                      "file's folder; its coordinates are in the solid's frame.", "-")
    scale: Positive = about(1.0, "Metres per unit of the file's coordinates, on all three axes "
                            "(0.001 for a file in mm); default 1: the file is in metres.", "m")


class SolidSpec(_Strict):
    """Exactly one of box / prism / segment / mesh / (vertices + faces)."""

    box: BoxSpec | None = about(None, "An axis-aligned box (one of box, prism, segment, mesh, "
                                "vertices + faces).", "-")
    prism: PrismSpec | None = about(None, "A right prism (one of box, prism, segment, mesh, "
                                    "vertices + faces).", "-")
    segment: SegmentSpec | None = about(None, "A box along a segment, for a link (one of box, "
                                        "prism, segment, mesh, vertices + faces).", "-")
    mesh: MeshSpec | None = about(None, "A mesh file (one of box, prism, segment, mesh, "
                                  "vertices + faces).", "-")
    vertices: list[Vec3] | None = about(None, "An inline solid's vertices, x, y, z in the "
                                        "solid's frame (with faces).", "m")
    faces: list[Annotated[list[Annotated[Count, Field(ge=0)]], Field(min_length=3)]] | None = (
        about(None, "An inline solid's faces (with vertices): each at least 3 vertex indices, "
              "counting from 0, counter-clockwise seen from outside.", "-"))
    closed: Flag = about(True, "For vertices + faces only: the faces close a solid (checked: "
                         "each edge shared by two faces, wound outward); false: open surfaces. "
                         "Boxes, prisms and segments are closed, a mesh as its file is.", "-")
    pose: PoseSpec | None = about(None, "The solid's frame in its parent's frame (the link, "
                                  "tool, workpiece or static object it belongs to); default: "
                                  "the parent's frame.", "-")
    features: list[str] | None = about(None, "Names of the solid's feature points, one per "
                                       "vertex in the built solid's vertex order (a prism: "
                                       "the base polygon's, then the top's); default: f1, f2, "
                                       "...", "-")

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

    a: Finite = about(0.0, "DH link length: along x_i, from z_(i-1) to z_i "
                      "(A_i = Rz(theta) Tz(d) Tx(a) Rx(alpha)).", "m")
    alpha: Finite = about(0.0, "DH link twist: about x_i, from z_(i-1) to z_i.", "rad")
    d: Finite = about(0.0, "DH link offset along z_(i-1); a prismatic joint's value adds to it.",
                      "m")
    theta: Finite = about(0.0, "DH joint angle about z_(i-1) at joint value 0; a revolute "
                          "joint's value adds to it.", "rad")
    kind: Literal["revolute", "prismatic"] = about(
        "revolute", "The joint: revolute (turns about z_(i-1)) or prismatic (slides along it).",
        "-")
    qlim: Annotated[list[Finite], Field(min_length=2, max_length=2)] = about(
        [-math.pi, math.pi], "The joint's limits [lo, hi], lo < hi; default [-pi, pi] (also for "
        "a prismatic joint, then in m).", JOINT_UNIT)
    solids: list[SolidSpec] = about([], "The solids fixed to this link's frame (DH frame i), "
                                    "in that frame; default none.", "-")

    @model_validator(mode="after")
    def _limits(self) -> LinkSpec:
        if self.qlim[0] >= self.qlim[1]:
            raise ValueError(f"qlim must be [lo, hi] with lo < hi, got {self.qlim}")
        return self


class GripperSpec(_Strict):
    """A parallel gripper: its mount on the flange, palm solids, one jaw's solid, the largest
    opening (m) and the tool centre point in the tool frame."""

    mount: PoseSpec = about(PoseSpec(), "The tool frame in the flange frame (the DH chain's "
                            "last frame, or the URDF's flange link); tool z is the approach "
                            "direction, the jaws close along tool y; default: the flange "
                            "frame.", "-")
    palm: Annotated[list[SolidSpec], Field(min_length=1)] = about(
        ..., "The palm's solids in the tool frame, at least one.", "-")
    jaw: SolidSpec = about(..., "One jaw's solid in its own frame: gripping face on the plane "
                           "y = 0, body at y > 0; the jaws sit at y = +-opening/2 in the tool "
                           "frame, the second turned half a turn about z.", "-")
    max_opening: Positive = about(..., "The jaws' largest opening (the distance between their "
                                  "gripping faces), also the open command.", "m")
    tcp: Vec3 = about([0.0, 0.0, 0.0], "The tool centre point in the tool frame (same axes); "
                      "default: the tool frame's origin.", "m")


class FingersSpec(_Strict):
    """A URDF robot's own hand as its gripper: the two fingers of its URDF (a prismatic joint
    and its mimic, hanging off the last actuated link) become the jaws. The tool frame sits at
    the leading finger's joint origin, y along its axis; the opening is the distance between
    the fingers' frames along it."""

    fingers: Literal["urdf"] = about(..., "Where the fingers come from: the robot's URDF.", "-")
    tcp: Vec3 = about([0.0, 0.0, 0.0], "The tool centre point in the tool frame (at the "
                      "leading finger's joint origin, y along its axis); default: its origin.",
                      "m")


URDF_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "tenth-inch": 0.00254}
"""The length units a URDF may be written in (``urdf: {scale: inch}``), in metres."""


class UrdfSpec(_Strict):
    """A URDF robot: the file (relative to the cell file, or ``package://NAME/...``), which
    geometry becomes its solids, the flange link the tool mounts on (default: ``tool0`` when
    it is fixed to the last actuated link, else that link), and ``scale``: the file's length
    unit in metres, a number or a name of :data:`URDF_UNITS` (``inch``: every joint origin,
    prismatic limit and geometry times 0.0254)."""

    file: Annotated[str, Field(min_length=1)] = about(
        ..., "The URDF file: relative to the cell file's folder, file://PATH, or "
        "package://NAME/PATH (the cell's packages map, else an installed package).", "-")
    geometry: Literal["collision", "visual"] = about(
        "collision", "Which of the URDF's elements become the robot's solids.", "-")
    flange: Annotated[str, Field(min_length=1)] | None = about(
        None, "The URDF link the tool mounts on, fixed to the last actuated link; default: "
        "tool0 when it is so fixed, else that last link.", "-")
    scale: Positive | Literal["m", "cm", "mm", "inch", "tenth-inch"] = about(
        1.0, "Metres per length unit of the file, or the unit's name: joint origins, prismatic "
        "limits and geometry are multiplied by it; default 1 (metres).", "m")

    @property
    def metres(self) -> float:
        """``scale`` as metres per unit of the file."""
        return float(URDF_UNITS.get(self.scale, self.scale)) if isinstance(
            self.scale, str) else float(self.scale)


class RobotSpec(_Strict):
    """A robot: a DH table (``links``, with ``base_solids``) or a URDF (``urdf``)."""

    name: Annotated[str, Field(min_length=1)] = about(
        ..., "The robot's name, unique among robots, workpieces and static objects; its solids "
        "are labelled NAME.link2, NAME.gripper, ...", "-")
    base: PoseSpec = about(PoseSpec(), "The robot's frame 0 (its base) in the cell's base "
                           "frame; default: the cell's base frame.", "-")
    base_solids: list[SolidSpec] = about([], "Solids fixed to the robot's frame 0, in that frame "
                                         "(DH robots only); default none.", "-")
    links: Annotated[list[LinkSpec], Field(min_length=1)] | None = about(
        None, "The DH table, one link per joint from the base (give links or urdf).", "-")
    urdf: UrdfSpec | None = about(None, "The URDF the robot is read from (give links or urdf).",
                                  "-")
    tool: GripperSpec | FingersSpec | None = about(
        None, "The parallel gripper on the flange, or {fingers: urdf} for the URDF's own "
        "fingers; default none (a robot without one does not grasp), or the URDF's fingers "
        "when it has them.", "-")
    home: list[Finite] = about(..., "HOME, one value per joint within its limits: where the "
                               "robot starts, stays when idle, and carries the part back to.",
                               JOINT_UNIT)
    final: list[Finite] | None = about(None, "FINAL, one value per joint within its limits: "
                                       "where the grasping robot puts the part down; default "
                                       "none (then the robot does not grasp).", JOINT_UNIT)

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

    name: Annotated[str, Field(min_length=1)] = about(
        ..., "The workpiece's name, unique among robots, workpieces and static objects.", "-")
    solid: SolidSpec = about(..., "The part's solid in the part frame; its vertices are the "
                             "feature points the cameras track.", "-")
    pose: PoseSpec = about(PoseSpec(), "The part frame's nominal (start) pose in the cell's base "
                           "frame; default: the base frame.", "-")
    grasp: PoseSpec | None = about(None, "The tool centre point's pose in the part frame when the "
                                   "gripper holds it; default: at the part's bounding-box centre, "
                                   "tool z along the part's -z, tool y along its y.", "-")


class StaticSpec(_Strict):
    """A static object: its pose and its solids."""

    name: Annotated[str, Field(min_length=1)] = about(
        ..., "The object's name, unique among robots, workpieces and static objects.", "-")
    pose: PoseSpec = about(PoseSpec(), "The object's frame in the cell's base frame; default: "
                           "the base frame.", "-")
    solids: Annotated[list[SolidSpec], Field(min_length=1)] = about(
        ..., "The object's solids in its frame, at least one.", "-")


class LookAtSpec(_Strict):
    """A camera pose from its eye point, the point it looks at and the up direction."""

    eye: Vec3 = about(..., "The camera's optical centre in the cell's base frame.", "m")
    target: Vec3 = about(..., "The point on the optical axis it looks at, in the cell's base "
                         "frame.", "m")
    up: Vec3 = about([0.0, 0.0, 1.0], "The base-frame direction that appears upward in the "
                     "image (its length does not matter); default +z.", "-")


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

    file: Annotated[str, Field(min_length=1)] = about(
        ..., "The intrinsics file, relative to the cell file's folder.", "-")
    format: Literal["opencv", "ros"] | None = about(
        None, "opencv (FileStorage YAML/XML) or ros (camera_info YAML, or an echoed CameraInfo "
        "message); default: guessed from the file.", "-")


class HandEyeSpec(_Strict):
    """A fixed camera's pose from an eye-to-hand calibration file (relative to the cell file):
    easy_handeye YAML or OpenCV FileStorage with ``R_base_camera``/``t_base_camera``. The pose
    is in ``robot``'s base frame when given (composed with the robot's ``base``), else in the
    cell's base frame."""

    file: Annotated[str, Field(min_length=1)] = about(
        ..., "The eye-to-hand calibration file (the camera's optical frame in a base frame), "
        "relative to the cell file's folder.", "-")
    format: Literal["opencv", "easy_handeye"] | None = about(
        None, "opencv (FileStorage with R_base_camera, t_base_camera) or easy_handeye (its "
        "YAML); default: guessed from the file.", "-")
    robot: Annotated[str, Field(min_length=1)] | None = about(
        None, "The robot whose base frame the pose is in (composed with that robot's base); "
        "default: the cell's base frame.", "-")


CalibrationFile = Annotated[CalibrationFileSpec, BeforeValidator(_file_entry)]
HandEyeFile = Annotated[HandEyeSpec, BeforeValidator(_file_entry)]
INTRINSIC_KEYS = ("width", "height", "fx", "fy", "lens_mm", "pixel_mm", "cx", "cy", "dist")


class CameraSpec(_Strict):
    """OpenCV pinhole camera. Intrinsics either from a ``calibration`` file or given: image
    size and the focal length in pixels (fx, fy) or as a lens (mm) with the pixel pitch (mm);
    the pose as xyz/rpy of T_base_cam (``pose``), ``look_at`` or a ``hand_eye`` file."""

    name: Annotated[str, AfterValidator(_safe_name)] = about(
        ..., "The camera's name, unique in the cell and part of output file names: at most 64 "
        "letters, digits, '_', '-', '.', not starting with '.'.", "-")
    calibration: CalibrationFile | None = about(
        None, "An intrinsics file (FILE or {file, format}) giving the image size, K and "
        "distortion; then none of width ... dist.", "-")
    width: Annotated[Count, Field(gt=0)] | None = about(
        None, "The image's width; needed without a calibration file.", "px")
    height: Annotated[Count, Field(gt=0)] | None = about(
        None, "The image's height; needed without a calibration file.", "px")
    fx: Positive | None = about(None, "The focal length along x in pixels (give fx, or lens_mm "
                                "with pixel_mm, or a calibration file).", "px")
    fy: Positive | None = about(None, "The focal length along y in pixels; default: fx.", "px")
    lens_mm: Positive | None = about(None, "The lens's focal length, with pixel_mm: fx = fy = "
                                     "lens_mm / pixel_mm.", "mm")
    pixel_mm: Positive | None = about(None, "The pixel pitch (square pixels), with lens_mm.",
                                      "mm")
    cx: Finite | None = about(None, "The principal point's x; default (width - 1) / 2, the "
                              "image centre (pixel centres at integers).", "px")
    cy: Finite | None = about(None, "The principal point's y; default (height - 1) / 2.", "px")
    dist: Annotated[list[Finite], Field(min_length=4, max_length=5)] | None = about(
        None, "OpenCV's distortion coefficients k1, k2, p1, p2[, k3]; default none.", "-")
    pose: PoseSpec | None = about(
        None, "T_base_cam: the camera's optical frame (x right, y down, z forward) in the cell's "
        "base frame (give one of pose, look_at, hand_eye).", "-")
    look_at: LookAtSpec | None = about(
        None, "The pose from an eye point, a target and an up direction (give one of pose, "
        "look_at, hand_eye).", "-")
    hand_eye: HandEyeFile | None = about(
        None, "The pose from an eye-to-hand calibration file, FILE or {file, format, robot} "
        "(give one of pose, look_at, hand_eye).", "-")

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


class CellSpec(_Strict):
    """A whole cell file."""

    name: str = about("cell", "The cell's name, in messages and reports.", "-")
    packages: dict[Annotated[str, Field(min_length=1)], str] = about(
        {}, "URDF packages: NAME -> the folder package://NAME/ stands for, relative to the cell "
        "file's folder or python://MODULE/sub/path in an installed Python package.", "-")
    robots: list[RobotSpec] = about([], "The robots; default none.", "-")
    workpieces: list[WorkpieceSpec] = about([], "The workpieces (the cell needs at least "
                                            "one).", "-")
    static: list[StaticSpec] = about([], "The static objects (tables, conveyors, stands); "
                                     "default none.", "-")
    cameras: Annotated[list[CameraSpec], Field(min_length=1)] = about(
        ..., "The fixed cameras, at least one.", "-")
    experiments: ExperimentsSpec | None = about(None, "The set-up of the paper's experiments; "
                                                "default none.", "-")
