"""The board on a robot's flange and what the robot can do with it (for :mod:`.plan`): the
board's geometry in the flange frame (:class:`BoardOnFlange`), which cameras see it whole, the
cells the planner checks against, collisions (:class:`Collider`), the poses the arm reaches
(:class:`ReachMap`) and a seed's prior chance (:func:`chance`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from cellsight.camera import Camera, border_distance
from cellsight.errors import CellsightError
from cellsight.geometry.polyhedron import Polyhedron, prism
from cellsight.geometry.transforms import invert_pose, make_pose
from cellsight.model.cell import Cell, Workpiece
from cellsight.model.robot import Robot
from cellsight.world.contacts import mount_pairs
from cellsight.world.mjcf import body_name, cell_mjcf, joint_name
from cellsight.world.scene import Scene

if TYPE_CHECKING:
    import mujoco

BOARD = "calibration_board"
"""The board's name as a workpiece of the planning cells (MuJoCo body, predictor labels)."""
MARGIN_PX = 20.0  # px: every corner at least this far inside the image
MAX_VIEW_DEG = 60.0  # deg: largest angle between the board's normal and the line of sight
MIN_SQUARE_PX = 15.0  # px: smallest image distance between neighbouring corners
REACH_BATCH, REACH_BATCHES = 10000, 4  # random joint vectors per batch of the reach map, most
REACH_M = 0.15  # m: the reach map's neighbourhood of a wrist point
SEED_M, SEED_RAD = 0.1, 0.5  # m, rad: the scales of a seed's distance in :func:`chance`
LIMIT_MARGIN = 0.05  # rad or m: least distance to every joint limit
CLEARANCE_M = 0.01  # m: least distance from the robot and the board to everything else
SELF_CLEARANCE_M = 0.0  # m: ... to the robot's own links (the kinematics are exact; the board
# bolted on a bent wrist may come within a millimetre of the forearm, as R6AX's at HOME)
PLATE_M = 0.005  # m: the plate's thickness behind the outline, for collisions and occlusion
FAR = make_pose(None, (0.0, 0.0, 1e3))  # the board's nominal pose, out of everything's way


def chance(shift_m: float, turn_rad: float) -> float:
    """The prior chance that a board pose passes the checks when its IK seed puts the board
    ``shift_m`` (m) and ``turn_rad`` (rad) away: ``exp(-(shift / SEED_M)^2 / 2 -
    (turn / SEED_RAD)^2 / 2)``."""
    return math.exp(-0.5 * (shift_m / SEED_M) ** 2 - 0.5 * (turn_rad / SEED_RAD) ** 2)


