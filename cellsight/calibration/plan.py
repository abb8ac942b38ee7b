"""The robot poses of a cell calibration (``cellsight calibrate``): where a robot holds the
ChArUco board bolted to its flange, in place of its gripper, for the cell's fixed cameras to
photograph it.

Frames and units: the board is given in the robot's flange frame (frame n of its chain,
``robot.chain.fkine(q)[-1]``): its corners (m), the normal out of its printed face and its
plate's outline (m). Poses ``T_base_*`` are in the cell's base frame; joints in the robot's
encoder terms (rad, m for a prismatic joint); pixels as OpenCV's (distortion included).

**Candidates**, board poses, from two sources:

- designed, per camera: a Latin hypercube over the board centre's pixel, its distance from
  the camera (:func:`depth_span`: ``DEPTH_SPAN`` times the work area's, the work area being
  around the workpieces' start poses), the axis of the board's tilt away from facing the
  camera (any direction in the board's plane) and its angle (``TILT_DEG``), and a turn about
  its normal by any angle (:func:`designed_boards`);
- reached (:class:`ReachMap`): random joint vectors, by forward kinematics alone, whose board
  centre is in a camera's view, each clear of collisions, its board turned by the least
  rotation onto the designed family for that camera (:func:`snapped_board`): the tilt it
  has, clipped to ``TILT_DEG``, about the axis it has. A robot that can present the board to
  a camera only in a few contorted ways (R6AX, behind whose base the built-in cell's cameras
  stand) is found there, where designed poses would almost all fail.

Tilts about axes in every direction and turns about the normal make the relative rotations
between poses turn about axes in every direction (hand-eye is observable). Each candidate is
first checked for every camera by projection alone (:func:`view_cameras`): every corner in
front of the camera and at least ``MARGIN_PX`` inside its image
(:func:`cellsight.camera.border_distance`), the face turned toward the camera (within
``MAX_VIEW_DEG`` of the line of sight) and neighbouring corners at least ``MIN_SQUARE_PX``
apart. The IK is the cost, so the candidate tried next is the one worth most
(:meth:`_Planner.search`): the square of the number of cameras that see it still short of
poses (a pose two cameras see ties them together), times its prior chance (:func:`_chance`:
how far its IK seed leaves the board from it), over one plus its likeness to the candidates
tried so far (the search leaves regions where tries failed, and spreads the poses). The reach
map grows, by batches, while no candidate is worth ``WORTH_MIN``.

**Checks** of a candidate, cheapest first, until every camera has ``per_camera`` poses:

- reachable: the cell's own IK (:func:`cellsight.control.ik.solve_ik`) on the robot without
  its tool, whose TCP is then its flange, from the candidate's seed, mid-range and the start
  (HOME unless given); a solution at least ``LIMIT_MARGIN`` (rad or m) inside every joint
  limit; of several, the one nearest the start first;
- free of collisions (:class:`Collider`): MuJoCo's distances (``mj_geomDistance``, pair by
  pair: MuJoCo's own collision pass skips a workpiece, a mocap body, against static objects)
  on the cell's own MuJoCo model (:func:`cellsight.world.mjcf.cell_mjcf`) with the board's
  plate as a workpiece: at least ``CLEARANCE_M`` between the robot's links and the plate and
  the static objects, the workpieces at their start, the other robots at HOME; no overlap
  with the robot's own links (``SELF_CLEARANCE_M``), but for a link and its neighbour, the
  pairs that touch at HOME (mounts, as for the world's contact monitor:
  :func:`cellsight.world.contacts.mount_pairs`) and the plate and the flange link it is
  bolted on;
- seen: the occlusion predictor (:class:`cellsight.occlusion.predictor.VisibilityPredictor`)
  with the board as a workpiece whose features are its corners: no corner hidden from a
  camera by the robot's links, the board itself, the other robots or the cell's objects. The
  flange link is left out of the occluders: it is behind the board (the board is bolted on
  the flange, where the gripper was; a flange link's solid may reach a few centimetres past
  the flange, into where the gripper was, cf. :data:`cellsight.experiments.cellcheck.MOUNT_M`,
  as the built-in cell's does), so it cannot hide the face from a camera the face is turned
  toward;
- moved to: the route leaves from the start; a new pose goes where it lengthens it least
  (joint space, Euclidean, rad and m alike: cheapest insertion), among the ``INSERT_PLACES``
  best places where the straight joint-space moves to it and from it, sampled every
  ``MOVE_STEP`` (rad or m, in every joint), are free of collisions (the same check).

**Refusal.** A camera that cannot see the board around the work area, a start where the board
is not clear, and (:mod:`.cell_plan`) a camera with fewer than ``min_poses`` poses at the end,
are a :class:`~cellsight.errors.CellsightError` naming the robot, the camera or the solids, why
poses were dropped and what to do.
"""

