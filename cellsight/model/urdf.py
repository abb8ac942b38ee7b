"""Robots from URDF files: a :class:`~cellsight.kinematics.SerialChain` and the links' solids.

The URDF is parsed with ``yourdfpy``. The actuated joints (revolute, continuous, prismatic)
must form one serial chain from the root link; they are the robot's joints, in chain order.
A gripper's fingers are the exception: two prismatic joints with nothing actuated beyond them,
one mimicking the other (``<mimic joint multiplier offset>``: its value is ``multiplier`` times
the leader's plus ``offset``), hanging off links fixed to the chain's last frame, as the
Franka Panda's hand. They are not joints of the chain: they become the robot's parallel gripper
(:func:`finger_gripper`), the leader its jaw 1 and the opening the distance between the two
fingers' frames along the leader's axis. Any other mimic joint is refused.
Fixed joints fold into their parent: a link fixed to the child link of actuated joint ``i``
(or to the root) moves with chain frame ``i`` (0: the root link's frame), and keeps its own name
as its solids' label. Frames (URDF convention): frame ``i`` is the child link of actuated joint
``i``, ``T_{i-1,i}(q) = origin_i @ M(q_i)`` with the joint's axis in frame ``i``.

Geometry (``collision`` or ``visual`` elements) becomes :class:`Polyhedron` solids in the frame
that carries the link, origin offsets applied: meshes (STL/OBJ through
:func:`~cellsight.geometry.meshes.load_mesh_solid`, URDF ``scale`` per axis), boxes, cylinders
as right prisms over a regular ``CYLINDER_SIDES``-gon inscribed in the circle (vertices on the
true surface; radial error at most ``r (1 - cos(pi / 24))``, 0.86 % of r), spheres as a UV
sphere of ``SPHERE_BANDS`` latitude bands and ``SPHERE_SECTORS`` longitudes, vertices on the
sphere (planar quads and cap triangles; radial error at most 1.9 % of r).

Lengths in metres, angles in radians. The file is found and read, hostile input refused
before yourdfpy sees it, by :mod:`.urdf_files`; lengths that are not metres are refused here:
a geometry element reaching over ``MAX_REACH`` from its link frame, or a link over
``MAX_REACH`` from the root link along the joint origins and prismatic travel (a URDF or a
mesh in millimetres or inches).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.errors import CellsightError, GeometryError
from cellsight.geometry.meshes import load_mesh_solid
from cellsight.geometry.polyhedron import Polyhedron, box, joined, prism
from cellsight.geometry.transforms import invert_pose, make_pose
from cellsight.kinematics import JointKind, SerialChain
from cellsight.model.robot import Jaw, ParallelGripper
from cellsight.model.urdf_files import UrdfError, _parse, _tree, resolve_uri

CYLINDER_SIDES = 24
SPHERE_BANDS, SPHERE_SECTORS = 8, 16
CONTINUOUS_LIMIT = 2 * np.pi  # rad, limits given to a continuous joint: (-2 pi, 2 pi)
MAX_REACH = 20.0  # m, farthest a link or a geometry may be: beyond, the lengths are not metres
_KINDS: dict[str, JointKind] = {"revolute": "revolute", "continuous": "revolute",
                                "prismatic": "prismatic"}


@dataclass(frozen=True)
class UrdfFinger:
    """A finger of a URDF hand: its prismatic ``joint`` and child ``link``, the link's frame
    at the joint's zero in the chain's last frame (``T_last_finger0``, m), the joint's unit
    ``axis`` in that frame's axes, its value as ``multiplier`` times the leader's plus
    ``offset`` (m; 1 and 0 for the leader), the joint's limits (m), and ``solid``: the finger
    link's solids and those of links fixed to it, joined, in the finger link's frame."""

    joint: str
    link: str
    T_last_finger0: np.ndarray
    axis: np.ndarray
    multiplier: float
    offset: float
    limits: tuple[float, float]
    solid: Polyhedron


@dataclass(frozen=True)
class UrdfRobot:
    """What a URDF gives a :class:`~cellsight.model.Robot`: the chain (frame 0 = root link),
    per frame the solids and the URDF link each belongs to, and ``T_last_flange``, the flange
    link's pose in frame n (the gripper mounts on the flange), and ``max_velocity``: each
    actuated joint's rated speed (its ``limit velocity``, rad/s or m/s; inf where not a positive
    number); ``fingers``: the hand's two fingers, leader first, or none."""

    chain: SerialChain
    link_solids: tuple[tuple[Polyhedron, ...], ...]
    solid_links: tuple[tuple[str, ...], ...]
    T_last_flange: np.ndarray
    flange: str
    max_velocity: np.ndarray
    fingers: tuple[UrdfFinger, ...] = ()