@dataclass(frozen=True)
class BoardOnFlange:
    """The board in the flange frame: ``corners`` (N, 3) m, unit ``normal`` (3,) out of the
    printed face, ``outline`` (k, 3) m of its plate's face. Derived: ``T_flange_board`` (the
    board frame: origin at the corners' centroid, z the normal, x their longest spread),
    ``neighbour`` (N,): each corner's nearest corner, ``radius`` (m): the farthest corner from
    the centroid."""

    corners: np.ndarray
    normal: np.ndarray
    outline: np.ndarray
    T_flange_board: np.ndarray
    neighbour: np.ndarray
    radius: float

    @classmethod
    def from_flange(cls, points_flange: ArrayLike, normal_flange: ArrayLike,
                    outline_flange: ArrayLike) -> BoardOnFlange:
        """The board from its corners, normal and outline in the flange frame (checked)."""
        corners = _points("points_flange", points_flange, 4)
        outline = _points("outline_flange", outline_flange, 3)
        normal = np.asarray(normal_flange, dtype=float).reshape(-1)
        if normal.shape != (3,) or not np.isfinite(normal).all() or not normal.any():
            raise CellsightError(f"calibration board: normal_flange must be a non-zero finite "
                                 f"3-vector, got {normal.tolist()}")
        normal = normal / np.linalg.norm(normal)
        centre = corners.mean(axis=0)
        spread = (corners - centre) - np.outer((corners - centre) @ normal, normal)
        x = np.linalg.svd(spread, full_matrices=False)[2][0]
        R = np.column_stack([x, np.cross(normal, x), normal])
        gaps = np.linalg.norm(corners[:, None] - corners[None], axis=2)
        np.fill_diagonal(gaps, np.inf)
        return cls(corners, normal, outline, make_pose(R, centre), np.argmin(gaps, axis=1),
                   float(np.linalg.norm(corners - centre, axis=1).max()))

    def plate(self, with_corners: bool) -> Polyhedron:
        """The plate (flange frame): the outline extruded ``PLATE_M`` back from the face;
        ``with_corners``: its features are the corners (else every plate vertex)."""
        T = self.T_flange_board
        local = (self.outline - T[:3, 3]) @ T[:3, :3]
        face = float(local[:, 2].mean())
        solid = prism(BOARD, local[:, :2], PLATE_M, face - PLATE_M).transformed(T)
        if not with_corners:
            return solid
        k = len(solid.vertices)
        return Polyhedron(BOARD, np.vstack([solid.vertices, self.corners]), solid.faces,
                          feature_vertices=tuple(range(k, k + len(self.corners))))