from __future__ import annotations

import copy
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from cellsight.calibration.presenting import (
    BOARD,
    CLEARANCE_M,
    LIMIT_MARGIN,
    MARGIN_PX,
    REACH_BATCHES,
    BoardOnFlange,
    Collider,
    ReachMap,
    chance,
    planning_cells,
    view_cameras,
)
from cellsight.camera import Camera
from cellsight.control.ik import IKError, solve_ik
from cellsight.errors import CellsightError
from cellsight.geometry.transforms import make_pose
from cellsight.model.cell import Cell
from cellsight.model.robot import Robot
from cellsight.occlusion.backends import visibility_predictor

MIN_POSES = 6  # poses per camera below which the plan is refused
FIRST_ROUND = 8
"""The search gives every camera this many poses before it seeks more for any: sought for all
at once, a camera that is easy to reach drew the tries, the route grew, and a hard one's poses
no longer fitted into it (``lab`` seed 6: R6AX gave cam2 5 of 16, against 8 of 8)."""
TILT_DEG = (15.0, 40.0)  # deg: the board's tilt away from facing the camera
DEPTH_SPAN = (0.4, 1.15)  # board distance from a camera, as a fraction of the work area's
MIN_DEPTH_M = 0.3  # m: the board never nearer a camera
DESIGNED = 40  # designed candidates per camera
MAX_TRIES = 60  # candidates tried per camera at most (R6AX, the hardest, needs about 30)
WORTH_MIN = 0.3  # a candidate's worth below which a new batch of the reach map comes first
LIKE_M, LIKE_NORMAL = 0.1, 0.4  # m, unit-normal difference: the scales of :func:`_likeness`
MOVE_STEP = 0.02  # rad or m: largest joint change between samples of a move
INSERT_PLACES = 4  # places in the route tried for a new pose, those that lengthen it least
_LAST_CHECKS = ("collision", "occluded", "move")  # after IK, in order
SAME_POSE = 1e-3  # rad (m): joints no further apart than this in every joint are one pose


@dataclass(frozen=True)
class Plan:
    """The poses of one robot's calibration, in the order to visit them from the start.

    ``joints`` (P, n): the joint vectors (encoder terms, rad or m); ``T_base_flange``
    (P, 4, 4): the flange pose each gives by the cell's kinematics (base frame, m);
    ``cameras``: per pose, the names of the cameras that see the whole board; ``dropped``:
    how many candidate poses each check dropped (module docstring: ``out of view``,
    ``unreachable``, ``joint limits``, ``collision`` (with the reach map's samples in view that
    are not clear), ``occluded``, ``move``).
    """

    robot: str
    joints: np.ndarray
    T_base_flange: np.ndarray
    cameras: tuple[tuple[str, ...], ...]
    dropped: dict[str, int]

    def per_camera(self) -> dict[str, int]:
        """Camera name -> the number of poses it sees (cameras that see none left out)."""
        return dict(Counter(name for names in self.cameras for name in names))


def work_centre(cell: Cell) -> np.ndarray:
    """The work area's centre (base frame, m): the mean of the workpieces' start positions;
    a :class:`CellsightError` for a cell without workpieces."""
    if not cell.workpieces:
        raise CellsightError(f"cell {cell.name}: no workpiece to centre the calibration poses "
                             f"on; add the workpiece the cameras watch to the cell file")
    return np.mean([p.T_base_part[:3, 3] for p in cell.workpieces], axis=0)