@dataclass
class _Walk:
    """Chain under construction: per actuated joint its origin in the previous frame, axis,
    kind and limits; per link its frame index and pose in that frame."""

    origins: list
    axes: list
    kinds: list
    qlim: list
    joint_links: list
    link_frame: dict
    joint_names: list = field(default_factory=list)
    speeds: list = field(default_factory=list)
    fingers: list = field(default_factory=list)  # (finger joint, its parent's frame)
    children: dict = field(default_factory=dict)  # link -> its child joints


def _actuated(walk: _Walk, j, frame: int, T_frame_parent: np.ndarray, path: Path) -> None:
    """Append actuated joint ``j`` (parent link in chain frame ``frame``) to the chain."""
    if j.type not in _KINDS:
        raise UrdfError("file", f"URDF file {path}: joint {j.name!r} of type {j.type!r}; "
                        f"expected revolute, continuous, prismatic or fixed")
    if j.mimic is not None:
        raise UrdfError("file", f"URDF file {path}: joint {j.name!r} mimics {j.mimic.joint!r}; "
                        f"a mimic joint is supported only between a gripper's two fingers "
                        f"(prismatic joints with nothing actuated beyond them)")
    if frame != len(walk.origins):
        raise UrdfError("file", f"URDF file {path}: joint {j.name!r} branches off the chain "
                        f"of actuated joints; only serial chains are supported")
    if j.type == "continuous":
        lo, hi = -CONTINUOUS_LIMIT, CONTINUOUS_LIMIT
    elif j.limit is None or j.limit.lower is None or j.limit.upper is None \
            or not j.limit.lower < j.limit.upper:
        raise UrdfError("file", f"URDF file {path}: joint {j.name!r} needs <limit lower "
                        f"upper> with lower < upper")
    else:
        lo, hi = float(j.limit.lower), float(j.limit.upper)
    origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
    walk.origins.append(T_frame_parent @ origin)
    walk.axes.append([1.0, 0.0, 0.0] if j.axis is None else np.asarray(j.axis, dtype=float))
    walk.kinds.append(_KINDS[j.type])
    walk.qlim.append((lo, hi))
    walk.joint_links.append(j.child)
    walk.joint_names.append(j.name)
    speed = None if j.limit is None else j.limit.velocity
    walk.speeds.append(float(speed) if speed is not None and float(speed) > 0 else np.inf)


def _actuated_below(link: str, children: dict[str, list]) -> bool:
    """Whether any joint under ``link`` is not fixed."""
    return any(j.type != "fixed" or _actuated_below(j.child, children) for j in children[link])


def _finger_joints(robot, children: dict[str, list], path: Path) -> set[str]:
    """The names of a hand's finger joints: a mimic joint and its leader, both prismatic with
    nothing actuated beyond them (none when no joint mimics another); a :class:`UrdfError`
    for a mimic that is not such a pair."""
    joints = {j.name: j for j in robot.joints}
    mimics = [j for j in robot.joints if j.mimic is not None]
    if not mimics:
        return set()
    pair = [mimics[0], joints.get(mimics[0].mimic.joint)]
    for j in pair:
        if j is None:
            raise UrdfError("file", f"URDF file {path}: joint {mimics[0].name!r} mimics "
                            f"{mimics[0].mimic.joint!r}, which is not a joint of the file")
        if j.type != "prismatic" or _actuated_below(j.child, children):
            raise UrdfError("file", f"URDF file {path}: joint {mimics[0].name!r} mimics "
                            f"{mimics[0].mimic.joint!r}: a mimic joint is supported only "
                            f"between a gripper's two fingers (prismatic joints with nothing "
                            f"actuated beyond them); {j.name!r} is {j.type}"
                            + ("" if j.type != "prismatic" else " with actuated joints beyond"))
    if len(mimics) > 1 or pair[1].mimic is not None:
        names = sorted(j.name for j in mimics)
        raise UrdfError("file", f"URDF file {path}: mimic joints {names}: a hand of two fingers "
                        f"(one leading, one mimicking it) is supported, not more")
    return {j.name for j in pair}


