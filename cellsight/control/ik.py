"""Inverse kinematics of a cell's robot: every configuration branch that puts its tool centre
point (TCP) at a pose, each with its margins.

The solver is damped least squares (Levenberg-Marquardt) on the TCP's 6D pose error
(position m, rotation vector rad, cell base frame), iterated from several seeds (HOME, FINAL,
the middle of the joint ranges, and ``seeds`` drawn uniformly in the limits with a fixed seed)
until the error is below ``tol_m`` and ``tol_rad``. Every step is clipped to the joint limits,
so a solution is always inside them; its errors are checked again by forward kinematics.

**Branches.** An arm of six revolute joints (after a track, if it has one) has up to eight
branches, told apart by three signs, with ``a_i``, ``o_i`` the axis and a point of the arm's
i-th joint (1-6), base frame, and ``p_w`` the wrist centre (the point of joint 4's axis
nearest joint 5's: where the last three axes meet on a spherical wrist):

- shoulder: ``front`` when ``(p_w - o_1) . (a_1 x a_2) > 0`` (the wrist centre on the side of
  joint 1's axis where the shoulder's plane points), else ``back``;
- elbow: ``up`` when, across joint 2's axis, the elbow (joint 3's axis) lies on the robot
  base's +z side of the line from the shoulder (joint 2's axis) to the wrist centre, else
  ``down``;
- wrist: ``noflip`` when ``(a_4 x a_6) . a_5 >= 0``, else ``flip`` (the sign of joint 5's
  angle, for the usual zero).

The solutions are kept one per branch (where several reach it, such as a track's positions or
a joint turned by a full turn on a UR, the one farthest from its joint limits); a branch no
seed reached is listed as not reached. Any other arm gets its distinct solutions, two being
the same when every joint is within ``SAME_RAD`` of the other's; its branch is the seed's
name.

Joint units: m for prismatic joints, rad for revolute ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import product

import numpy as np

from cellsight.control.clik import rotation_error, tcp_pose_and_jacobian
from cellsight.errors import CellsightError
from cellsight.model.robot import Robot

SAME_RAD = 1e-3  # solutions closer than this in every joint are one
BRANCH_FLAGS = {"shoulder": ("front", "back"), "elbow": ("up", "down"),
                "wrist": ("noflip", "flip")}
_WRIST_TOL_M = 1e-6  # the last three axes meet within this: a spherical wrist
_MAX_STEP = 0.3  # rad or m per iteration at most
_ITERATIONS = 400


class IKError(CellsightError):
    """No joint vector inside the limits puts the TCP at the pose."""


@dataclass(frozen=True)
class IKSolution:
    """One configuration: ``q`` (n,), its ``branch`` (flag -> value, module docstring; or
    ``{"seed": name}``), the TCP's errors by forward kinematics (m, rad), ``limit_margin``
    (n,): each joint's distance to its nearer limit (rad or m), and ``sigma_min``: the smallest
    singular value of the TCP's 6 x n Jacobian (base frame; 0 at a singularity)."""

    q: np.ndarray
    branch: dict[str, str]
    position_error_m: float
    rotation_error_rad: float
    limit_margin: np.ndarray
    sigma_min: float


@dataclass(frozen=True)
class IKResult:
    """The solutions (sorted by branch) and the branches not reached (arms with branch
    flags)."""

    solutions: list[IKSolution]
    unreached: list[dict[str, str]] = field(default_factory=list)


