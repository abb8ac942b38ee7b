"""Visual-servoing control: CLIK, interpolating filter, trajectory planner and the grasp task.

The closed-loop tests use ideal part-pose measurements (the true pose plus small seeded noise,
no vision) and run the task against ``_KinematicCell``, a TEST-ONLY stand-in for the world
written here: set-points are followed exactly, the part moves at a known velocity until it is
grasped, and a grasp engages when the jaws reach the part's width while the TCP is within 1 cm
and 10 degrees of the part's grasp pose (either of its two symmetric grasps). When
``cellsight.world`` imports, the same scenarios also run against the MuJoCo world.

Smoothness bounds (stated here, used below): joint set-point velocities within the CLIK's joint
speed limits (0.5 m/s track, 2 rad/s revolute joints) and accelerations within those limits
reached in no less than 0.25 s: 2 m/s^2 for the track, 8 rad/s^2 for revolute joints.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from cellsight import load_cell
from cellsight.control import (
    Clik,
    GraspTask,
    InterpolatingFilter,
    PartGoal,
    PartMotion,
    Phase,
    PoseGoal,
    TaskTiming,
    TrajectoryPlanner,
    default_joint_velocity_limits,
    min_jerk,
)
from cellsight.control.clik import rotation_error
from cellsight.control.task import TaskMoves, grasp_miss
from cellsight.geometry.transforms import make_pose
from cellsight.model.grasp import grasp_pose

CELL = load_cell()
ROBOT = CELL.robot("R7AX")
PART = CELL.workpieces[0]
# A start pose of the planner tests, independent of the cell's HOME: the gripper pointing
# down 40 cm above the table's edge, 0.6 m from the goal of the segment test.
Q_START = np.array([0.3, 0.0, -0.531, 0.91, 0.0, 1.193, 0.0])
DT = 1 / 500
VISION_DT = 1 / 26
HALF_TURN_Z = make_pose(np.diag([-1.0, -1.0, 1.0]))
V_MAX = default_joint_velocity_limits(ROBOT)  # 0.5 m/s track, 2 rad/s revolute
A_MAX = V_MAX / 0.25  # full speed in no less than a quarter second
FAST = TaskTiming().scaled(0.4)  # short runs
PHASE_ORDER = [Phase.WAITING, Phase.APPROACH, Phase.GRASP, Phase.MANIPULATE, Phase.RELEASE,
               Phase.DONE]


def _angle(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(np.linalg.norm(rotation_error(R_a, R_b)))


def _grasp_error(T_tcp: np.ndarray, T_part: np.ndarray) -> tuple[float, float]:
    """Position (m) and angle (rad) error of the TCP from the nearer of the two grasps."""
    G = T_part @ grasp_pose(PART)
    return (float(np.linalg.norm(T_tcp[:3, 3] - G[:3, 3])),
            min(_angle(G[:3, :3], T_tcp[:3, :3]), _angle((G @ HALF_TURN_Z)[:3, :3], T_tcp[:3, :3])))


# ---- test-only stand-in for the world ----------------------------------------------------------

class _KinematicCell:
    """TEST-ONLY kinematic stand-in: see the module docstring. ``refuse_grasps``: the first so
    many closings do not engage (a failed grasp, to exercise the retry)."""

    PART_WIDTH = 0.06
    JAW_SPEED = 0.2  # m/s

    def __init__(self, velocity=(0.0, 0.0, 0.0), refuse_grasps: int = 0, seed: int = 0) -> None:
        self.q = ROBOT.home.copy()
        self.T_part = PART.T_base_part.copy()
        self.velocity = np.asarray(velocity, dtype=float)
        self.opening = ROBOT.tool.max_opening
        self.T_tcp_part: np.ndarray | None = None
        self.on_conveyor = True
        self.refuse_grasps = refuse_grasps
        self.rng = np.random.default_rng(seed)

    def step(self, q: np.ndarray, opening: float) -> None:
        self.q = np.asarray(q, dtype=float).copy()
        before = self.opening
        self.opening += float(np.clip(opening - self.opening, -self.JAW_SPEED * DT,
                                      self.JAW_SPEED * DT))
        T_tcp = ROBOT.tcp_pose(self.q)
        if self.T_tcp_part is not None and self.opening > self.PART_WIDTH:
            self.T_tcp_part = None  # released: the part stays where it is
        if self.T_tcp_part is not None:
            self.T_part = T_tcp @ self.T_tcp_part
            return
        if self.on_conveyor:
            self.T_part[:3, 3] += self.velocity * DT
        if before > self.PART_WIDTH >= self.opening:
            dp, da = _grasp_error(T_tcp, self.T_part)
            if self.refuse_grasps:
                self.refuse_grasps -= 1
            elif dp < 0.01 and da < np.radians(10.0):
                self.T_tcp_part = np.linalg.solve(T_tcp, self.T_part)
                self.on_conveyor = False

    def jaws_closed(self) -> bool:
        return self.T_tcp_part is not None

    def measured_part_pose(self) -> np.ndarray:
        """True pose + 0.5 mm and 0.2 degree noise."""
        T = self.T_part.copy()
        T[:3, 3] += self.rng.normal(0.0, 5e-4, 3)
        turn = Rotation.from_rotvec(self.rng.normal(0.0, np.radians(0.2), 3)).as_matrix()
        T[:3, :3] = turn @ T[:3, :3]
        return T


@dataclass
class _Record:
    t: list = field(default_factory=list)
    q: list = field(default_factory=list)
    opening: list = field(default_factory=list)
    part: list = field(default_factory=list)
    phase: list = field(default_factory=list)
    vision_t: list = field(default_factory=list)

    def arrays(self):
        return np.array(self.t), np.array(self.q), np.array(self.part)


def _run(task: GraspTask, sim: _KinematicCell, t_end: float, localised_after: float = 0.0,
         stop_when_done: bool = True) -> _Record:
    """Vision at 26 Hz, control at 500 Hz, until ``t_end`` or one second after the task ends
    (done or failed, back HOME)."""
    rec = _Record()
    next_vision = 0.0
    for k in range(int(round(t_end / DT))):
        t = k * DT
        if t >= next_vision - 1e-9:
            pose = sim.measured_part_pose() if t >= localised_after else None
            task.update_vision(t, pose, sim.q, sim.jaws_closed())
            rec.vision_t.append(t)
            next_vision += VISION_DT
        q, opening = task.step_control(t, sim.q)
        sim.step(q, opening)
        rec.t.append(t)
        rec.q.append(q)
        rec.opening.append(opening)
        rec.part.append(sim.T_part.copy())
        rec.phase.append(task.phase)
        if stop_when_done and task.phase in (Phase.DONE, Phase.FAILED) and task.stage == "hold" \
                and t > task.events[-1][0] + 1.0:
            break
    return rec


def _fast_task(**kwargs) -> GraspTask:
    planner = TrajectoryPlanner(grasp_pose(PART), max_speed=0.5, max_angular_speed=1.2)
    return GraspTask(ROBOT, PART, timing=FAST, planner=planner, **kwargs)


@pytest.fixture(scope="module")
def still_run():
    """The still part with the default (paper-like) timing."""
    task = GraspTask(ROBOT, PART)
    sim = _KinematicCell()
    return task, sim, _run(task, sim, 70.0)


@pytest.fixture(scope="module")
def moving_run():
    """A part moving at 3 cm/s along x and 1 cm/s along y, compressed timing."""
    task = _fast_task()
    sim = _KinematicCell(velocity=(0.03, 0.01, 0.0))
    return task, sim, _run(task, sim, 40.0)


# ---- CLIK --------------------------------------------------------------------------------------

def test_clik_pose_and_jacobian_match_the_kinematics() -> None:
    clik = Clik(ROBOT)
    T_flange_tcp = ROBOT.tool.T_flange_tool @ ROBOT.tool.T_tool_tcp
    R = ROBOT.T_base_robot[:3, :3]
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = ROBOT.chain.random_q(rng)
        T, J = clik.tcp_pose_and_jacobian(q)
        J_chain = ROBOT.chain.jacobian(q, T_flange_tcp)
        np.testing.assert_allclose(T, ROBOT.tcp_pose(q), atol=1e-12)
        np.testing.assert_allclose(J[:3], R @ J_chain[:3], atol=1e-12)
        np.testing.assert_allclose(J[3:], R @ J_chain[3:], atol=1e-12)


@settings(max_examples=12, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=7, max_size=7))
def test_clik_converges_to_a_reachable_pose(offsets: list[float]) -> None:
    """Targets are poses of joint vectors within +-0.3 rad (0.3 m on the track) of HOME."""
    q_goal = np.clip(ROBOT.home + 0.3 * np.array(offsets), *ROBOT.chain.qlim.T)
    T_goal = ROBOT.tcp_pose(q_goal)
    clik = Clik(ROBOT)
    q = ROBOT.home.copy()
    for _ in range(2500):
        q = clik.step(q, T_goal)
    T = ROBOT.tcp_pose(q)
    assert np.linalg.norm(T[:3, 3] - T_goal[:3, 3]) < 1e-4
    assert _angle(T_goal[:3, :3], T[:3, :3]) < 1e-3


def test_clik_respects_joint_position_and_velocity_limits() -> None:
    """An unreachable target far away and a fast feed-forward twist: every step stays within
    the joint limits and the joint speed limits."""
    clik = Clik(ROBOT, gain=200.0)
    T_far = make_pose(Rotation.from_rotvec([2.0, -1.0, 0.5]).as_matrix(), (2.5, 1.5, 2.5))
    q = ROBOT.home.copy()
    lo, hi = ROBOT.chain.qlim.T
    for _ in range(3000):
        q_next = clik.step(q, T_far, np.array([3.0, 0.0, 0.0, 0.0, 0.0, 5.0]))
        assert np.all(np.abs(q_next - q) / DT <= V_MAX * (1 + 1e-9))
        assert np.all(q_next >= lo) and np.all(q_next <= hi)
        q = q_next
    assert np.any(np.isclose(q, lo) | np.isclose(q, hi))  # the limits were really in play


@pytest.mark.parametrize("redundancy", ["joint_limits", "none"])
def test_null_space_term_moves_the_track_off_its_limit_without_moving_the_tcp(
        redundancy: str) -> None:
    q = ROBOT.home.copy()
    q[0] = 0.02  # the track 2 cm from its lower limit, inside the 16 cm band
    T_hold = ROBOT.tcp_pose(q)
    clik = Clik(ROBOT, redundancy=redundancy)
    for _ in range(2500):
        q = clik.step(q, T_hold)
        T = ROBOT.tcp_pose(q)
        assert np.linalg.norm(T[:3, 3] - T_hold[:3, 3]) < 1e-3
        assert _angle(T_hold[:3, :3], T[:3, :3]) < 1e-3
    band = 0.1 * 1.6
    if redundancy == "joint_limits":
        assert q[0] > 0.85 * band
    else:
        assert q[0] == pytest.approx(0.02, abs=1e-6)


def test_clik_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError, match="redundancy"):
        Clik(ROBOT, redundancy="posture")
    with pytest.raises(ValueError, match="velocity limits"):
        Clik(ROBOT, joint_velocity_limits=np.ones(3))


# ---- interpolating filter ---------------------------------------------------------------------

def test_filter_step_response_is_critically_damped() -> None:
    wn = 8.0
    filt = InterpolatingFilter(natural_frequency=wn, dt=DT)
    filt.reset(np.eye(4))
    step = make_pose(Rotation.from_rotvec([0.0, 0.0, 0.5]).as_matrix(), (0.1, 0.0, 0.0))
    filt.set_target(step)
    x, angle = [], []
    for _ in range(1000):
        T, _ = filt.step()
        x.append(T[0, 3])
        angle.append(Rotation.from_matrix(T[:3, :3]).as_rotvec()[2])
    t = DT * np.arange(1, 1001)
    expected = 1.0 - (1.0 + wn * t) * np.exp(-wn * t)  # critically damped unit step
    np.testing.assert_allclose(np.array(x) / 0.1, expected, atol=0.01)
    np.testing.assert_allclose(np.array(angle) / 0.5, expected, atol=0.01)
    assert np.all(np.diff(x) >= -1e-12) and max(x) <= 0.1 + 1e-9  # no overshoot


def test_filter_follows_a_moving_target_without_lag() -> None:
    """26 Hz updates of a target moving at constant (linear, angular) velocity: once the
    transient has died out, the 500 Hz output is on the target's true path."""
    twist = np.array([0.1, -0.05, 0.02, 0.0, 0.0, 0.4])
    filt = InterpolatingFilter(dt=DT)
    filt.reset(np.eye(4), twist)

    def truth(t: float) -> np.ndarray:
        return make_pose(Rotation.from_rotvec(twist[3:] * t).as_matrix(), twist[:3] * t)

    next_update = 0.0
    for k in range(1500):
        t = k * DT
        if t >= next_update - 1e-9:
            filt.set_target(truth(t), twist)
            next_update += VISION_DT
        T, v = filt.step()
    T_true = truth(1500 * DT)
    assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 1e-5
    assert _angle(T_true[:3, :3], T[:3, :3]) < 1e-5
    np.testing.assert_allclose(v, twist, atol=1e-5)