def _walk(robot, path: Path) -> _Walk:
    """Depth-first walk from the root: the chain of actuated joints and where each link sits;
    a hand's finger joints (:func:`_finger_joints`) are set aside with their parents' frames."""
    root, children = _tree(robot, path)
    fingers = _finger_joints(robot, children, path)
    walk = _Walk([], [], [], [], [root], {}, children=children)
    stack = [(root, 0, np.eye(4))]
    while stack:
        link, frame, T = stack.pop()
        walk.link_frame[link] = (frame, T)
        for j in reversed(children[link]):
            if j.name in fingers:
                walk.fingers.append((j, frame))
            elif j.type == "fixed":
                origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
                stack.append((j.child, frame, T @ origin))
            else:
                _actuated(walk, j, frame, T, path)
                stack.append((j.child, len(walk.origins), np.eye(4)))
    if not walk.origins:
        raise UrdfError("file", f"URDF file {path}: no actuated joint")
    for j, frame in walk.fingers:
        if frame != len(walk.origins):
            raise UrdfError("file", f"URDF file {path}: finger joint {j.name!r} hangs off link "
                            f"{j.parent!r}, which moves with joint "
                            f"{walk.joint_names[frame - 1] if frame else 'none'!r}: a hand's "
                            f"fingers must hang off links fixed to the last actuated link")
    walk.fingers.sort(key=lambda f: f[0].mimic is not None)  # the leader first
    return walk


def _outward(name: str, vertices: np.ndarray, faces: list[tuple[int, ...]]) -> Polyhedron:
    """A convex solid centred on the origin, each face turned counter-clockwise from outside."""
    out = []
    for f in faces:
        p = vertices[list(f)]
        normal = np.cross(p[1] - p[0], p[2] - p[0])
        out.append(f if normal @ p.mean(axis=0) > 0 else tuple(reversed(f)))
    return Polyhedron(name, vertices, tuple(out))


def cylinder_solid(name: str, radius: float, length: float) -> Polyhedron:
    """A URDF cylinder (axis z, centred on the origin) as a prism over an inscribed regular
    ``CYLINDER_SIDES``-gon (m)."""
    a = 2 * np.pi * np.arange(CYLINDER_SIDES) / CYLINDER_SIDES
    return prism(name, radius * np.column_stack([np.cos(a), np.sin(a)]), length, -length / 2)


def sphere_solid(name: str, radius: float) -> Polyhedron:
    """A URDF sphere (centred on the origin) as a UV sphere, vertices on the sphere (m):
    ``SPHERE_BANDS`` latitude bands of ``SPHERE_SECTORS`` planar faces each."""
    polar = np.pi * np.arange(1, SPHERE_BANDS) / SPHERE_BANDS
    lon = 2 * np.pi * np.arange(SPHERE_SECTORS) / SPHERE_SECTORS
    ring = np.array([[np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)]
                     for t in polar for p in lon])
    v = radius * np.vstack([[0.0, 0.0, 1.0], ring, [0.0, 0.0, -1.0]])
    s, bottom = SPHERE_SECTORS, len(v) - 1

    def at(band: int, k: int) -> int:
        return 1 + band * s + k % s

    faces = [(0, at(0, k), at(0, k + 1)) for k in range(s)]
    faces += [(at(b, k), at(b + 1, k), at(b + 1, k + 1), at(b, k + 1))
              for b in range(SPHERE_BANDS - 2) for k in range(s)]
    faces += [(bottom, at(SPHERE_BANDS - 2, k + 1), at(SPHERE_BANDS - 2, k)) for k in range(s)]
    return _outward(name, v, faces)


def _positive(name: str, what: str, value: float) -> None:
    """Refuses a cylinder or sphere size that is not positive (a :class:`GeometryError`)."""
    if not value > 0:
        raise GeometryError(f"solid '{name}': {what} must be positive, got {float(value)}")


def _shape(geometry, name: str, packages: Mapping[str, Path], folder: Path) -> Polyhedron:
    """One URDF geometry element as a solid in its own (origin) frame."""
    if geometry.box is not None:
        return box(name, geometry.box.size)
    if geometry.cylinder is not None:
        _positive(name, "cylinder radius", geometry.cylinder.radius)
        _positive(name, "cylinder length", geometry.cylinder.length)
        return cylinder_solid(name, geometry.cylinder.radius, geometry.cylinder.length)
    if geometry.sphere is not None:
        _positive(name, "sphere radius", geometry.sphere.radius)
        return sphere_solid(name, geometry.sphere.radius)
    if geometry.mesh is None:
        raise UrdfError("geometry", f"solid {name}: a geometry with no shape")
    file = resolve_uri(geometry.mesh.filename, packages, folder)
    scale = np.broadcast_to(np.asarray(1.0 if geometry.mesh.scale is None
                                       else geometry.mesh.scale, dtype=float), (3,))
    if not np.all(scale > 0):
        raise UrdfError("geometry", f"solid {name}: mesh scale must be positive, got {scale}")
    solid = load_mesh_solid(file, name, float(scale[0]))
    if np.ptp(scale) == 0:
        return solid
    return Polyhedron(name, solid.vertices * (scale / scale[0]), solid.faces, solid.closed)