def _points(name: str, value: ArrayLike, least: int) -> np.ndarray:
    """``value`` as a finite (N >= least, 3) array, or a :class:`CellsightError`."""
    points = np.asarray(value, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < least or \
            not np.isfinite(points).all():
        raise CellsightError(f"calibration board: {name} must be a finite (N >= {least}, 3) "
                             f"array (m, flange frame), got shape {points.shape}")
    return points


def view_cameras(cameras: list[Camera], board: BoardOnFlange,
                 T_base_flange: np.ndarray) -> list[int]:
    """Indices of the cameras that see the whole board at ``T_base_flange`` by projection
    alone (occlusions aside): every corner in front and ``MARGIN_PX`` inside the image, the
    face within ``MAX_VIEW_DEG`` of the line of sight from the board's centre, neighbouring
    corners at least ``MIN_SQUARE_PX`` apart in the image."""
    R, p = T_base_flange[:3, :3], T_base_flange[:3, 3]
    corners = board.corners @ R.T + p
    centre = T_base_flange @ board.T_flange_board[:, 3]
    normal = R @ board.normal
    cos_max = math.cos(math.radians(MAX_VIEW_DEG))
    out = []
    for k, cam in enumerate(cameras):
        sight = cam.center - centre[:3]
        if normal @ sight < cos_max * np.linalg.norm(sight):
            continue
        if (cam.depth(corners) <= 0).any():
            continue
        px = cam.project(corners)
        if border_distance(cam, px).min() < MARGIN_PX:
            continue
        if np.linalg.norm(px - px[board.neighbour], axis=1).min() >= MIN_SQUARE_PX:
            out.append(k)
    return out


def planning_cells(cell: Cell, robot: Robot, board: BoardOnFlange) -> tuple[Cell, Cell]:
    """The cell for collisions: ``robot`` without its tool, the plate a workpiece (``BOARD``,
    at ``FAR``); and the cell for occlusion: the same with the plate's features at the corners
    and the flange link's solids left out (module docstring)."""
    bare = replace(robot, tool=None)
    links = bare.solid_links
    flangeless = replace(bare, link_solids=bare.link_solids[:-1] + ((),),
                         solid_links=None if links is None else links[:-1] + ((),))

    def cell_with(presenter: Robot, plate: Polyhedron) -> Cell:
        robots = [presenter if r.name == robot.name else r for r in cell.robots]
        return Cell(f"{cell.name} (calibration)", robots,
                    [*cell.workpieces, Workpiece(BOARD, plate, FAR)], cell.static,
                    cell.cameras, cell.source)

    return cell_with(bare, board.plate(False)), cell_with(flangeless, board.plate(True))


class Collider:
    """Whether a robot's pose, with the board on its flange, keeps ``clearance`` (m) from
    everything else and does not overlap its own links where it may not (module docstring),
    by MuJoCo's ``mj_geomDistance`` on the model of ``cell`` (the collision cell of
    :func:`planning_cells`): the other robots at HOME with their jaws open, the workpieces at
    their start poses."""

    def __init__(self, cell: Cell, robot: str, clearance: float = CLEARANCE_M) -> None:
        import mujoco  # after cellsight.world, which chooses MuJoCo's OpenGL back-end

        model = mujoco.MjModel.from_xml_string(cell_mjcf(cell))
        self.scene = Scene(model, mujoco.MjData(model))
        self._qadr = _qpos_addresses(model, cell.robot(robot))
        self._mocap = int(model.body(BOARD).mocapid[0])
        _place_home(self.scene, cell)
        self.pairs, own = self._pairs(cell, robot)
        self._limit = np.where(own, SELF_CLEARANCE_M, clearance)  # per pair, m
        self._plane = (model.geom_rbound[self.pairs] == 0).any(axis=1)  # a plane: unbounded

    def _pairs(self, cell: Cell, robot: str) -> tuple[np.ndarray, np.ndarray]:
        """(K, 2) geom pairs to check: each of the robot's moving geoms and the plate with every
        other geom, less a body and its parent, the plate and the flange link, and the mounts
        (:func:`~cellsight.world.contacts.mount_pairs`: the robots at HOME, the board far);
        and (K,) whether both are the robot's or the plate's."""
        model = self.scene.model
        n = cell.robot(robot).n_joints
        body, parent = model.geom_bodyid, model.body_parentid
        board, flange = model.body(BOARD).id, model.body(body_name(robot, n)).id
        own = {model.body(body_name(robot, i)).id for i in range(n + 1)}
        moving = [g for g in range(model.ngeom) if body[g] == board or (
            body[g] in own and model.body_weldid[body[g]] != 0)]
        skip = mount_pairs(self.scene, cell)
        pairs = set()
        for g in moving:
            for h in range(model.ngeom):
                a, b = int(body[g]), int(body[h])
                pair = (min(g, h), max(g, h))
                if a == b or parent[a] == b or parent[b] == a or {a, b} == {board, flange} \
                        or pair in skip:
                    continue
                pairs.add(pair)
        pairs = np.array(sorted(pairs), dtype=int).reshape(-1, 2)
        return pairs, np.isin(body[pairs], [*own, board]).all(axis=1)

    def hit(self, q: np.ndarray, T_base_flange: np.ndarray) -> tuple[str, str] | None:
        """The names of the first two solids nearer than their clearance with the robot at
        ``q`` and the board's flange frame at ``T_base_flange``; None when all are clear."""
        import mujoco  # after cellsight.world, which chooses MuJoCo's OpenGL back-end

        scene = self.scene
        scene.set_qpos(self._qadr, q)
        scene.set_mocap(self._mocap, T_base_flange)
        scene.sync()
        model, data = scene.model, scene.data
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        gap = (np.linalg.norm(data.geom_xpos[a] - data.geom_xpos[b], axis=1)
               - model.geom_rbound[a] - model.geom_rbound[b])
        near = np.flatnonzero((gap < self._limit) | self._plane)
        for (g, h), limit in zip(self.pairs[near], self._limit[near], strict=True):
            if mujoco.mj_geomDistance(model, data, int(g), int(h), limit, None) < limit:
                return model.geom(int(g)).name, model.geom(int(h)).name
        return None


def _qpos_addresses(model: mujoco.MjModel, robot: Robot) -> np.ndarray:
    """The ``qpos`` addresses of the robot's joints 1..n."""
    return model.jnt_qposadr[[model.joint(joint_name(robot.name, i)).id
                              for i in range(1, robot.n_joints + 1)]]


def _place_home(scene: Scene, cell: Cell) -> None:
    """Every robot at HOME, every gripper open (the world's defaults)."""
    model = scene.model
    for robot in cell.robots:
        scene.set_qpos(_qpos_addresses(model, robot), robot.home)
        if robot.tool is not None:
            adr = [model.jnt_qposadr[model.joint(body_name(robot.name, jaw)).id]
                   for jaw in ("jaw1", "jaw2")]
            scene.set_qpos(adr, robot.tool.jaw_values(robot.tool.max_opening))
    scene.sync()


class ReachMap:
    """Random joint vectors of ``robot``, uniform inside its limits less ``LIMIT_MARGIN``, and
    where they put the board (forward kinematics only, ``T_base_board``): IK seeds, and board
    poses the robot reaches (:meth:`grow` adds a batch). A pose's seed is, of the samples
    whose wrist point is within ``REACH_M`` of the pose's (the nearest when none is), the one
    whose board normal is nearest. The wrist point is fixed to the flange where frame n-1's
    origin is at HOME: on a spherical wrist, the centre its three axes meet at, which the arm
    alone places, so that the samples near it are the arm's ways of getting there."""

    def __init__(self, robot: Robot, board: BoardOnFlange, rng: np.random.Generator) -> None:
        self.robot, self.rng = robot, rng
        frames = robot.chain.fkine(robot.home)
        self.T_board_flange = invert_pose(board.T_flange_board)
        self.wrist = self.T_board_flange @ invert_pose(frames[-1]) @ frames[-2][:, 3]
        self.q = np.zeros((0, robot.n_joints))
        self.boards = np.zeros((0, 4, 4))
        self._tree = cKDTree(np.zeros((0, 3)))

    def grow(self, count: int = REACH_BATCH) -> range:
        """Add ``count`` samples; the indices of the new ones."""
        qlim = self.robot.chain.qlim
        q = self.rng.uniform(qlim[:, 0] + LIMIT_MARGIN, qlim[:, 1] - LIMIT_MARGIN,
                             (count, self.robot.n_joints))
        flanges = np.array([self.robot.link_poses(x)[-1] for x in q])
        start = len(self.q)
        self.q = np.vstack([self.q, q])
        self.boards = np.concatenate([self.boards, flanges @ invert_pose(self.T_board_flange)])
        self._tree = cKDTree((self.boards @ self.wrist)[:, :3])
        return range(start, len(self.q))

    def seed(self, T_base_board: np.ndarray) -> tuple[np.ndarray, float]:
        """The seed for a board pose (class docstring) and its :func:`_chance`."""
        wrist = (T_base_board @ self.wrist)[:3]
        near = np.asarray(self._tree.query_ball_point(wrist, REACH_M), dtype=int)
        if not near.size:
            near = np.atleast_1d(self._tree.query(wrist)[1])
        cosines = self.boards[near, :3, 2] @ T_base_board[:3, 2]
        k = near[np.argmax(cosines)]
        shift = float(np.linalg.norm((self.boards[k] @ self.wrist)[:3] - wrist))
        return self.q[k], chance(shift, math.acos(float(np.clip(cosines.max(), -1, 1))))

    def in_view(self, cam: Camera, board: BoardOnFlange, span: tuple[float, float],
                samples: range) -> np.ndarray:
        """Indices of ``samples`` whose board centre is in ``cam``'s image with room for the
        board and the margin, at a distance in ``span`` (m)."""
        centres = self.boards[samples.start:samples.stop, :3, 3]
        depth = cam.depth(centres)
        room = MARGIN_PX + board.radius * cam.focal_px / np.maximum(depth, 1e-9)
        inside = border_distance(cam, cam.project(centres)) >= room
        return np.flatnonzero(inside & (depth >= span[0]) & (depth <= span[1])) + samples.start