def test_filter_reproduces_a_planned_segment_and_smooths_a_jump() -> None:
    """A minimum-jerk segment handed over at 26 Hz with its twist and acceleration comes out
    at 500 Hz on the planned path; a sudden jump of the goal comes out without overshoot."""
    planner = TrajectoryPlanner(grasp_pose(PART))
    T_home = ROBOT.tcp_pose(Q_START)
    planner.reset(0.0, T_home)
    T_goal = make_pose(Rotation.from_rotvec([0.0, 0.0, 1.0]).as_matrix(), (0.6, 0.0, 0.8)) @ T_home
    T_goal[:3, 3] = (0.6, 0.0, 0.8)
    planner.move_to(0.0, PoseGoal(T_goal), 3.0)
    filt = InterpolatingFilter(dt=DT)
    filt.reset(T_home)
    next_update, worst = 0.0, 0.0
    for k in range(2000):
        t = k * DT
        if t >= next_update - 1e-9:
            filt.set_target(*planner.target(t))
            next_update += VISION_DT
        T, _ = filt.step()
        T_plan = planner.target(t + DT)[0]
        worst = max(worst, np.linalg.norm(T[:3, 3] - T_plan[:3, 3]),
                    _angle(T_plan[:3, :3], T[:3, :3]))
    assert worst < 2e-4  # 0.2 mm, 0.2 mrad along a 0.6 m, 1 rad move
    filt.set_target(T_home)  # a jump back, no planner: critically damped, no overshoot
    distance = [np.linalg.norm(filt.step()[0][:3, 3] - T_home[:3, 3]) for _ in range(1500)]
    assert np.all(np.diff(distance) <= 1e-12) and distance[-1] < 1e-4