def _scale_walk(walk: _Walk, scale: float) -> None:
    """Lengths of the file's unit in metres: joint origins, link placements, prismatic
    limits."""
    if scale == 1.0:
        return
    for T in walk.origins:
        T[:3, 3] *= scale
    for _, T in walk.link_frame.values():
        T[:3, 3] *= scale
    walk.qlim = [(lo * scale, hi * scale) if kind == "prismatic" else (lo, hi)
                 for (lo, hi), kind in zip(walk.qlim, walk.kinds, strict=True)]
    walk.speeds = [v * scale if kind == "prismatic" else v
                   for v, kind in zip(walk.speeds, walk.kinds, strict=True)]


def _link_shapes(link, geometry: str, robot_name: str, packages: Mapping[str, Path],
                 path: Path, scale: float) -> list[Polyhedron]:
    """A link's ``geometry`` elements as solids in the link's frame; the file's lengths times
    ``scale`` (m)."""
    shapes = []
    elements = link.collisions if geometry == "collision" else link.visuals
    for k, element in enumerate(elements):
        name = f"{robot_name}.{link.name}"
        try:
            shape = _shape(element.geometry, name, packages, path.parent)
        except CellsightError as exc:
            raise UrdfError("geometry", f"URDF file {path}: link {link.name!r}, "
                            f"{geometry} {k}: {exc}") from exc
        origin = np.eye(4) if element.origin is None else np.asarray(element.origin, float)
        if scale != 1.0:
            shape = shape.transformed(np.diag([scale, scale, scale, 1.0]))
            origin = origin.copy()
            origin[:3, 3] *= scale
        placed = shape.vertices @ origin[:3, :3].T + origin[:3, 3]
        reach = float(np.linalg.norm(placed, axis=1).max())
        if reach > MAX_REACH:
            raise UrdfError("geometry", f"URDF file {path}: link {link.name!r}, {geometry} "
                            f"{k} reaches {reach:.4g} m from the link frame, over "
                            f"{MAX_REACH:g} m: lengths must be metres (a mesh in mm "
                            f"needs scale=\"0.001 0.001 0.001\", in inches 0.0254 each)")
        shapes.append(shape.transformed(origin))
    return shapes


def _solids(robot, walk: _Walk, geometry: str, robot_name: str, packages: Mapping[str, Path],
            path: Path, scale: float = 1.0) -> tuple[list[list[Polyhedron]], list[list[str]]]:
    """Per chain frame, the solids of the links it carries (in that frame) and their links;
    the file's lengths times ``scale`` (m). A hand's fingers are not the chain's."""
    n = len(walk.origins)
    solids: list[list[Polyhedron]] = [[] for _ in range(n + 1)]
    links: list[list[str]] = [[] for _ in range(n + 1)]
    for link in robot.links:
        if link.name not in walk.link_frame:
            continue
        frame, T_frame_link = walk.link_frame[link.name]
        for shape in _link_shapes(link, geometry, robot_name, packages, path, scale):
            solids[frame].append(shape.transformed(T_frame_link))
            links[frame].append(link.name)
    return solids, links