def depth_span(cam: Camera, board: BoardOnFlange, centre: np.ndarray) -> tuple[float, float]:
    """The board centre's distances from ``cam`` (m, along its axis) for the candidates:
    ``DEPTH_SPAN`` times the work area ``centre``'s (base frame, m), no nearer than
    ``MIN_DEPTH_M`` nor than where the board, facing the camera, fits in its image with the
    margin; ``near > far`` when none."""
    depth = float(cam.depth(centre[None])[0])
    room = 0.5 * min(cam.width, cam.height) - MARGIN_PX  # px from the image's centre
    if room <= 0:
        return math.inf, 0.0
    fits = board.radius * cam.focal_px / room
    return max(DEPTH_SPAN[0] * depth, fits, MIN_DEPTH_M), DEPTH_SPAN[1] * depth


def _latin(rng: np.random.Generator, count: int, dims: int) -> np.ndarray:
    """(count, dims) in [0, 1): a Latin hypercube (each column one point in each of ``count``
    equal strata, the strata shuffled per column)."""
    strata = np.column_stack([rng.permutation(count) for _ in range(dims)])
    return (strata + rng.random((count, dims))) / count


def designed_boards(cam: Camera, board: BoardOnFlange, span: tuple[float, float],
                    rng: np.random.Generator, count: int = DESIGNED) -> list[np.ndarray]:
    """``count`` board poses ``T_base_board`` for ``cam`` (module docstring: a Latin
    hypercube over the pixel, the distance in ``span`` (m), the tilt's axis and angle)."""
    near, far = span
    u = _latin(rng, count, 5)
    d = near + u[:, 0] * (far - near)
    size = np.array([cam.width, cam.height], dtype=float)
    half = (MARGIN_PX + board.radius * cam.focal_px / d)[:, None]
    pixels = half + u[:, 1:3] * (size - 2 * half)
    rays = np.column_stack([pixels, np.ones(count)]) @ np.linalg.inv(cam.K).T
    points = (rays * d[:, None]) @ cam.T_base_cam[:3, :3].T + cam.center
    tilts = np.radians(TILT_DEG[0] + u[:, 4] * (TILT_DEG[1] - TILT_DEG[0]))
    out = []
    for p, a, tilt, turn in zip(points, u[:, 3], tilts, rng.uniform(-math.pi, math.pi, count),
                                strict=True):
        z = cam.center - p
        z /= np.linalg.norm(z)
        x = cam.T_base_cam[:3, 0] - (cam.T_base_cam[:3, 0] @ z) * z
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        axis = math.cos(2 * math.pi * a) * x + math.sin(2 * math.pi * a) * y
        R = (Rotation.from_rotvec(tilt * axis) * Rotation.from_matrix(np.column_stack([x, y, z]))
             * Rotation.from_euler("z", turn)).as_matrix()
        out.append(make_pose(R, p))
    return out


def snapped_board(cam: Camera, T_base_board: np.ndarray) -> tuple[np.ndarray, float]:
    """The board pose of the design family for ``cam`` nearest ``T_base_board`` (same centre;
    its normal tilted from facing the camera by the given pose's tilt clipped to
    ``TILT_DEG``, about the same axis; turned by the least rotation), and the angle (rad)
    between the two."""
    centre, normal = T_base_board[:3, 3], T_base_board[:3, 2]
    facing = cam.center - centre
    facing /= np.linalg.norm(facing)
    axis = np.cross(facing, normal)
    if np.linalg.norm(axis) < 1e-9:  # facing the camera (or away from it): any tilt axis
        axis = T_base_board[:3, 0]
    axis /= np.linalg.norm(axis)
    tilt = math.acos(float(np.clip(facing @ normal, -1.0, 1.0)))
    goal = Rotation.from_rotvec(np.clip(tilt, *np.radians(TILT_DEG)) * axis).apply(facing)
    turn = np.cross(normal, goal)
    sine = float(np.linalg.norm(turn))
    angle = math.atan2(sine, float(normal @ goal))
    if sine > 1e-12:  # else no turn, or a half turn about no axis in particular: left as is
        turn *= angle / sine
    R = Rotation.from_rotvec(turn if sine > 1e-12 else np.zeros(3)).as_matrix()
    return make_pose(R @ T_base_board[:3, :3], centre), angle


@dataclass(frozen=True)
class _Candidate:
    """A candidate pose: the flange's ``T_base_flange``, the IK ``seed``, the ``prior``
    chance of passing, the cameras that see the board by projection, and its ``key`` for
    :func:`_likeness` (board centre over ``LIKE_M``, normal over ``LIKE_NORMAL``)."""

    T_base_flange: np.ndarray
    seed: np.ndarray
    prior: float
    cameras: tuple[int, ...]
    key: np.ndarray