def test_filter_rejects_a_coarse_discretisation() -> None:
    with pytest.raises(ValueError, match="too coarse"):
        InterpolatingFilter(natural_frequency=200.0, dt=DT)


# ---- planner ----------------------------------------------------------------------------------

def test_min_jerk_profile() -> None:
    assert min_jerk(0.0) == (0.0, 0.0, 0.0)
    assert min_jerk(1.0) == (1.0, 0.0, 0.0)
    assert min_jerk(2.0) == (1.0, 0.0, 0.0)
    s, ds, dds = min_jerk(0.5)
    assert s == pytest.approx(0.5) and ds == pytest.approx(1.875) and dds == pytest.approx(0.0)
    h = 1e-6
    for tau in (0.1, 0.3, 0.7, 0.9):
        assert min_jerk(tau)[1] == pytest.approx((min_jerk(tau + h)[0] - min_jerk(tau - h)[0])
                                                 / (2 * h), rel=1e-6)
        assert min_jerk(tau)[2] == pytest.approx((min_jerk(tau + h)[1] - min_jerk(tau - h)[1])
                                                 / (2 * h), rel=1e-6)


def test_grasp_pose_geometry() -> None:
    """Tool z down, tool y along the part's y axis, TCP at the cell file's grasp point (3 mm above
    mid-height, 1 cm off-centre); of the two symmetric grasps the planner picks the one nearer in
    orientation."""
    T_part = PART.T_base_part
    planner = TrajectoryPlanner(grasp_pose(PART))
    T_home = ROBOT.tcp_pose(ROBOT.home)
    G = planner.grasp_pose(T_part, T_home)
    np.testing.assert_allclose(G[:3, 2], [0.0, 0.0, -1.0], atol=1e-12)
    assert abs(G[:3, 1] @ T_part[:3, 1]) == pytest.approx(1.0)
    np.testing.assert_allclose(G[:3, 3], (T_part @ [0.0, -0.01, 0.018, 1.0])[:3], atol=1e-12)
    other = G @ HALF_TURN_Z
    assert _angle(G[:3, :3], T_home[:3, :3]) < _angle(other[:3, :3], T_home[:3, :3])
    np.testing.assert_allclose(planner.grasp_pose(T_part, other), other, atol=1e-12)