def _fingers(robot, walk: _Walk, geometry: str, robot_name: str,
             packages: Mapping[str, Path], path: Path, scale: float) -> tuple[UrdfFinger, ...]:
    """The hand's fingers (leader first), their solids those of the finger link and the links
    fixed below it, joined in the finger link's frame; lengths times ``scale`` (m)."""
    links = {lk.name: lk for lk in robot.links}
    fingers = []
    for j, _ in walk.fingers:
        T_last_parent = walk.link_frame[j.parent][1]  # the parent is on the last frame
        shapes, stack = [], [(j.child, np.eye(4))]
        while stack:
            name, T_finger_link = stack.pop()
            shapes += [s.transformed(T_finger_link) for s in
                       _link_shapes(links[name], geometry, robot_name, packages, path, scale)]
            for below in walk.children[name]:
                origin = np.asarray(below.origin if below.origin is not None else np.eye(4),
                                    dtype=float).copy()
                origin[:3, 3] *= scale
                stack.append((below.child, T_finger_link @ origin))
        if not shapes:
            raise UrdfError("geometry", f"URDF file {path}: finger link {j.child!r} has no "
                            f"{geometry} geometry: a finger needs a solid")
        origin = np.asarray(j.origin if j.origin is not None else np.eye(4), dtype=float).copy()
        origin[:3, 3] *= scale
        axis = np.asarray([1.0, 0.0, 0.0] if j.axis is None else j.axis, dtype=float)
        mimic = j.mimic
        multiplier = 1.0 if mimic is None or mimic.multiplier is None else float(mimic.multiplier)
        offset = 0.0 if mimic is None or mimic.offset is None else float(mimic.offset) * scale
        if j.limit is None or j.limit.lower is None or j.limit.upper is None \
                or not j.limit.lower < j.limit.upper:
            raise UrdfError("file", f"URDF file {path}: finger joint {j.name!r} needs <limit "
                            f"lower upper> with lower < upper")
        fingers.append(UrdfFinger(
            j.name, j.child, T_last_parent @ origin, axis / np.linalg.norm(axis), multiplier,
            offset, (float(j.limit.lower) * scale, float(j.limit.upper) * scale),
            joined(f"{robot_name}.{j.child}", shapes)))
    return tuple(fingers)


def _check_reach(walk: _Walk, path: Path) -> None:
    """Refuses a link farther than ``MAX_REACH`` from the root link along the joint origins
    and the prismatic joints' travel (``max(|lower|, |upper|)``): lengths not in metres."""
    along = np.zeros(len(walk.origins) + 1)
    for i, (origin, kind, (lo, hi)) in enumerate(zip(walk.origins, walk.kinds, walk.qlim,
                                                    strict=True)):
        travel = max(abs(lo), abs(hi)) if kind == "prismatic" else 0.0
        along[i + 1] = along[i] + np.linalg.norm(origin[:3, 3]) + travel
    reach = {link: along[frame] + np.linalg.norm(T[:3, 3])
             for link, (frame, T) in walk.link_frame.items()}
    far = max(reach, key=reach.__getitem__)
    if reach[far] > MAX_REACH:
        raise UrdfError("file", f"URDF file {path}: link {far!r} is up to {reach[far]:.4g} m "
                        f"from the root link (joint origins and prismatic travel), over "
                        f"{MAX_REACH:g} m: lengths must be metres (a URDF in mm or inches? "
                        f"give its unit in the cell file: urdf: {{file: ..., scale: inch}}, "
                        f"or mm, cm, tenth-inch, or metres per unit)")


def _flange(walk: _Walk, flange: str | None, path: Path) -> tuple[str, np.ndarray]:
    """The flange link (given, else ``tool0`` when it is fixed to frame n, else frame n's
    link) and its pose in frame n."""
    n = len(walk.origins)
    name = flange
    if name is None:
        fixed = walk.link_frame.get("tool0")
        name = "tool0" if fixed is not None and fixed[0] == n else walk.joint_links[-1]
    where = walk.link_frame.get(name)
    if where is None or where[0] != n:
        on_last = sorted(k for k, (f, _) in walk.link_frame.items() if f == n)
        raise UrdfError("flange", f"URDF file {path}: flange {name!r} is not a link fixed to the "
                        f"last actuated joint's link; those are {on_last}")
    return name, where[1]


PARALLEL_TOL = 1e-6  # |1 - |cos||, fingers' axes and the leader's: a parallel gripper's


