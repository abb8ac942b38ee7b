"""Build a :class:`~cellsight.model.Cell` from a validated cell file spec
(:class:`~cellsight.model.schema.CellSpec`).

Each builder turns one part of the spec into the model's objects: solids (boxes, prisms,
segments, inline solids, mesh files), robots (DH table or URDF, with gripper and joint
vectors), workpieces, static objects, cameras (intrinsics and hand-eye poses from calibration
files) and the experiments' setup. What the schema cannot check field by field is checked here:
unique names, occluder names, joint vectors against the chain, robots and workpieces named
elsewhere. Every error is a :class:`~cellsight.errors.CellFileError` naming the file and the
field's path (``robots[1].links[2].solids[0]``); files are found relative to the cell file's
folder.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
from pydantic import BaseModel

from cellsight.camera import Camera, camera_from_lens
from cellsight.errors import CellFileError, CellsightError
from cellsight.geometry.meshes import load_mesh_solid
from cellsight.geometry.polyhedron import Polyhedron, box, prism, segment_box
from cellsight.geometry.transforms import look_at
from cellsight.kinematics import DHChain, DHLink, KinematicChain
from cellsight.model.calibration import CalibrationError, read_hand_eye, read_intrinsics
from cellsight.model.cell import Cell, ExperimentSetup, StaticObject, Workpiece
from cellsight.model.experiments_schema import ExperimentsSpec
from cellsight.model.robot import ParallelGripper, Robot
from cellsight.model.schema import (
    CalibrationFileSpec,
    CameraSpec,
    CellSpec,
    FingersSpec,
    GripperSpec,
    HandEyeSpec,
    MeshSpec,
    RobotSpec,
    SolidSpec,
    UrdfSpec,
)
from cellsight.model.urdf import (
    UrdfRobot,
    finger_gripper,
    load_urdf_robot,
)
from cellsight.model.urdf_files import UrdfError, package_folder, resolve_uri, urdf_files


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


def _check_len(file: str, where: str, values: list[float], n: int, what: str) -> np.ndarray:
    """``values`` as an array, or a :class:`CellFileError` if there are not ``n`` of them."""
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
    if isinstance(t, FingersSpec):
        raise CellFileError(file, f"{at}.tool.fingers", t.fingers,
                            "a robot's own fingers come from its URDF: this robot has none")
    palm = tuple(_solid(s, f"{rs.name}.gripper", f"{at}.tool.palm[{j}]", file, folder)
                 for j, s in enumerate(t.palm))
    jaw = _solid(t.jaw, f"{rs.name}.gripper.jaw", f"{at}.tool.jaw", file, folder)
    mount = t.mount.matrix() if T_last_flange is None else T_last_flange @ t.mount.matrix()
    return ParallelGripper.mirrored(palm, jaw, mount, t.max_opening, np.array(t.tcp))


def _urdf_gripper(rs: RobotSpec, model: UrdfRobot, at: str, file: str,
                  folder: Path, path: Path) -> ParallelGripper | None:
    """A URDF robot's gripper: its own fingers (when the URDF has a hand, and ``tool`` is
    ``{fingers: urdf}`` or not given), else the ``tool`` given."""
    if not model.fingers:
        return _gripper(rs, at, file, folder, model.T_last_flange)
    names = [f.joint for f in model.fingers]
    if isinstance(rs.tool, GripperSpec):
        raise CellFileError(file, f"{at}.tool", "a gripper",
                            f"URDF file {path} has its own fingers (joints {names}): give "
                            f"tool: {{fingers: urdf, tcp: [x, y, z]}}, or no tool, not a "
                            f"second gripper")
    tcp = (0.0, 0.0, 0.0) if rs.tool is None else rs.tool.tcp
    try:
        return finger_gripper(model.fingers, model.T_last_flange, tcp, path)
    except UrdfError as exc:
        raise CellFileError(file, f"{at}.urdf.file", rs.urdf.file, str(exc)) from exc


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
        return load_urdf_robot(path, rs.name, spec.geometry, spec.flange, packages,
                               spec.metres)
    except UrdfError as exc:
        value = getattr(spec, exc.field, spec.file)
        raise CellFileError(file, f"{at}.urdf.{exc.field}", value, str(exc)) from exc


def _robot(rs: RobotSpec, at: str, file: str, folder: Path,
           packages: dict[str, Path] | None = None) -> Robot:
    """One robot: chain (DH table or URDF), solids, gripper and joint vectors (``at``: its
    field path; ``packages``: the cell file's package folders)."""
    if rs.urdf is not None:
        model = _urdf(rs, at, file, packages or {}, folder)
        path = resolve_uri(rs.urdf.file, packages or {}, folder)
        tool = _urdf_gripper(rs, model, at, file, folder, path)
        home, final = _joint_vectors(rs, model.chain, at, file)
        return Robot(rs.name, rs.base.matrix(), model.chain, model.link_solids, tool, home,
                     final, model.solid_links, model.max_velocity)
    chain = DHChain(
        [DHLink(lk.a, lk.alpha, lk.d, lk.theta, lk.kind, tuple(lk.qlim)) for lk in rs.links],
        name=rs.name,
    )
    solids = _link_solids(rs, at, file, folder)
    tool = _gripper(rs, at, file, folder)
    home, final = _joint_vectors(rs, chain, at, file)
    return Robot(rs.name, rs.base.matrix(), chain, tuple(solids), tool, home, final)


def _workpieces(spec: CellSpec, file: str, folder: Path) -> list[Workpiece]:
    """The cell's workpieces, each with its solid and pose (and grasp, if given)."""
    return [
        Workpiece(w.name, _solid(w.solid, w.name, f"workpieces[{k}].solid", file, folder),
                  w.pose.matrix(), None if w.grasp is None else w.grasp.matrix())
        for k, w in enumerate(spec.workpieces)
    ]


def _static_objects(spec: CellSpec, file: str, folder: Path) -> list[StaticObject]:
    """The cell's static objects, each with its solids and pose."""
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
    if cs.lens_mm is not None:  # the schema: either a lens with its pixel pitch, or fx
        return camera_from_lens(cs.width, cs.height, T, cs.lens_mm, cs.pixel_mm, dist=cs.dist,
                                name=cs.name)
    return Camera.from_intrinsics(cs.width, cs.height, T, (cs.fx, cs.fy or cs.fx),
                                  principal=(cs.cx, cs.cy), dist=cs.dist, name=cs.name)


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


def _packages(spec: CellSpec, file: str, folder: Path) -> dict[str, Path]:
    """The ``packages`` map's folders (:func:`~cellsight.model.urdf.package_folder`)."""
    out = {}
    for name, value in spec.packages.items():
        try:
            out[name] = package_folder(value, folder)
        except UrdfError as exc:
            raise CellFileError(file, f"packages.{name}", value, str(exc)) from exc
    return out


def build_cell(spec: CellSpec, file: str, folder: Path) -> Cell:
    """Turn a validated :class:`CellSpec` into a :class:`Cell`."""
    packages = _packages(spec, file, folder)
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
        return Cell(spec.name, robots, parts, static, cameras, source=file, experiments=setup,
                    files=tuple(str(f) for f in _files(spec, folder, packages)))
    except CellsightError as exc:
        raise CellFileError(file, "<cell>", spec.name, str(exc)) from exc


def _files(spec: BaseModel, folder: Path, packages: dict[str, Path]) -> list[Path]:
    """Every file the cell file points to, in field order: meshes, calibration and hand-eye
    files (relative to ``folder``), URDFs and their meshes (after the cell is built, so every
    one of them loaded)."""
    found: list[Path] = []
    for value in spec.__dict__.values():
        for item in value if isinstance(value, list) else [value]:
            if isinstance(item, UrdfSpec):
                found += urdf_files(resolve_uri(item.file, packages, folder), item.geometry,
                                    packages)
            elif isinstance(item, MeshSpec | CalibrationFileSpec | HandEyeSpec):
                found.append(folder / item.file)
            elif isinstance(item, BaseModel):
                found += _files(item, folder, packages)
    return found


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


def _picks(spec: ExperimentsSpec, parts: list[Workpiece], file: str) -> tuple[str, ...]:
    """The ``experiments.picks`` of a line: workpieces of the cell, each once, each with a
    grasp, and not beside ``experiments.workpiece``."""
    if spec.picks is None:
        return ()
    if spec.workpiece is not None:
        raise CellFileError(file, "experiments.picks", spec.picks,
                            f"picks or workpiece ({spec.workpiece!r}), not both: a line's "
                            "robot picks the parts that picks lists")
    by_name = {w.name: w for w in parts}
    for k, name in enumerate(spec.picks):
        if name not in by_name:
            raise CellFileError(file, f"experiments.picks[{k}]", name,
                                f"one of the workpieces {sorted(by_name)}")
        if name in spec.picks[:k]:
            raise CellFileError(file, f"experiments.picks[{k}]", name,
                                "a workpiece not picked before: each part is picked once")
    if not spec.picks:
        raise CellFileError(file, "experiments.picks", [], "at least one workpiece")
    return tuple(spec.picks)


def _passing(spec: ExperimentsSpec, parts: list[Workpiece], picks: tuple[str, ...],
             file: str) -> tuple[str, ...]:
    """The ``experiments.passing.parts``: workpieces of the cell, each once, none picked."""
    if spec.passing is None:
        return ()
    names = [w.name for w in parts]
    for k, name in enumerate(spec.passing.parts):
        at = f"experiments.passing.parts[{k}]"
        if name not in names:
            raise CellFileError(file, at, name, f"one of the workpieces {sorted(names)}")
        if name in picks or (not picks and name == (spec.workpiece or names[0])):
            raise CellFileError(file, at, name, "a workpiece the robot does not pick")
        if name in spec.passing.parts[:k]:
            raise CellFileError(file, at, name, "a workpiece not listed before")
    return tuple(spec.passing.parts)


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
    setup = ExperimentSetup(robot=spec.robot, workpiece=spec.workpiece,
                            picks=_picks(spec, parts, file),
                            place_step=tuple(spec.place_step or (0.0, 0.0)), source=file)
    if spec.passing is not None:
        setup = replace(setup, passing=_passing(spec, parts, setup.picks, file),
                        passing_travel=tuple(spec.passing.travel),
                        passing_speed=spec.passing.speed, passing_t_start=spec.passing.t_start)
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
        grasper = spec.robot or next((r.name for r in robots
                                      if r.tool is not None and r.final is not None), None)
        if robot.name == grasper:
            raise CellFileError(file, f"{at}.robot", robot.name,
                                f"a robot other than the grasping robot ({grasper}, "
                                f"experiments.robot or the first with a tool and a FINAL "
                                f"pose): one robot cannot grasp and cross at once")
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