def test_part_motion_smooths_noisy_estimates() -> None:
    rng = np.random.default_rng(5)
    motion = PartMotion(window=0.5)
    v = np.array([0.04, -0.02, 0.0])
    raw, smoothed = [], []
    for k in range(80):
        t = k * VISION_DT
        T_true = PART.T_base_part.copy()
        T_true[:3, 3] += v * t
        T = T_true.copy()
        T[:3, 3] += rng.normal(0.0, 5e-4, 3)
        T[:3, :3] = Rotation.from_rotvec(rng.normal(0.0, 0.005, 3)).as_matrix() @ T[:3, :3]
        motion.update(t, T)
        if k >= 20:
            raw.append([np.linalg.norm(T[:3, 3] - T_true[:3, 3]),
                        _angle(T[:3, :3], T_true[:3, :3])])
            smoothed.append([np.linalg.norm(motion.T_base_part[:3, 3] - T_true[:3, 3]),
                             _angle(motion.T_base_part[:3, :3], T_true[:3, :3])])
    assert np.all(np.mean(smoothed, axis=0) < 0.6 * np.mean(raw, axis=0))
    assert np.linalg.norm(motion.velocity - v) < 0.005
    T_pred, _ = motion.predict(t + 0.2)
    np.testing.assert_allclose(T_pred[:3, 3], motion.T_base_part[:3, 3] + 0.2 * motion.velocity)
    _, v_stale = motion.predict(t + 2.0)  # too old: held, not extrapolated further
    assert np.all(v_stale == 0.0)
    motion.update(t + VISION_DT, T, velocity=v)  # the estimator's velocity: taken as it is
    np.testing.assert_allclose(motion.T_base_part, T)
    np.testing.assert_allclose(motion.velocity, v)


def test_segment_follows_a_moving_part_and_keeps_the_speed_limit() -> None:
    v = np.array([0.05, 0.02, 0.0])
    planner = TrajectoryPlanner(grasp_pose(PART), max_speed=0.25)
    T_home = ROBOT.tcp_pose(Q_START)
    planner.reset(0.0, T_home)

    def part_at(t: float) -> np.ndarray:
        T = PART.T_base_part.copy()
        T[:3, 3] += v * t
        return T

    planner.part.update(0.0, part_at(0.0), v)
    duration = planner.move_to(0.0, PartGoal(0.05), 1.0)
    over = planner.goal_at(PartGoal(0.05), 0.0)[0]
    relative_distance = np.linalg.norm(T_home[:3, 3] - over[:3, 3])
    assert duration == pytest.approx(1.875 * relative_distance / 0.25)  # lengthened
    h = 1e-4
    for k in range(int(duration * 26) + 30):
        t = k * VISION_DT
        planner.part.update(t, part_at(t), v)
        # twist and acceleration at t + h agree with central differences of the target pose
        # (between estimates the part is extrapolated forward only, hence t .. t + 2h)
        (T_a, tw_a, _), (T_b, tw_b, _) = planner.target(t), planner.target(t + 2 * h)
        T, twist, accel = planner.target(t + h)
        np.testing.assert_allclose(twist[:3], (T_b[:3, 3] - T_a[:3, 3]) / (2 * h), atol=1e-6)
        np.testing.assert_allclose(twist[3:], rotation_error(T_b[:3, :3], T_a[:3, :3]) / (2 * h),
                                   atol=1e-6)
        np.testing.assert_allclose(accel, (tw_b - tw_a) / (2 * h), atol=1e-5)
        assert np.linalg.norm(twist[:3] - v) <= 0.25 * (1 + 1e-9)  # speed relative to the part
    T, twist, _ = planner.target(t)
    G = planner.grasp_pose(part_at(t), T)
    G[2, 3] += 0.05
    np.testing.assert_allclose(T, G, atol=1e-9)
    np.testing.assert_allclose(twist, np.concatenate([v, np.zeros(3)]), atol=1e-12)