def finger_gripper(fingers: tuple[UrdfFinger, ...], T_last_flange: np.ndarray, tcp,
                   path: Path) -> ParallelGripper:
    """A URDF hand as the robot's parallel gripper: the tool frame at the leading finger's
    joint origin, y along its axis (the other axes those of the joint's frame, turned the least
    that does it), the jaws the fingers (jaw 1 the leader, jaw 2 its mimic), no palm of its own
    (the hand's solids stay the robot's links), ``tcp`` in the tool frame (m); the opening is
    the distance between the fingers' frames along tool y. A :class:`UrdfError` when the
    fingers do not slide along one line, apart as the leader's value rises."""
    leader = fingers[0]
    e_y = np.array([0.0, 1.0, 0.0])
    turn, _ = Rotation.align_vectors([leader.axis], [e_y])
    T_last_tool = leader.T_last_finger0 @ make_pose(turn.as_matrix())
    T_tool_last = invert_pose(T_last_tool)
    jaws = []
    for finger in fingers:
        T_tool_jaw0 = T_tool_last @ finger.T_last_finger0
        axis = T_tool_jaw0[:3, :3] @ finger.axis
        if abs(abs(axis[1]) - 1.0) > PARALLEL_TOL:
            raise UrdfError("file", f"URDF file {path}: finger joint {finger.joint!r} slides "
                            f"along {np.round(axis, 4).tolist()} in the frame of "
                            f"{leader.joint!r}'s axis (y): a parallel gripper's fingers slide "
                            f"along one line")
        jaws.append(Jaw(finger.solid, T_tool_jaw0, axis, finger.multiplier, finger.offset,
                        finger.joint, finger.link))
    first, second = jaws
    at_zero = float(first.T_tool_jaw0[1, 3] - second.T_tool_jaw0[1, 3] - second.axis[1]
                    * second.offset)
    gain = float(first.axis[1] - second.multiplier * second.axis[1])
    if gain <= 0:
        raise UrdfError("file", f"URDF file {path}: fingers {leader.joint!r} and "
                        f"{fingers[1].joint!r} do not move apart as {leader.joint!r}'s value "
                        f"rises (mimic multiplier {fingers[1].multiplier:g})")
    lo, hi = leader.limits
    return ParallelGripper((), (first, second), invert_pose(T_last_flange) @ T_last_tool,
                           at_zero + gain * hi, np.asarray(tcp, dtype=float), gain, at_zero,
                           (lo, hi))


@dataclass(frozen=True)
class FixedFrames:
    """A URDF's fixed links, each on its parent link: ``transforms`` (parent link, child link,
    ``T_parent_child`` in m), the chain's ``links`` (frames 0..n), the ``flange`` link's name
    and ``T_last_flange`` (the flange in the chain's last frame)."""

    transforms: list[tuple[str, str, np.ndarray]]
    links: tuple[str, ...]
    flange: str
    T_last_flange: np.ndarray


def fixed_frames(path: Path, scale: float = 1.0, flange: str | None = None) -> FixedFrames:
    """The fixed links of the URDF in ``path`` (``scale``: metres per length unit of the file;
    ``flange``: the tool's link, None for the default of :func:`load_urdf_robot`), placed as
    :func:`load_urdf_robot` places them; a :class:`UrdfError` naming the file."""
    robot = _parse(path)
    walk = _walk(robot, path)
    _scale_walk(walk, float(scale))
    transforms = [(j.parent, j.child,
                   invert_pose(walk.link_frame[j.parent][1]) @ walk.link_frame[j.child][1])
                  for j in robot.joints if j.type == "fixed" and j.child in walk.link_frame]
    name, T_last_flange = _flange(walk, flange, path)
    return FixedFrames(transforms, tuple(walk.joint_links), name, T_last_flange)


def load_urdf_robot(path: Path, robot_name: str, geometry: str = "collision",
                    flange: str | None = None,
                    packages: Mapping[str, Path] | None = None,
                    scale: float = 1.0) -> UrdfRobot:
    """Chain, solids and flange of the URDF robot in ``path`` (see the module docstring);
    ``geometry`` is ``collision`` or ``visual``; ``scale``: metres per length unit of the file
    (0.0254 for a URDF in inches: joint origins, prismatic limits and geometry scaled); a
    :class:`UrdfError` naming the URDF file."""
    packages = dict(packages or {})
    robot = _parse(path)
    walk = _walk(robot, path)
    _scale_walk(walk, float(scale))
    _check_reach(walk, path)
    solids, links = _solids(robot, walk, geometry, robot_name, packages, path, float(scale))
    name, T_last_flange = _flange(walk, flange, path)
    try:
        chain = SerialChain(np.array(walk.origins), np.array(walk.axes), walk.kinds, walk.qlim,
                            name=robot_name, link_names=tuple(walk.joint_links),
                            joint_names=tuple(walk.joint_names))
    except CellsightError as exc:
        raise UrdfError("file", f"URDF file {path}: {exc}") from exc
    fingers = _fingers(robot, walk, geometry, robot_name, packages, path, float(scale))
    return UrdfRobot(chain, tuple(map(tuple, solids)), tuple(map(tuple, links)), T_last_flange,
                     name, np.array(walk.speeds, dtype=float), fingers)