def _likeness(keys: np.ndarray, tried: np.ndarray) -> np.ndarray:
    """(P,): for candidates' keys (P, 6), the sum over tried ones' (T, 6) of how alike they
    are, ``exp(-|dkey|^2 / 2)`` (1 for itself)."""
    if not len(tried):
        return np.zeros(len(keys))
    gaps = ((keys[:, None, :] - tried[None, :, :]) ** 2).sum(axis=2)
    return np.exp(-0.5 * gaps).sum(axis=1)


@dataclass(frozen=True)
class _Pose:
    """An accepted pose: joints, flange pose, indices of the cameras that see the board."""

    q: np.ndarray
    T_base_flange: np.ndarray
    cameras: tuple[int, ...]


class _Planner:
    """The checks of the module docstring for one robot presenting one board."""

    def __init__(self, cell: Cell, robot: Robot, board: BoardOnFlange, rng: np.random.Generator,
                 spans: list[tuple[float, float]], start: np.ndarray) -> None:
        """``spans``: each camera's :func:`depth_span`; ``start``: the joints the route
        starts from."""
        self.cell, self.board, self.rng, self.spans = cell, board, rng, spans
        self.start = start
        self.robot = replace(robot, tool=None)  # its TCP is its flange
        collision_cell, view_cell = planning_cells(cell, robot, board)
        self.collider = Collider(collision_cell, robot.name)
        self.predictor = visibility_predictor(view_cell, near_px=0.0)
        self.reach = ReachMap(self.robot, board, rng)

    def candidates(self, samples: range, designed: bool) -> tuple[list[_Candidate], Counter]:
        """The candidates from the reach map's ``samples`` that keep clear of everything
        (:func:`snapped_board`) and, when ``designed``, :func:`designed_boards`' for every
        camera, each with the cameras that see it by projection (:func:`view_cameras`); and
        those dropped (a sample not clear: ``collision``; seen by none: ``out of view``)."""
        boards: list[tuple[np.ndarray, np.ndarray, float]] = []
        dropped: Counter = Counter()
        for cam, span in zip(self.cell.cameras, self.spans, strict=True):
            if designed:
                boards += [(T, *self.reach.seed(T))
                           for T in designed_boards(cam, self.board, span, self.rng)]
            for k in self.reach.in_view(cam, self.board, span, samples):
                q, T_base_board = self.reach.q[k], self.reach.boards[k]
                if self.collider.hit(q, T_base_board @ self.reach.T_board_flange) is not None:
                    dropped["collision"] += 1
                    continue
                T, turn = snapped_board(cam, T_base_board)
                boards.append((T, q, chance(0.0, turn)))
        out = []
        for T_base_board, seed, prior in boards:
            T = T_base_board @ self.reach.T_board_flange
            cameras = tuple(view_cameras(self.cell.cameras, self.board, T))
            if cameras:
                key = np.hstack([T_base_board[:3, 3] / LIKE_M, T_base_board[:3, 2] / LIKE_NORMAL])
                out.append(_Candidate(T, seed, prior, cameras, key))
        dropped["out of view"] += len(boards) - len(out)
        return out, dropped

    def search(self, per_camera: int) -> tuple[list[_Pose], Counter]:
        """The route of poses from the start until every camera has ``per_camera`` (or the
        candidates run out, ``REACH_BATCHES`` batches of the reach map spent, or ``MAX_TRIES``
        per camera are tried), and the candidates dropped, by reason. In two rounds: every
        camera to ``FIRST_ROUND`` poses, then to ``per_camera``. The next candidate
        tried is the one worth most: the square of the number of its cameras still short of
        poses (a pose two cameras see ties them together), times its prior chance, over one
        plus its likeness to those tried so far (:func:`_likeness`: the search leaves a
        region where tries failed, and spreads the poses it keeps); while none is worth
        ``WORTH_MIN``, the reach map first grows a batch."""
        candidates, dropped = self.candidates(self.reach.grow(), designed=True)
        batches, route, tried = 1, [], []
        count = np.zeros(len(self.cell.cameras), dtype=int)
        goals = iter(sorted({min(per_camera, FIRST_ROUND), per_camera}))
        goal = next(goals)
        while not (count >= per_camera).all():
            if (count >= goal).all():
                goal = next(goals)
            short = np.array([sum(count[k] < goal for k in c.cameras)
                              for c in candidates])
            keys = np.array([c.key for c in candidates]).reshape(-1, 6)
            prior = np.array([c.prior for c in candidates])
            worth = short ** 2 * prior / (1 + _likeness(keys, np.array(tried).reshape(-1, 6)))
            if worth.max(initial=0.0) < WORTH_MIN and batches < REACH_BATCHES:
                batches += 1
                more, dropped_more = self.candidates(self.reach.grow(), designed=False)
                candidates += more
                dropped += dropped_more
                continue
            if len(tried) >= MAX_TRIES * len(self.cell.cameras):
                break
            if not worth.any():  # no candidate left for a camera short of this round's goal
                goal = next(goals, None)
                if goal is None:
                    break
                continue
            best = candidates.pop(int(np.argmax(worth)))
            tried.append(best.key)
            reason = self.try_pose(best, route)
            if reason is not None:
                dropped[reason] += 1
            count = np.bincount([k for p in route for k in p.cameras],
                                minlength=len(self.cell.cameras))
        return route, +dropped

    def try_pose(self, candidate: _Candidate, route: list[_Pose]) -> str | None:
        """Insert into ``route`` the candidate's pose, with those of its cameras that see the
        whole board, from the first IK solution (nearest the start first) that passes every check
        (:meth:`insert` for the moves); None when one did, else the last check that any
        solution failed (module docstring)."""
        T = candidate.T_base_flange
        qs = self.solve(T, candidate.seed)
        if isinstance(qs, str):
            return qs
        qs = [q for q in qs if all(np.abs(q - p.q).max() > SAME_POSE for p in route)]
        if not qs:  # another candidate's IK came to the same joints
            return "already planned"
        failed = 0  # index into _LAST_CHECKS
        for q in qs:
            if self.collider.hit(q, T) is not None:
                continue
            views = self.predictor.predict({self.robot.name: q}, {BOARD: T})[BOARD]
            seen = tuple(k for k in candidate.cameras if views[k].visible.all())
            if seen and self.insert(route, _Pose(q, T, seen)):
                return None
            failed = max(failed, 2 if seen else 1)
        return _LAST_CHECKS[failed]

    def solve(self, T_base_flange: np.ndarray, seed: np.ndarray) -> list[np.ndarray] | str:
        """The IK solutions for the flange at ``T_base_flange`` at least ``LIMIT_MARGIN``
        inside every limit, nearest the start first (:func:`~cellsight.control.ik.solve_ik`
        from ``seed``, mid-range and the start: the robot's HOME and FINAL are its first
        seeds); else why none."""
        seeded = replace(self.robot, home=seed, final=self.start)
        try:
            solutions = solve_ik(seeded, T_base_flange, seeds=0).solutions
        except IKError:
            return "unreachable"
        qs = sorted((s.q for s in solutions if s.limit_margin.min() >= LIMIT_MARGIN),
                    key=lambda q: float(np.linalg.norm(q - self.start)))
        return qs or "joint limits"

    def insert(self, route: list[_Pose], pose: _Pose) -> bool:
        """Put ``pose`` into ``route`` (which leaves from the start) at the first, of the
        ``INSERT_PLACES`` places that lengthen it least (joint space, Euclidean), whose moves
        to it and from it are free (:meth:`move_is_free`); whether it was put."""
        stops = [self.start] + [p.q for p in route]

        def added(i: int) -> float:
            to = float(np.linalg.norm(pose.q - stops[i]))
            if i + 1 == len(stops):
                return to
            return to + float(np.linalg.norm(stops[i + 1] - pose.q)
                              - np.linalg.norm(stops[i + 1] - stops[i]))

        for i in sorted(range(len(stops)), key=added)[:INSERT_PLACES]:
            if self.move_is_free(stops[i], pose.q) and (
                    i + 1 == len(stops) or self.move_is_free(pose.q, stops[i + 1])):
                route.insert(i, pose)
                return True
        return False

    def move_is_free(self, q0: np.ndarray, q1: np.ndarray) -> bool:
        """Whether the straight joint-space move from ``q0`` to ``q1``, sampled every
        ``MOVE_STEP`` in every joint, keeps the clearance everywhere (its end included); the
        samples coarse to fine (every 8th, the 4th between them, every other 2nd, the rest),
        so that a collision is found early."""
        steps = max(1, math.ceil(float(np.abs(q1 - q0).max()) / MOVE_STEP))
        s = np.linspace(0.0, 1.0, steps + 1)[1:]
        for fraction in np.concatenate([s[::8], s[4::8], s[2::4], s[1::2]]):
            q = q0 + fraction * (q1 - q0)
            if self.collider.hit(q, self.robot.link_poses(q)[-1]) is not None:
                return False
        return True