def test_planner_needs_a_start_pose_and_a_localised_part() -> None:
    planner = TrajectoryPlanner(grasp_pose(PART))
    with pytest.raises(RuntimeError, match="reset"):
        planner.target(0.0)
    planner.reset(0.0, np.eye(4))
    with pytest.raises(RuntimeError, match="localised"):
        planner.move_to(0.0, PartGoal(0.05), 1.0)
    planner.move_to(0.0, PoseGoal(make_pose(None, (0.1, 0.0, 0.0))), 1.0)
    np.testing.assert_allclose(planner.target(1.0)[0][:3, 3], [0.1, 0.0, 0.0])


# ---- the task, closed loop with the stand-in ---------------------------------------------------

def _phases(task: GraspTask) -> list[Phase]:
    return [Phase.WAITING] + [to for _, _, to, _ in task.transitions]


def test_still_part_is_grasped_and_delivered_with_paper_like_durations(still_run) -> None:
    task, sim, rec = still_run
    assert _phases(task) == PHASE_ORDER
    assert [str(p) for p in _phases(task)] == ["waiting", "approach", "grasp", "manipulate",
                                                "release", "done"]
    t, _, _ = rec.arrays()
    spans = {phase: (t0, t1) for phase, t0, t1 in task.phase_intervals(t[-1])}
    assert spans[Phase.APPROACH][0] == pytest.approx(4.0, abs=0.05)  # paper: after about 4 s
    assert 10.0 <= spans[Phase.APPROACH][1] <= 14.0  # paper: ends at about 12 s
    assert 7.0 <= spans[Phase.GRASP][1] - spans[Phase.GRASP][0] <= 9.0  # paper: about 8 s
    assert 18.0 <= spans[Phase.MANIPULATE][0] <= 26.0  # paper: about 25 s
    assert 40.0 <= spans[Phase.DONE][0] <= 60.0  # paper: FINAL at ~50 s, then HOME
    assert task.attempts == 0
    # delivered: released at FINAL, the robot back HOME with the jaws open
    T_final = ROBOT.tcp_pose(ROBOT.final)
    held_at = (sim.T_part @ grasp_pose(PART))[:2, 3]  # where the jaws held the part
    assert np.linalg.norm(held_at - T_final[:2, 3]) < 0.005
    T_end = ROBOT.tcp_pose(sim.q)
    assert np.linalg.norm(T_end[:3, 3] - task.T_home[:3, 3]) < 0.005
    assert rec.opening[-1] == ROBOT.tool.max_opening
    assert all(isinstance(reason, str) and reason for *_, reason in task.transitions)


def test_approach_goes_five_cm_over_the_part_then_descends(still_run) -> None:
    task, _, rec = still_run
    t, q, part = rec.arrays()
    (t_descend,) = [e[0] for e in task.events if e[2] == "descend"]
    k = int(np.searchsorted(t, t_descend)) - 1
    T = ROBOT.tcp_pose(q[k])
    G = part[k] @ grasp_pose(PART)
    assert T[2, 3] - G[2, 3] == pytest.approx(0.05, abs=0.002)
    assert np.linalg.norm(T[:2, 3] - G[:2, 3]) < 0.005
    t_grasp = task.transitions[1][0]
    k = int(np.searchsorted(t, t_grasp))
    dp, da = _grasp_error(ROBOT.tcp_pose(q[k]), part[k])
    assert dp < 0.005 and da < np.radians(2.0)


def test_moving_part_is_followed_and_grasped(moving_run) -> None:
    task, sim, rec = moving_run
    assert _phases(task) == PHASE_ORDER
    t, q, part = rec.arrays()
    assert task.attempts == 0
    # while hovering over the part (after the move there) the TCP follows it in x, y
    (t_over,) = [e[0] for e in task.events if e[2] == "over"]
    (t_descend,) = [e[0] for e in task.events if e[2] == "descend"]
    hover = (t > t_descend - FAST.stable) & (t < t_descend)
    tcp = np.array([ROBOT.tcp_pose(qk)[:3, 3] for qk in q[hover]])
    goal = np.array([(P @ grasp_pose(PART))[:3, 3] for P in part[hover]])
    assert np.max(np.linalg.norm(tcp[:, :2] - goal[:, :2], axis=1)) < 0.002
    np.testing.assert_allclose(tcp[:, 2] - goal[:, 2], 0.05, atol=0.002)
    assert np.linalg.norm(part[hover][-1][:3, 3] - part[hover][0][:3, 3]) > 0.01  # it did move
    # grasped while moving and carried: the part ends at FINAL, not on the conveyor
    assert not sim.on_conveyor
    T_final = ROBOT.tcp_pose(ROBOT.final)
    held_at = (sim.T_part @ grasp_pose(PART))[:2, 3]  # where the jaws held the part
    assert np.linalg.norm(held_at - T_final[:2, 3]) < 0.005
    assert t_over == pytest.approx(FAST.start, abs=0.05)


