"""Robots from URDF files: a :class:`~cellsight.kinematics.SerialChain` and the links' solids.

The URDF is parsed with ``yourdfpy``. The actuated joints (revolute, continuous, prismatic)
must form one serial chain from the root link; they are the robot's joints, in chain order.
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

``package://NAME/path`` resolves through the cell file's ``packages`` map, else through an
installed package's share folder (``<prefix>/share/NAME``, also the ``cmeel.prefix`` of wheels
such as ``example-robot-data``). Other relative paths are relative to the URDF file.
Lengths in metres, angles in radians.
"""

from __future__ import annotations

import site
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellsight.errors import CellsightError
from cellsight.geometry.meshes import load_mesh_solid
from cellsight.geometry.polyhedron import Polyhedron, box, prism
from cellsight.kinematics import JointKind, SerialChain

CYLINDER_SIDES = 24
SPHERE_BANDS, SPHERE_SECTORS = 8, 16
CONTINUOUS_LIMIT = 2 * np.pi  # rad, limits given to a continuous joint: (-2 pi, 2 pi)
_KINDS: dict[str, JointKind] = {"revolute": "revolute", "continuous": "revolute",
                                "prismatic": "prismatic"}


class UrdfError(CellsightError, ValueError):
    """A URDF robot cannot be built; ``field`` is the ``urdf`` sub-field at fault (``file``,
    ``geometry`` or ``flange``)."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        super().__init__(message)


@dataclass(frozen=True)
class UrdfRobot:
    """What a URDF gives a :class:`~cellsight.model.Robot`: the chain (frame 0 = root link),
    per frame the solids and the URDF link each belongs to, and ``T_last_flange``, the flange
    link's pose in frame n (the gripper mounts on the flange)."""

    chain: SerialChain
    link_solids: tuple[tuple[Polyhedron, ...], ...]
    solid_links: tuple[tuple[str, ...], ...]
    T_last_flange: np.ndarray
    flange: str


def installed_package_folder(name: str) -> Path | None:
    """The share folder of an installed package ``name`` (``<prefix>/share/<name>`` or
    ``<site-packages>/cmeel.prefix/share/<name>``), or None."""
    roots = [Path(sys.prefix) / "share"]
    for sp in [*site.getsitepackages(), *sys.path]:
        roots.append(Path(sp) / "cmeel.prefix" / "share")
    for root in roots:
        if (root / name).is_dir():
            return root / name
    return None


def resolve_uri(uri: str, packages: Mapping[str, Path], folder: Path) -> Path:
    """A URDF file name as a path: ``package://NAME/rest`` (``packages`` first, then an
    installed package), ``file://`` or a path relative to ``folder``; a :class:`UrdfError`
    (field ``file``) for an unknown package."""
    if uri.startswith("package://"):
        name, _, rest = uri[len("package://"):].partition("/")
        root = packages.get(name) or installed_package_folder(name)
        if root is None:
            raise UrdfError("file", f"{uri}: unknown package {name!r} (give it in the cell "
                            f"file's 'packages' map, or install it); known: {sorted(packages)}")
        return Path(root) / rest
    if uri.startswith("file://"):
        return Path(uri[len("file://"):])
    return folder / uri


def _parse(path: Path):
    """The yourdfpy robot model of a URDF file (meshes not loaded)."""
    import yourdfpy

    if not path.is_file():
        raise UrdfError("file", f"URDF file {path} does not exist (or is not a file)")
    try:
        urdf = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False,
                                  build_collision_scene_graph=False, load_collision_meshes=False)
    except Exception as exc:  # yourdfpy and lxml raise anything on bad input
        detail = str(exc).splitlines()[0][:100] if str(exc) else type(exc).__name__
        raise UrdfError("file", f"URDF file {path}: not a readable URDF ({detail})") from exc
    return urdf.robot


def _tree(robot, path: Path) -> tuple[str, dict[str, list]]:
    """The root link and each link's child joints; refuses a URDF that is not one tree."""
    names = [lk.name for lk in robot.links]
    children: dict[str, list] = {n: [] for n in names}
    child_links = set()
    for j in robot.joints:
        if j.parent not in children or j.child not in children:
            raise UrdfError("file", f"URDF file {path}: joint {j.name!r} names a missing link")
        children[j.parent].append(j)
        child_links.add(j.child)
    roots = [n for n in names if n not in child_links]
    if len(roots) != 1 or len(child_links) != len(robot.joints):
        raise UrdfError("file", f"URDF file {path}: links must form one tree (roots: {roots})")
    return roots[0], children


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