def plan_reach(cell: Cell, robot: str, board: BoardOnFlange, *, per_camera: int,
               seed: int = 0, cameras: Sequence[str] | None = None,
               start: ArrayLike | None = None) -> Plan:
    """The poses in which ``robot`` presents the ``board`` (its corners, face normal and
    plate outline in its flange frame: :meth:`BoardOnFlange.from_flange`) to the cell's
    cameras (or to those named in ``cameras``), until each has ``per_camera`` or the search
    gives up, in visiting order from ``start`` (joints, rad or m; default HOME), where the
    board is mounted (module docstring); ``seed`` draws the candidates. A
    :class:`CellsightError` when the board is not clear at the start; a camera with few poses
    is for the caller to judge (:mod:`.cell_plan`)."""
    try:
        presenter = cell.robot(robot)
    except KeyError as error:
        raise CellsightError(str(error.args[0])) from None
    cell = with_cameras(cell, cameras)
    if not cell.cameras or per_camera < 1:
        raise CellsightError(f"calibration plan for robot {robot}: needs a camera and "
                             f"per_camera >= 1, got {len(cell.cameras)} camera(s), "
                             f"per_camera={per_camera}")
    start = presenter.chain.check_q(presenter.home if start is None else start,
                                    check_limits=True)
    spans = _spans_or_refuse(cell, robot, board)
    planner = _Planner(cell, presenter, board, np.random.default_rng(seed), spans, start)
    clash = planner.collider.hit(start, presenter.link_poses(start)[-1])
    if clash is not None:
        raise CellsightError(
            f"calibration plan for robot {robot}: at the start {np.round(start, 3).tolist()} "
            f"with the board on its flange, {clash[0]} and {clash[1]} are too near (they "
            f"overlap, or are within {CLEARANCE_M * 1e3:g} mm); start from joints where the "
            f"board is clear (start=...)")
    poses, dropped = planner.search(per_camera)
    names = [cam.name for cam in cell.cameras]
    return Plan(robot, np.array([p.q for p in poses]).reshape(-1, presenter.n_joints),
                np.array([presenter.link_poses(p.q)[-1] for p in poses]).reshape(-1, 4, 4),
                tuple(tuple(names[k] for k in p.cameras) for p in poses), dict(dropped))