def test_failed_jaw_check_goes_back_to_approach_and_retries() -> None:
    task = _fast_task()
    sim = _KinematicCell(refuse_grasps=1)
    _run(task, sim, 40.0)
    assert _phases(task) == [Phase.WAITING, Phase.APPROACH, Phase.GRASP, Phase.APPROACH,
                             Phase.GRASP, Phase.MANIPULATE, Phase.RELEASE, Phase.DONE]
    assert "jaws not closed" in task.transitions[2][3]
    assert task.attempts == 1 and not sim.on_conveyor


def test_grasp_gives_up_after_max_attempts() -> None:
    task = _fast_task(moves=TaskMoves(max_attempts=2))
    sim = _KinematicCell(refuse_grasps=5)
    _run(task, sim, 40.0)
    assert _phases(task)[-1] == Phase.FAILED and task.attempts == 2
    assert "giving up" in task.transitions[-1][3]
    assert np.linalg.norm(ROBOT.tcp_pose(sim.q)[:3, 3] - task.T_home[:3, 3]) < 0.005
    assert sim.on_conveyor


def test_waits_until_the_part_is_localised(caplog) -> None:
    task = _fast_task()
    sim = _KinematicCell()
    with caplog.at_level(logging.INFO, logger="cellsight.control.task"):
        rec = _run(task, sim, 6.0, localised_after=5.0, stop_when_done=False)
    assert "waiting -> approach (part localised)" in caplog.text
    (t_start,) = [t for t, _, to, _ in task.transitions if to == Phase.APPROACH]
    assert t_start == pytest.approx(5.0, abs=VISION_DT + 1e-9)  # not at FAST.start = 1.6 s
    t, q, _ = rec.arrays()
    assert np.abs(q[t < t_start] - ROBOT.home).max() < 1e-9


def test_a_lost_part_sends_the_approach_back_clear_of_the_views_until_found() -> None:
    task = _fast_task()
    sim = _KinematicCell()
    T_start = ROBOT.tcp_pose(sim.q)
    t, k, stages = 0.0, 0, []
    lost = (3.0, 6.0)  # the tracker says lost, with no estimate, between these times
    while t < 8.0:
        if k % round(VISION_DT / DT) == 0:
            is_lost = lost[0] <= t < lost[1]
            task.update_vision(t, None if is_lost else sim.measured_part_pose(), sim.q,
                               sim.jaws_closed(), part_lost=is_lost)
            stages.append((t, task.stage))
        sim.step(*task.step_control(t, sim.q))
        k += 1
        t = k * DT
        if abs(t - lost[1]) < DT / 2:
            at_lost_end = ROBOT.tcp_pose(sim.q)
    assert [s for t, s in stages if lost[0] <= t < lost[1]] == ["clear"] * sum(
        lost[0] <= t < lost[1] for t, _ in stages)
    np.testing.assert_allclose(at_lost_end[:3, 3], T_start[:3, 3], atol=0.005)
    assert "over" in [s for t, s in stages if t >= lost[1]]


# ---- smoothness of the 500 Hz set-points -------------------------------------------------------

