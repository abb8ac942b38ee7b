"""Load and validate a YAML cell file.

The schema is written with pydantic; any error becomes a :class:`CellFileError` naming the file,
the path of the bad field (``robots[1].links[2].qlim``), the value and what was expected. Solids
are given as ``box``, ``prism``, ``segment`` (a box along a segment, for links), inline
``vertices`` + ``faces`` (CCW seen from outside), or a ``mesh`` file (STL/OBJ, path relative to
the cell file), each with an optional ``pose`` in its parent frame. An optional ``experiments``
section sets up the paper's experiments: the grasping ``robot`` and ``workpiece``, the
``conveyor`` path and a ``crossing`` robot's timed joint waypoints. A robot is either a DH
table (``links``) or a URDF file (``urdf: {file, geometry, flange}``, :mod:`cellsight.model.urdf`;
``package://NAME/...`` through the top-level ``packages: {NAME: folder}`` map, folders relative
to the cell file, or an installed package). A camera's intrinsics may come from a calibration file
(``calibration: FILE`` or ``{file, format: opencv|ros}``) and its pose from an eye-to-hand
hand-eye result (``hand_eye: FILE`` or ``{file, format: opencv|easy_handeye, robot}``),
files relative to the cell file (:mod:`cellsight.model.calibration`). Lengths in metres, angles
in radians; ``deg`` fields are accepted where noted.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    model_validator,
)

from cellsight.camera import Camera
from cellsight.errors import CellFileError, CellsightError
from cellsight.geometry.meshes import load_mesh_solid
from cellsight.geometry.polyhedron import Polyhedron, box, prism, segment_box
from cellsight.geometry.transforms import look_at, pose_from_xyz_rpy
from cellsight.kinematics import DHChain, DHLink, KinematicChain
from cellsight.model.calibration import CalibrationError, read_hand_eye, read_intrinsics
from cellsight.model.cell import Cell, ExperimentSetup, StaticObject, Workpiece
from cellsight.model.robot import ParallelGripper, Robot
from cellsight.model.urdf import UrdfError, UrdfRobot, load_urdf_robot, resolve_uri
from cellsight.model.yaml_input import load_yaml, read_cell_text

SAFE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}")  # a camera name: part of file names


def _no_bool(value: object) -> object:
    """Refuse ``true``/``false`` where a number is expected (pydantic would read 1.0, 0.0)."""
    if isinstance(value, bool):
        raise ValueError("a number, not a boolean")
    return value


def _safe_name(value: str) -> str:
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
    model_config = ConfigDict(extra="forbid")


class PoseSpec(_Strict):
    """A pose: position (m) and roll-pitch-yaw (rad), R = Rz(yaw) Ry(pitch) Rx(roll)."""

    xyz: Vec3 = [0.0, 0.0, 0.0]
    rpy: Vec3 = [0.0, 0.0, 0.0]

    def matrix(self) -> np.ndarray:
        return pose_from_xyz_rpy(self.xyz, self.rpy)


class BoxSpec(_Strict):
    size: Annotated[list[Positive], Field(min_length=3, max_length=3)]
    center: Vec3 = [0.0, 0.0, 0.0]


class PrismSpec(_Strict):
    polygon: Annotated[list[Vec2], Field(min_length=3)]
    height: Positive
    z0: Finite = 0.0


class SegmentSpec(_Strict):
    start: Vec3
    end: Vec3
    width: Positive
    height: Positive | None = None


class MeshSpec(_Strict):
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
    mount: PoseSpec = PoseSpec()
    palm: Annotated[list[SolidSpec], Field(min_length=1)]
    jaw: SolidSpec
    max_opening: Positive
    tcp: Vec3 = [0.0, 0.0, 0.0]


class UrdfSpec(_Strict):
    """A URDF robot: the file (relative to the cell file, or ``package://NAME/...``), which
    geometry becomes its solids, and the flange link the tool mounts on (default: ``tool0`` when
    it is fixed to the last actuated link, else that link)."""

    file: Annotated[str, Field(min_length=1)]
    geometry: Literal["collision", "visual"] = "collision"
    flange: Annotated[str, Field(min_length=1)] | None = None


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
    name: Annotated[str, Field(min_length=1)]
    solid: SolidSpec
    pose: PoseSpec = PoseSpec()
    grasp: PoseSpec | None = None  # tool centre point in the part frame when held


class StaticSpec(_Strict):
    name: Annotated[str, Field(min_length=1)]
    pose: PoseSpec = PoseSpec()
    solids: Annotated[list[SolidSpec], Field(min_length=1)]


class LookAtSpec(_Strict):
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


class WaypointSpec(_Strict):
    t: Positive
    q: Annotated[list[Finite], Field(min_length=1)]


class CrossingSpec(_Strict):
    """Experiment 3: a robot's own timed joint waypoints (absolute times, s)."""

    robot: Annotated[str, Field(min_length=1)]
    waypoints: Annotated[list[WaypointSpec], Field(min_length=1)]


class ExperimentsSpec(_Strict):
    robot: str | None = None
    workpiece: str | None = None
    conveyor: ConveyorSpec | None = None
    crossing: CrossingSpec | None = None


class CellSpec(_Strict):
    name: str = "cell"
    packages: dict[Annotated[str, Field(min_length=1)], str] = {}
    robots: list[RobotSpec] = []
    workpieces: list[WorkpieceSpec] = []
    static: list[StaticSpec] = []
    cameras: Annotated[list[CameraSpec], Field(min_length=1)]
    experiments: ExperimentsSpec | None = None


def _loc(parts) -> str:
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "<root>"


def _solid(spec: SolidSpec, name: str, where: str, file: str, folder: Path) -> Polyhedron:
    """Build one solid; geometry errors become CellFileErrors naming the field."""
    try:
        features = {}
        if spec.features:
            features = {"feature_names": tuple(spec.features)}
        if spec.box:
            solid = box(name, spec.box.size, spec.box.center)
        elif spec.prism:
            solid = prism(name, spec.prism.polygon, spec.prism.height, spec.prism.z0, **features)
        elif spec.segment:
            s = spec.segment
            solid = segment_box(name, s.start, s.end, s.width, s.height)
        elif spec.mesh:
            solid = load_mesh_solid(folder / spec.mesh.file, name, spec.mesh.scale)
        else:
            solid = Polyhedron(name, np.array(spec.vertices), tuple(map(tuple, spec.faces)),
                               spec.closed, **features)
        if spec.features and not spec.prism and not spec.vertices:
            solid = Polyhedron(name, solid.vertices, solid.faces, solid.closed,
                               tuple(spec.features))
    except CellsightError as exc:
        raise CellFileError(file, where, spec.model_dump(exclude_none=True), str(exc)) from exc
    return solid.transformed(spec.pose.matrix()) if spec.pose else solid


def _check_len(file: str, where: str, values, n: int, what: str) -> np.ndarray:
    if len(values) != n:
        raise CellFileError(file, where, values, f"{n} values ({what})")
    return np.array(values, dtype=float)


def _repeated(names: list[str]) -> list[str]:
    """The names that occur more than once, sorted."""
    return sorted({n for n in names if names.count(n) > 1})


def _link_solids(rs: RobotSpec, at: str, file: str, folder: Path) -> list[tuple[Polyhedron, ...]]:
    """Solids of each DH frame of a robot: its base (frame 0), then one tuple per link."""
    solids = [tuple(_solid(s, f"{rs.name}.link0", f"{at}.base_solids[{j}]", file, folder)
                    for j, s in enumerate(rs.base_solids))]
    for i, lk in enumerate(rs.links):
        solids.append(tuple(
            _solid(s, f"{rs.name}.link{i + 1}", f"{at}.links[{i}].solids[{j}]", file, folder)
            for j, s in enumerate(lk.solids)
        ))
    return solids


def _gripper(rs: RobotSpec, at: str, file: str, folder: Path,
             T_last_flange: np.ndarray | None = None) -> ParallelGripper | None:
    """A robot's parallel gripper, or None when it has no tool. ``T_last_flange``: the flange's
    pose in the chain's last frame (a URDF's ``tool0``), folded into ``T_flange_tool``."""
    if rs.tool is None:
        return None
    t = rs.tool
    palm = tuple(_solid(s, f"{rs.name}.gripper", f"{at}.tool.palm[{j}]", file, folder)
                 for j, s in enumerate(t.palm))
    jaw = _solid(t.jaw, f"{rs.name}.gripper.jaw", f"{at}.tool.jaw", file, folder)
    mount = t.mount.matrix() if T_last_flange is None else T_last_flange @ t.mount.matrix()
    return ParallelGripper(palm, jaw, mount, t.max_opening, np.array(t.tcp))


def _joint_vectors(rs: RobotSpec, chain: KinematicChain, at: str,
                   file: str) -> tuple[np.ndarray, np.ndarray | None]:
    """A robot's HOME and optional FINAL joint vectors, checked for length and limits."""
    home = _check_len(file, f"{at}.home", rs.home, chain.n, "one per joint")
    final = None if rs.final is None else _check_len(
        file, f"{at}.final", rs.final, chain.n, "one per joint")
    for field, q in (("home", home), ("final", final)):
        if q is not None:
            try:
                chain.check_q(q, check_limits=True)
            except CellsightError as exc:
                raise CellFileError(file, f"{at}.{field}", list(q), str(exc)) from exc
    return home, final


def _urdf(rs: RobotSpec, at: str, file: str, packages: dict[str, Path],
          folder: Path) -> UrdfRobot:
    """The chain, solids and flange of a robot's URDF; errors name the ``urdf`` field."""
    spec = rs.urdf
    try:
        path = resolve_uri(spec.file, packages, folder)
        return load_urdf_robot(path, rs.name, spec.geometry, spec.flange, packages)
    except UrdfError as exc:
        value = getattr(spec, exc.field, spec.file)
        raise CellFileError(file, f"{at}.urdf.{exc.field}", value, str(exc)) from exc


def _robot(rs: RobotSpec, at: str, file: str, folder: Path,
           packages: dict[str, Path] | None = None) -> Robot:
    """One robot: chain (DH table or URDF), solids, gripper and joint vectors (``at``: its
    field path; ``packages``: the cell file's package folders)."""
    if rs.urdf is not None:
        model = _urdf(rs, at, file, packages or {}, folder)
        tool = _gripper(rs, at, file, folder, model.T_last_flange)
        home, final = _joint_vectors(rs, model.chain, at, file)
        return Robot(rs.name, rs.base.matrix(), model.chain, model.link_solids, tool, home,
                     final, model.solid_links)
    chain = DHChain(
        [DHLink(lk.a, lk.alpha, lk.d, lk.theta, lk.kind, tuple(lk.qlim)) for lk in rs.links],
        name=rs.name,
    )
    solids = _link_solids(rs, at, file, folder)
    tool = _gripper(rs, at, file, folder)
    home, final = _joint_vectors(rs, chain, at, file)
    return Robot(rs.name, rs.base.matrix(), chain, tuple(solids), tool, home, final)


def _workpieces(spec: CellSpec, file: str, folder: Path) -> list[Workpiece]:
    return [
        Workpiece(w.name, _solid(w.solid, w.name, f"workpieces[{k}].solid", file, folder),
                  w.pose.matrix(), None if w.grasp is None else w.grasp.matrix())
        for k, w in enumerate(spec.workpieces)
    ]


def _static_objects(spec: CellSpec, file: str, folder: Path) -> list[StaticObject]:
    return [
        StaticObject(s.name, tuple(_solid(x, s.name, f"static[{k}].solids[{j}]", file, folder)
                                   for j, x in enumerate(s.solids)), s.pose.matrix())
        for k, s in enumerate(spec.static)
    ]


def _calibration_error(file: str, field: str, exc: CalibrationError) -> CellFileError:
    """A calibration file's error as the cell file's, naming both files (the calibration
    file's name cut to 160 characters, control characters escaped) and the key."""
    name = re.sub(r"[\x00-\x1f\x7f]", lambda m: f"\\x{ord(m.group()):02x}", exc.file)
    name = name if len(name) <= 160 else name[:60] + "..." + name[-97:]
    return CellFileError(file, field, exc.value, f"{name}: key '{exc.key}': {exc.expected}")


def _camera_pose(cs: CameraSpec, at: str, file: str, folder: Path,
                 robots: dict[str, Robot]) -> np.ndarray:
    """T_base_cam from ``pose``, ``look_at`` or a ``hand_eye`` file (in a robot's base)."""
    if cs.pose is not None:
        return cs.pose.matrix()
    if cs.look_at is not None:
        return look_at(cs.look_at.eye, cs.look_at.target, cs.look_at.up)
    he = cs.hand_eye
    T_base = np.eye(4)
    if he.robot is not None:
        if he.robot not in robots:
            raise CellFileError(file, f"{at}.hand_eye.robot", he.robot,
                                f"one of the cell's robots {sorted(robots)}")
        T_base = robots[he.robot].T_base_robot
    try:
        return T_base @ read_hand_eye(folder / he.file, he.format)
    except CalibrationError as exc:
        raise _calibration_error(file, f"{at}.hand_eye", exc) from exc


def _camera(cs: CameraSpec, at: str, file: str, folder: Path,
            robots: dict[str, Robot]) -> Camera:
    """The camera of a validated spec: intrinsics from its calibration file or through
    :meth:`Camera.from_intrinsics`; ``at``: its field path."""
    T = _camera_pose(cs, at, file, folder, robots)
    if cs.calibration is not None:
        try:
            intrinsics = read_intrinsics(folder / cs.calibration.file, cs.calibration.format)
        except CalibrationError as exc:
            raise _calibration_error(file, f"{at}.calibration", exc) from exc
        return intrinsics.camera(T, cs.name)
    return Camera.from_intrinsics(
        cs.width, cs.height, T, fx=cs.fx, fy=cs.fy, lens_mm=cs.lens_mm, pixel_mm=cs.pixel_mm,
        cx=cs.cx, cy=cs.cy, dist=cs.dist, name=cs.name)


def _cameras(spec: CellSpec, file: str, folder: Path,
             robots: list[Robot] | None = None) -> list[Camera]:
    """The cell's cameras; calibration files relative to ``folder``, hand-eye poses in the
    base frame of one of ``robots`` where the entry names one."""
    by_name = {r.name: r for r in robots or []}
    cameras = []
    for c, cs in enumerate(spec.cameras):
        try:
            cameras.append(_camera(cs, f"cameras[{c}]", file, folder, by_name))
        except CellFileError:
            raise
        except (CellsightError, ValueError) as exc:
            raise CellFileError(file, f"cameras[{c}]", cs.model_dump(exclude_none=True),
                                str(exc)) from exc
    return cameras


def build_cell(spec: CellSpec, file: str, folder: Path) -> Cell:
    """Turn a validated :class:`CellSpec` into a :class:`Cell`."""
    packages = {name: folder / sub for name, sub in spec.packages.items()}
    robots = [_robot(rs, f"robots[{r}]", file, folder, packages)
              for r, rs in enumerate(spec.robots)]
    parts = _workpieces(spec, file, folder)
    static = _static_objects(spec, file, folder)
    cameras = _cameras(spec, file, folder, robots)
    if not parts:
        raise CellFileError(file, "workpieces", spec.workpieces,
                            "at least one workpiece (cellsight predicts which of a workpiece's "
                            "feature points the cameras see)")
    names = [r.name for r in robots] + [w.name for w in parts] + [s.name for s in static]
    if dup := _repeated(names):
        raise CellFileError(file, "name", dup, "unique names of robots, workpieces, static")
    _check_occluder_names(robots, parts, static, file)
    if dup := _repeated([c.name for c in cameras]):
        raise CellFileError(file, "cameras[].name", dup, "unique camera names")
    setup = _experiments(spec.experiments, robots, parts, file)
    try:
        return Cell(spec.name, robots, parts, static, cameras, source=file, experiments=setup)
    except CellsightError as exc:
        raise CellFileError(file, "<cell>", spec.name, str(exc)) from exc


def _with_solids(label: str, n: int) -> list[str]:
    """An occluder's label and its solids' names (``label.1``, ... when it has several)."""
    return [label] + ([f"{label}.{j + 1}" for j in range(n)] if n > 1 else [])


def _occluder_names(robots: list[Robot], parts: list[Workpiece],
                    static: list[StaticObject]) -> list[tuple[str, str]]:
    """(name, owner's field path) of every occluder label and solid name the :class:`Cell` will
    give: ``R7AX.link2`` (``R7AX.link2.1``, ... for several solids; a URDF robot's links
    ``UR5.upper_arm_link``), ``R7AX.gripper``
    (``.jaw1``, ``.jaw2``), each workpiece's and static object's name."""
    out = []
    for r, robot in enumerate(robots):
        for i, link, solids in robot.link_groups():
            owner = (f"robots[{r}].urdf" if robot.solid_links is not None
                     else f"robots[{r}].base_solids" if i == 0 else f"robots[{r}].links[{i - 1}]")
            out += [(n, owner) for n in _with_solids(f"{robot.name}.{link}", len(solids))]
        if robot.tool is not None:
            label = f"{robot.name}.gripper"
            names = _with_solids(label, len(robot.tool.palm)) + [f"{label}.jaw1", f"{label}.jaw2"]
            out += [(n, f"robots[{r}].tool") for n in names]
    out += [(w.name, f"workpieces[{k}].name") for k, w in enumerate(parts)]
    for k, obj in enumerate(static):
        out += [(n, f"static[{k}].name") for n in _with_solids(obj.name, len(obj.solids))]
    return out


def _check_occluder_names(robots: list[Robot], parts: list[Workpiece],
                          static: list[StaticObject], file: str) -> None:
    """Refuse a workpiece or static object whose name (or a solid's name) is another
    occluder's label or solid name: occlusion reports name occluders by label."""
    seen: dict[str, str] = {}
    for name, owner in _occluder_names(robots, parts, static):
        first = seen.setdefault(name, owner)
        if first != owner:
            raise CellFileError(file, owner, name, f"a name no other occluder has; {first} is "
                                f"already named {name!r}")


def _experiments(spec: ExperimentsSpec | None, robots: list[Robot], parts: list[Workpiece],
                 file: str) -> ExperimentSetup:
    """Check the ``experiments`` section against the cell's robots and workpieces."""
    if spec is None:
        return ExperimentSetup(source=file)
    by_name = {r.name: r for r in robots}
    for field, name, names in (("robot", spec.robot, by_name),
                               ("workpiece", spec.workpiece, [w.name for w in parts])):
        if name is not None and name not in names:
            raise CellFileError(file, f"experiments.{field}", name, f"one of {sorted(names)}")
    grasping = by_name.get(spec.robot)
    if grasping is not None and (grasping.tool is None or grasping.final is None):
        raise CellFileError(file, "experiments.robot", spec.robot,
                            "a robot with a tool and a FINAL pose (robots[].tool, "
                            f"robots[].final) to grasp the part; {spec.robot} has no "
                            f"{'tool' if grasping.tool is None else 'final'}")
    setup = ExperimentSetup(robot=spec.robot, workpiece=spec.workpiece, source=file)
    if spec.conveyor is not None:
        setup = replace(setup, conveyor_points=np.array(spec.conveyor.points),
                        conveyor_speed=spec.conveyor.speed,
                        conveyor_t_start=spec.conveyor.t_start)
    if spec.crossing is not None:
        at = "experiments.crossing"
        robot = by_name.get(spec.crossing.robot)
        if robot is None:
            raise CellFileError(file, f"{at}.robot", spec.crossing.robot,
                                f"one of {sorted(by_name)}")
        waypoints, last = [], 0.0
        for k, w in enumerate(spec.crossing.waypoints):
            if w.t <= last:
                raise CellFileError(file, f"{at}.waypoints[{k}].t", w.t,
                                    f"a time after the previous waypoint's ({last} s)")
            q = _check_len(file, f"{at}.waypoints[{k}].q", w.q, robot.chain.n, "one per joint")
            try:
                robot.chain.check_q(q, check_limits=True)
            except CellsightError as exc:
                raise CellFileError(file, f"{at}.waypoints[{k}].q", w.q, str(exc)) from exc
            waypoints.append((w.t, q))
            last = w.t
        setup = replace(setup, crossing_robot=robot.name, crossing_waypoints=tuple(waypoints))
    return setup


@dataclass(frozen=True)
class BuiltinCell:
    """A cell file shipped with cellsight, loaded by name (``load_cell("ur-cell")``)."""

    name: str
    file: str  # in ``cellsight/data``
    description: str

    @property
    def path(self) -> Path:
        return Path(__file__).resolve().parent.parent / "data" / self.file


BUILTIN_CELLS: dict[str, BuiltinCell] = {cell.name: cell for cell in (
    BuiltinCell("dual-arm", "dual_arm_cell.yaml",
                "the paper's cell: R7AX on a track and R6AX (SmartSix-like DH surrogates), "
                "two cameras, a conveyor"),
    BuiltinCell("ur-cell", "ur_cell.yaml",
                "two UR5 (example-robot-data URDF, collision meshes), three cameras, a conveyor"),
)}
DEFAULT_CELL = "dual-arm"


def builtin_cell_path(name: str = DEFAULT_CELL) -> Path:
    """Path of a built-in cell's file (default: the dual-arm cell)."""
    return BUILTIN_CELLS[name].path


def cell_path(cell: str | Path | None = None) -> Path:
    """The file of ``cell``: an existing file, else a built-in cell's name (None: the default
    built-in cell); a :class:`CellFileError` listing the built-in cells' names otherwise."""
    if cell is None:
        return builtin_cell_path()
    path = Path(cell)
    try:
        if path.is_file():
            return path
    except (OSError, ValueError):  # not a usable path (too long, a NUL byte)
        pass
    if isinstance(cell, str) and cell in BUILTIN_CELLS:
        return BUILTIN_CELLS[cell].path
    raise CellFileError(str(cell), "<file>", str(cell), "an existing YAML cell file or the name "
                        f"of a built-in cell ({', '.join(BUILTIN_CELLS)})")


def parse_cell_text(text: str, file: str, folder: Path) -> tuple[CellSpec, dict]:
    """Parse and validate YAML text (a repeated key is an error); returns the spec and the raw
    mapping."""
    raw = load_yaml(text, file)
    if not isinstance(raw, dict):
        raise CellFileError(file, "<root>", raw, "a mapping with robots, workpieces, cameras")
    try:
        spec = CellSpec.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        raise CellFileError(file, _loc(err["loc"]), err.get("input"), err["msg"]) from exc
    return spec, raw


def load_cell(path: str | Path | None = None) -> Cell:
    """Load a cell from a YAML file, or a built-in cell by name (``"dual-arm"``, ``"ur-cell"``:
    :data:`BUILTIN_CELLS`); the built-in dual-arm cell when ``path`` is None. A file of a
    built-in cell's name in the working folder wins over the built-in cell."""
    path = cell_path(path)
    spec, _ = parse_cell_text(read_cell_text(path), str(path), path.parent)
    return build_cell(spec, str(path), path.parent)