def with_cameras(cell: Cell, cameras: Sequence[str] | None) -> Cell:
    """``cell`` with only the cameras named (all of them for None); an unknown name is a
    :class:`CellsightError`."""
    if cameras is None:
        return cell
    try:
        chosen = [cell.camera(name) for name in dict.fromkeys(cameras)]
    except KeyError as error:
        raise CellsightError(str(error.args[0])) from None
    cell = copy.copy(cell)
    cell.cameras = chosen
    return cell


def _spans_or_refuse(cell: Cell, robot: str, board: BoardOnFlange) -> list[tuple[float, float]]:
    """Each camera's :func:`depth_span`, or a :class:`CellsightError` naming the cameras that
    cannot see the board around the work area."""
    centre = work_centre(cell)
    spans = [depth_span(cam, board, centre) for cam in cell.cameras]
    blind = [cam.name for cam, (near, far) in zip(cell.cameras, spans, strict=True)
             if near > far]
    if blind:
        raise CellsightError(
            f"calibration plan for robot {robot}: camera {' and '.join(blind)} cannot see the "
            f"board around the work area at {np.round(centre, 2).tolist()} m (behind it, or "
            f"too near for the whole board to fit in its image); aim it at the work area, or "
            f"leave it out (cameras=...) and calibrate it with another robot")
    return spans