def _derivatives(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Finite-difference joint velocity and acceleration of the 500 Hz set-points."""
    v = np.diff(q, axis=0) / DT
    return v, np.diff(v, axis=0) / DT


@pytest.mark.parametrize("scenario", ["still_run", "moving_run"])
def test_setpoints_are_smooth_across_phase_changes_and_planner_updates(scenario, request):
    """Whole runs (every phase change, stage change and 26 Hz planner update included):
    velocities within V_MAX, accelerations within A_MAX, and no acceleration step from one
    2 ms sample to the next larger than A_MAX / 2 (the planner updates and the phase changes
    are where the filter gets new targets, hence where such steps would show)."""
    task, _, rec = request.getfixturevalue(scenario)
    assert len(task.transitions) == 5 and len(task.events) >= 9 and len(rec.vision_t) > 300
    q = np.vstack([ROBOT.home, np.array(rec.q)])  # from the measured start: first step counts
    v, a = _derivatives(q)
    assert np.all(np.abs(v) <= V_MAX * (1 + 1e-9))
    assert np.all(np.abs(a) <= A_MAX)
    assert np.all(np.abs(np.diff(a, axis=0)) <= 0.5 * A_MAX)


def test_smoothness_check_fails_without_the_interpolating_filter() -> None:
    """Negative control: feeding the 26 Hz planner targets straight to the CLIK (zero-order
    hold instead of the filter) breaks the acceleration bound used above."""

    class ZeroOrderHold(InterpolatingFilter):
        def step(self):
            return self._T_ref.copy(), np.zeros(6)

    task = _fast_task(interpolator=ZeroOrderHold(dt=DT))
    rec = _run(task, _KinematicCell(), 6.0, stop_when_done=False)
    _, a = _derivatives(np.array(rec.q))
    assert np.any(np.abs(a) > A_MAX)
    assert np.any(np.abs(np.diff(a, axis=0)) > 0.5 * A_MAX)


# ---- the task against the MuJoCo world (when it is available) ---------------------------------

def _world_run(speed: float, world_grasp: bool, t_end: float = 40.0, miss_x: float = 0.0,
               check_opening: bool = False, retry_shift: float = 0.0035):
    """The task (compressed timing) against the MuJoCo world, the part on a conveyor moving
    along +x at ``speed`` (m/s); the grasp is the world's own (``world_grasp``) or the
    controller's default, aimed ``miss_x`` (m) off along the part's x; ``check_opening``: the
    task checks the jaws' opening against the grasp's, and moves its retries by
    ``retry_shift``."""
    world_mod = pytest.importorskip("cellsight.world")
    start = PART.T_base_part[:2, 3]
    conveyor = (world_mod.ConveyorPath(np.array([start, start + [0.8, 0.0]]), speed)
                if speed > 0 else world_mod.ConveyorPath.still())
    world = world_mod.World(CELL, seed=1, conveyor=conveyor)
    T_part_tcp = world.grippers.grasp_pose(PART.name) if world_grasp else grasp_pose(PART)
    aim = T_part_tcp.copy()
    aim[0, 3] += miss_x
    planner = TrajectoryPlanner(aim, max_speed=0.5, max_angular_speed=1.2)
    opening = (pytest.importorskip("cellsight.model.grasp").grasp_opening(
        PART.solid, ROBOT.tool, T_part_tcp) if check_opening else None)
    task = GraspTask(ROBOT, PART, timing=FAST, planner=planner, grasp_opening=opening,
                     moves=TaskMoves(retry_shift=retry_shift))
    rng = np.random.default_rng(2)
    name = ROBOT.name
    next_vision, grasped_at = 0.0, None
    q_record = []
    while world.time < t_end and task.phase != Phase.DONE:
        t = world.time
        q_meas = world.measured_joints()[name]
        if t >= next_vision - 1e-9:
            T = world.true_part_poses()[PART.name].copy()
            T[:3, 3] += rng.normal(0.0, 5e-4, 3)  # ideal measurement + small noise
            task.update_vision(t, T, q_meas, world.jaws_closed_on_part(name),
                               jaw_opening=world.jaw_openings()[name])
            next_vision += VISION_DT
        q, opening = task.step_control(t, q_meas)
        q_record.append(q)
        world.step({name: q}, {name: opening})
        if grasped_at is None and world.grasp(name) is not None:
            grasped_at = world.time
    return task, world, T_part_tcp, grasped_at, np.array(q_record)


@pytest.mark.parametrize(("speed", "world_grasp", "tolerance"), [
    # the controller's grasp (bounding-box centre): the jaws clamp the U's 4 cm of material
    # under the TCP and centre it, which shifts the part by 1 cm in the gripper; the part's
    # grasp point then ends 1 cm from the TCP
    (0.0, False, 0.015),
    (0.03, True, 0.005),  # the world's grasp, centred on that material: no shift
])
def test_task_grasps_and_delivers_in_the_mujoco_world(speed: float, world_grasp: bool,
                                                      tolerance: float) -> None:
    task, world, T_part_tcp, grasped_at, q = _world_run(speed, world_grasp)
    assert _phases(task) == PHASE_ORDER and task.attempts == 0
    assert grasped_at is not None
    t_grasp = task.transitions[1][0]
    assert t_grasp < grasped_at < t_grasp + FAST.close + VISION_DT
    grip_point = (world.true_part_poses()[PART.name] @ T_part_tcp)[:2, 3]
    T_final = ROBOT.tcp_pose(ROBOT.final)
    assert np.linalg.norm(grip_point - T_final[:2, 3]) < tolerance  # released under FINAL
    assert world.grasp(ROBOT.name) is None
    v, a = _derivatives(q)
    assert np.all(np.abs(v) <= V_MAX * (1 + 1e-9)) and np.all(np.abs(a) <= A_MAX)


def test_grasp_miss_names_a_wrong_opening() -> None:
    assert grasp_miss(False, None, None, 0.005) == "jaws not closed on the part"
    assert grasp_miss(True, 0.0601, None, 0.005) is None  # nothing to compare with
    assert grasp_miss(True, None, 0.04, 0.005) is None  # no reading
    assert grasp_miss(True, 0.044, 0.04, 0.005) is None
    assert "60.1 mm, not the grasp's 40.0 mm" in grasp_miss(True, 0.0601, 0.04, 0.005)


def test_jaws_caught_off_the_grasp_are_opened_again_in_the_mujoco_world() -> None:
    """Aimed 4 mm along the part's x, the jaws (35 mm wide) miss the U's 40 mm slot and close
    on its 60 mm ends; the world does not weld that grasp (the part pushed 1 cm off it).
    Without the opening check the task lifts empty jaws; with it, it opens them and tries
    again, 3.5 mm along the jaws' width: 0.5 mm off the slot's middle, the world welds the
    grasp and the part is lifted. Tried again at the same aim, it misses again."""
    grasp_opening = pytest.importorskip("cellsight.model.grasp").grasp_opening
    assert grasp_opening(PART.solid, ROBOT.tool, grasp_pose(PART)) == \
        pytest.approx(0.04)
    blind, world, *_ = _world_run(0.0, True, t_end=12.0, miss_x=0.004)
    assert Phase.MANIPULATE in _phases(blind) and world.grasp(ROBOT.name) is None
    lifted = world.true_part_poses()[PART.name][2, 3] - PART.T_base_part[2, 3]
    assert abs(lifted) < 1e-3  # left behind
    task, world, *_ = _world_run(0.0, True, t_end=12.0, miss_x=0.004, check_opening=True)
    assert _phases(task)[:6] == [Phase.WAITING, Phase.APPROACH, Phase.GRASP, Phase.APPROACH,
                                 Phase.GRASP, Phase.MANIPULATE]
    assert "they caught the part off its grasp (attempt 1)" in task.transitions[2][3]
    assert "the next grasp" in task.transitions[2][3]
    assert world.grasp(ROBOT.name) is not None
    same, world, *_ = _world_run(0.0, True, t_end=12.0, miss_x=0.004, check_opening=True,
                                 retry_shift=0.0)
    assert Phase.MANIPULATE not in _phases(same) and same.attempts >= 2


@settings(max_examples=300, deadline=None)
@given(st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3),
       st.sampled_from([1e-12, 1e-7, 1e-4, 0.3, 2.0, np.pi - 1e-9, np.pi]))
def test_compiled_rotations_agree_with_scipy(direction, angle):
    """The control loop's compiled rotation vector <-> matrix conversions against SciPy's, at
    every angle from 1e-12 rad to pi (where the vector's sign is free)."""
    from cellsight.control._rotations import matrix_of_rotvec, rotvec_of_matrix

    w = np.array(direction) / np.linalg.norm(direction) * angle
    R = Rotation.from_rotvec(w).as_matrix()
    np.testing.assert_allclose(matrix_of_rotvec(w), R, atol=1e-14)
    ours, theirs = rotvec_of_matrix(R), Rotation.from_matrix(R).as_rotvec()
    if angle > np.pi - 1e-6:
        theirs = theirs if ours @ theirs > 0 else -theirs
    np.testing.assert_allclose(ours, theirs, atol=1e-12)


@pytest.mark.parametrize("turn_deg, switched", [(180.0, True), (130.0, True), (20.0, False),
                                                (100.0, False)])
def test_a_turned_estimate_switches_to_the_twin_grasp_without_a_jump(turn_deg, switched):
    """The part's estimate turns about the vertical by ``turn_deg`` after the grasp was chosen:
    past 110 deg (90 and half the margin) the twin grasp (half a turn about the approach
    axis) is the nearer one to the TCP (which has not turned), and the segment starts again
    from the TCP towards it; the goal's orientation is then the twin's at the turned estimate."""
    planner = TrajectoryPlanner(grasp_pose(PART))
    T_start = ROBOT.tcp_pose(Q_START)
    planner.reset(0.0, T_start)
    T_part = PART.T_base_part.copy()
    planner.part.update(0.0, T_part)
    planner.move_to(0.0, PartGoal(0.05), 4.0)
    chosen = planner.chosen_grasp
    turned = T_part.copy()
    turned[:3, :3] = Rotation.from_euler("z", turn_deg, degrees=True).as_matrix() @ T_part[:3, :3]
    for t in np.arange(0.04, 1.0, 0.04):  # the estimate holds the turned pose from now on
        planner.part.update(float(t), turned)
    T_tcp = T_part @ chosen  # the TCP over the part at the grasp chosen, not turned since
    T_tcp[2, 3] += 0.05
    before = planner.target(1.0)[0]
    assert planner.keep_grasp_near(1.0, T_tcp) is switched
    after = planner.target(1.0)[0]
    start = T_tcp if switched else before  # a new segment starts where the TCP is
    assert np.linalg.norm(after[:3, 3] - start[:3, 3]) < 1e-9 and _angle(
        after[:3, :3], start[:3, :3]) < 1e-9
    expected = chosen @ HALF_TURN_Z if switched else chosen
    np.testing.assert_allclose(planner.chosen_grasp, expected, atol=1e-12)
    goal = turned @ expected
    assert _angle(planner.goal_at(PartGoal(0.05), 1.0)[0][:3, :3], goal[:3, :3]) < 1e-9
    assert planner.keep_grasp_near(1.0, T_tcp) is False  # no switching back and forth


def test_the_task_and_the_world_aim_at_one_grasp_when_the_cell_gives_none():
    # Without a grasp in the cell file, the task's planner and the world's grippers take the
    # same default (cellsight.model.grasp): the jaws across the part's narrower side, centred
    # between where they touch it (two rules once aimed 1 cm apart on a part like this one).
    from dataclasses import replace

    from cellsight.model import Cell
    from cellsight.world import World

    part = replace(PART, T_part_grasp=None)
    cell = Cell(CELL.name, CELL.robots, [part], CELL.static, CELL.cameras, CELL.source,
                CELL.experiments)
    task = GraspTask(ROBOT, part, timing=FAST)
    world = World(cell)
    assert np.allclose(task.planner.T_part_tcp, world.grippers.grasp_pose(part.name))
    world.close()
    with pytest.raises(ValueError, match="no grasp in the cell file, and no gripper"):
        grasp_pose(part)