def _actuated(walk: _Walk, j, frame: int, T_frame_parent: np.ndarray, path: Path) -> None:
    """Append actuated joint ``j`` (parent link in chain frame ``frame``) to the chain."""
    if j.type not in _KINDS:
        raise UrdfError("file", f"URDF file {path}: joint {j.name!r} of type {j.type!r}; "
                        f"expected revolute, continuous, prismatic or fixed")
    if j.mimic is not None:
        raise UrdfError("file", f"URDF file {path}: joint {j.name!r} mimics another; "
                        f"mimic joints are not supported")
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


def _walk(robot, path: Path) -> _Walk:
    """Depth-first walk from the root: the chain of actuated joints and where each link sits."""
    root, children = _tree(robot, path)
    walk = _Walk([], [], [], [], [root], {})
    stack = [(root, 0, np.eye(4))]
    while stack:
        link, frame, T = stack.pop()
        walk.link_frame[link] = (frame, T)
        for j in reversed(children[link]):
            if j.type == "fixed":
                origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
                stack.append((j.child, frame, T @ origin))
            else:
                _actuated(walk, j, frame, T, path)
                stack.append((j.child, len(walk.origins), np.eye(4)))
    if not walk.origins:
        raise UrdfError("file", f"URDF file {path}: no actuated joint")
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


def _shape(geometry, name: str, packages: Mapping[str, Path], folder: Path) -> Polyhedron:
    """One URDF geometry element as a solid in its own (origin) frame."""
    if geometry.box is not None:
        return box(name, geometry.box.size)
    if geometry.cylinder is not None:
        return cylinder_solid(name, geometry.cylinder.radius, geometry.cylinder.length)
    if geometry.sphere is not None:
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


def _solids(robot, walk: _Walk, geometry: str, robot_name: str, packages: Mapping[str, Path],
            path: Path) -> tuple[list[list[Polyhedron]], list[list[str]]]:
    """Per chain frame, the solids of the links it carries (in that frame) and their links."""
    n = len(walk.origins)
    solids: list[list[Polyhedron]] = [[] for _ in range(n + 1)]
    links: list[list[str]] = [[] for _ in range(n + 1)]
    for link in robot.links:
        frame, T_frame_link = walk.link_frame[link.name]
        elements = link.collisions if geometry == "collision" else link.visuals
        for k, element in enumerate(elements):
            name = f"{robot_name}.{link.name}"
            try:
                shape = _shape(element.geometry, name, packages, path.parent)
            except CellsightError as exc:
                raise UrdfError("geometry", f"URDF file {path}: link {link.name!r}, "
                                f"{geometry} {k}: {exc}") from exc
            origin = np.eye(4) if element.origin is None else np.asarray(element.origin, float)
            solids[frame].append(shape.transformed(T_frame_link @ origin))
            links[frame].append(link.name)
    return solids, links


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


def urdf_files(path: Path, geometry: str = "collision",
               packages: Mapping[str, Path] | None = None) -> list[Path]:
    """The URDF file in ``path`` and the mesh files of its ``geometry`` (``collision`` or
    ``visual``) elements, in link order: what a robot built from it was read from."""
    robot = _parse(path)
    files = [path]
    for link in robot.links:
        for element in (link.collisions if geometry == "collision" else link.visuals):
            mesh = element.geometry.mesh if element.geometry is not None else None
            if mesh is not None:
                files.append(resolve_uri(mesh.filename, dict(packages or {}), path.parent))
    return files


def load_urdf_robot(path: Path, robot_name: str, geometry: str = "collision",
                    flange: str | None = None,
                    packages: Mapping[str, Path] | None = None) -> UrdfRobot:
    """Chain, solids and flange of the URDF robot in ``path`` (see the module docstring);
    ``geometry`` is ``collision`` or ``visual``; a :class:`UrdfError` naming the URDF file."""
    packages = dict(packages or {})
    robot = _parse(path)
    walk = _walk(robot, path)
    solids, links = _solids(robot, walk, geometry, robot_name, packages, path)
    name, T_last_flange = _flange(walk, flange, path)
    try:
        chain = SerialChain(np.array(walk.origins), np.array(walk.axes), walk.kinds, walk.qlim,
                            name=robot_name, link_names=tuple(walk.joint_links))
    except CellsightError as exc:
        raise UrdfError("file", f"URDF file {path}: {exc}") from exc
    return UrdfRobot(chain, tuple(map(tuple, solids)), tuple(map(tuple, links)), T_last_flange,
                     name)