def tcp_frame(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The TCP pose (4, 4, base frame; the flange without a tool) and its geometric Jacobian
    (6, n, base frame)."""
    T_flange_tcp = np.eye(4) if robot.tool is None else (robot.tool.T_flange_tool
                                                         @ robot.tool.T_tool_tcp)
    return tcp_pose_and_jacobian(robot, q, T_flange_tcp)


def solve_ik(robot: Robot, T_base_tcp: np.ndarray, *, seeds: int = 48, tol_m: float = 1e-6,
             tol_rad: float = 1e-6) -> IKResult:
    """Every branch of ``robot`` that puts its TCP at ``T_base_tcp`` (module docstring);
    :class:`IKError` when none does, naming how close the best attempt came."""
    T_goal = np.asarray(T_base_tcp, dtype=float)
    if T_goal.shape != (4, 4) or not np.isfinite(T_goal).all():
        raise IKError(f"ik: the TCP pose must be a finite 4x4 matrix, got {T_goal.tolist()}")
    found, closest = [], (np.inf, np.inf)
    for name, q0 in _seeds(robot, seeds):
        q, err = converge(robot, T_goal, q0, tol_m, tol_rad)
        if err[0] >= tol_m or err[1] >= tol_rad:
            closest = min(closest, err)
            continue
        found.append(_solution(robot, T_goal, q, name))
    if not found:
        raise IKError(f"ik: {robot.name} cannot put its TCP at {np.round(T_goal[:3, 3], 4)} "
                      f"(m) with that orientation inside its joint limits: the closest of "
                      f"{seeds + 3} attempts stays {closest[0] * 1e3:.1f} mm and "
                      f"{np.degrees(closest[1]):.2f} deg away")
    if not _has_branches(robot):
        return IKResult(_distinct(found))
    best: dict[tuple[str, ...], IKSolution] = {}
    for s in found:
        key = tuple(s.branch.values())
        if key not in best or _spare(robot, s) > _spare(robot, best[key]):
            best[key] = s
    every = [dict(zip(BRANCH_FLAGS, combo, strict=True))
             for combo in product(*BRANCH_FLAGS.values())]
    return IKResult([best[k] for k in sorted(best)],
                    [b for b in every if tuple(b.values()) not in best])


def branch_of(robot: Robot, q: np.ndarray) -> dict[str, str]:
    """The branch flags of ``q`` (module docstring); {} for an arm without them."""
    if not _has_branches(robot):
        return {}
    axes, points = _arm_axes(robot, q)
    a, o = axes[-6:], points[-6:]
    p_w = _meeting_point(a[3], o[3], a[4], o[4])  # the wrist centre
    shoulder = float(np.dot(p_w - o[0], np.cross(a[0], a[1])))
    # the elbow's side of the shoulder -> wrist line, in the plane across joint 2's axis
    v_w, v_e = (v - np.dot(v, a[1]) * a[1] for v in (p_w - o[1], o[2] - o[1]))
    line = v_w / max(float(np.linalg.norm(v_w)), 1e-12)
    elbow = float(np.dot(v_e - np.dot(v_e, line) * line, robot.T_base_robot[:3, 2]))
    wrist = float(np.dot(np.cross(a[3], a[5]), a[4]))
    return {"shoulder": "front" if shoulder > 0 else "back",
            "elbow": "up" if elbow > 0 else "down",
            "wrist": "noflip" if wrist >= 0 else "flip"}


def _seeds(robot: Robot, n: int) -> list[tuple[str, np.ndarray]]:
    qlim = robot.chain.qlim
    out = [("HOME", robot.home), ("middle", qlim.mean(axis=1))]
    out.append(("FINAL", robot.final if robot.final is not None else qlim.mean(axis=1)))
    rng = np.random.default_rng(0)
    out += [(f"random {k}", rng.uniform(qlim[:, 0], qlim[:, 1])) for k in range(n)]
    return out


def converge(robot: Robot, T_goal: np.ndarray, q0: np.ndarray, tol_m: float,
             tol_rad: float) -> tuple[np.ndarray, tuple[float, float]]:
    """Levenberg-Marquardt from ``q0``, every step clipped to the joint limits, until the TCP's
    errors are under ``tol_m`` and ``tol_rad`` or no step lowers them: the joints that came
    closest and their errors (m, rad)."""
    qlim = robot.chain.qlim
    q = np.clip(np.asarray(q0, dtype=float), qlim[:, 0], qlim[:, 1])
    e, J = _error(robot, T_goal, q)
    lam, best = 1e-2, (float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:])))
    for _ in range(_ITERATIONS):
        if best[0] < tol_m and best[1] < tol_rad:
            return q, best
        try:
            dq = J.T @ np.linalg.solve(J @ J.T + lam ** 2 * np.eye(6), e)
        except np.linalg.LinAlgError:  # singular and hardly damped: damp more
            lam *= 4.0
            continue
        dq *= min(1.0, _MAX_STEP / max(float(np.abs(dq).max()), 1e-300))
        q_new = np.clip(q + dq, qlim[:, 0], qlim[:, 1])
        e_new, J_new = _error(robot, T_goal, q_new)
        if np.linalg.norm(e_new) < np.linalg.norm(e):
            q, e, J, lam = q_new, e_new, J_new, max(lam * 0.3, 1e-6)
            best = (float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:])))
        else:
            lam *= 4.0
            if lam > 1e6:
                break
    return q, best


def _error(robot: Robot, T_goal: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T, J = tcp_frame(robot, q)
    e = np.concatenate([T_goal[:3, 3] - T[:3, 3], rotation_error(T_goal[:3, :3], T[:3, :3])])
    return e, J


def _solution(robot: Robot, T_goal: np.ndarray, q: np.ndarray, seed: str) -> IKSolution:
    T, J = tcp_frame(robot, q)
    qlim = robot.chain.qlim
    margin = np.minimum(q - qlim[:, 0], qlim[:, 1] - q)
    return IKSolution(
        q=q, branch=branch_of(robot, q) or {"seed": seed},
        position_error_m=float(np.linalg.norm(T_goal[:3, 3] - T[:3, 3])),
        rotation_error_rad=float(np.linalg.norm(rotation_error(T_goal[:3, :3], T[:3, :3]))),
        limit_margin=margin, sigma_min=float(np.linalg.svd(J, compute_uv=False)[-1]))


def _spare(robot: Robot, s: IKSolution) -> float:
    """The smallest joint-limit margin as a fraction of that joint's range."""
    span = np.ptp(robot.chain.qlim, axis=1)
    return float(np.min(s.limit_margin / span))


def _distinct(found: list[IKSolution]) -> list[IKSolution]:
    out: list[IKSolution] = []
    for s in found:
        if all(np.abs(s.q - o.q).max() > SAME_RAD for o in out):
            out.append(s)
    return out


def _arm_axes(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every joint's unit axis and a point on it (n, 3 each, base frame) at ``q``."""
    frames = robot.chain.fkine(q)
    axes, points = robot.chain.joint_axes(frames)
    R, p = robot.T_base_robot[:3, :3], robot.T_base_robot[:3, 3]
    return axes @ R.T, points @ R.T + p


def _meeting_point(a1: np.ndarray, o1: np.ndarray, a2: np.ndarray,
                   o2: np.ndarray) -> np.ndarray:
    """The point of line 1 (``o1 + s a1``) nearest line 2."""
    w, b = o1 - o2, float(np.dot(a1, a2))
    aa, cc = float(np.dot(a1, a1)), float(np.dot(a2, a2))
    den = aa * cc - b * b
    s = 0.0 if den < 1e-12 else (b * float(np.dot(a2, w)) - cc * float(np.dot(a1, w))) / den
    return o1 + s * a1


def _has_branches(robot: Robot) -> bool:
    """Six revolute joints, after any prismatic ones (a track): an arm with branch flags."""
    revolute = ~robot.chain.prismatic
    return int(revolute.sum()) == 6 and bool(revolute[-6:].all())
