"""A robot joint's position servo at the control rate: how far the real arm lags its set-points.

Each joint is a second-order loop, ``q'' = wn^2 (q_target - q) - 2 zeta wn q'`` with
``wn = 2 pi bandwidth_hz``, the target held over each control period ``dt`` and the loop
integrated exactly over it (the matrix exponential of the linear system), then the velocity
clipped to the joint's limit and its change to the acceleration limit. Unclipped, its step
response is ``1 - (1 + wn t) e^(-wn t)`` at the control instants when critically damped
(``zeta = 1``), and it follows a ramp of slope ``v`` with a steady lag of ``2 zeta v / wn``.
With ``velocity_feedforward`` (as industrial drives have) the loop is
``q'' = wn^2 (q_target - q) + 2 zeta wn (v_target - q')``, ``v_target`` the set-point's velocity
over the period (the set-point then moves along a ramp through it rather than jumping at its
start): a ramp is followed with no steady lag, and what is left is the transient of each change
of velocity. A bandwidth of 0 is the ideal servo of a kinematic world: the joint is at its
target at the end of each period. Units: rad (m for a prismatic joint), s, Hz.

With ``mujoco`` the joints are MuJoCo's instead (:mod:`cellsight.world.mjcf`,
:class:`~cellsight.world.world.World`): each is driven by a position actuator on a rotor
inertia (``armature``: :data:`ARMATURE_KG_M2`, :data:`ARMATURE_KG` for a prismatic joint, the
motor's inertia through its gearbox) with the same second-order loop, tuned to the robot being
driven: its gains are set for the joint's whole inertia ``I`` at the robot's start (the rotor's
plus the links' beyond it, from MuJoCo's mass matrix: 0.03-9.6 kg m^2 on the built-in cells'
arms), so every joint of every robot has the profile's bandwidth there
(:func:`actuator_gains`: ``kp = I wn^2``, ``kv = 2 zeta I wn``; the feed-forward enters as the
actuator's set-point ``q_target + (kv / kp) v_target``), a torque (force) limit
``I max_acceleration``, gravity compensated (as a robot controller's feed-forward does), the
velocity clipped after each step, and integrated by ``mj_step`` with contacts on: what the arm
hits pushes back.

Every joint's speed limit is the profile's ``max_velocity`` or the robot's rated speed (its
URDF's ``limit velocity``), whichever is lower.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

ARMATURE_KG_M2 = 2.0  # a revolute joint's rotor inertia through its gearbox (our estimate)
ARMATURE_KG = 200.0  # a prismatic joint's (a carriage on its track; our estimate)


@dataclass(frozen=True)
class ServoParams:
    """``bandwidth_hz`` (0: ideal), ``damping`` (zeta), ``max_velocity`` (rad/s or m/s) and
    ``max_acceleration`` (rad/s^2 or m/s^2) of every joint; ``mujoco``: MuJoCo's actuators and
    contacts move the joints (module docstring; needs a bandwidth); ``velocity_feedforward``:
    the set-point's velocity is fed forward (module docstring)."""

    bandwidth_hz: float = 0.0
    damping: float = 1.0
    max_velocity: float = math.inf
    max_acceleration: float = math.inf
    mujoco: bool = False
    velocity_feedforward: bool = False

    def __post_init__(self) -> None:
        if self.mujoco and self.bandwidth_hz <= 0.0:
            raise ValueError("ServoParams: MuJoCo's actuators need a bandwidth > 0 Hz")

    @property
    def ideal(self) -> bool:
        return self.bandwidth_hz <= 0.0

    @property
    def feedforward_gain(self) -> float:
        """``kv / kp`` (s): the actuator set-point's lead per unit of set-point velocity."""
        return 2.0 * self.damping / (2.0 * math.pi * self.bandwidth_hz)


def actuator_gains(params: ServoParams, inertia: float) -> tuple[float, float, float]:
    """(kp, kv, force limit) of a MuJoCo position actuator that gives a joint of ``inertia``
    (kg m^2 or kg: its rotor's and its links') the servo's second-order loop (module
    docstring); the force limit is infinite when the acceleration is unlimited."""
    wn = 2.0 * math.pi * params.bandwidth_hz
    return (inertia * wn * wn, 2.0 * params.damping * inertia * wn,
            inertia * params.max_acceleration)


class JointServo:
    """The servo of one robot's joints (module docstring), starting at rest at ``q0``;
    ``rated_velocity``: each joint's rated speed (rad/s, m/s), which caps the profile's."""

    def __init__(self, params: ServoParams, q0: np.ndarray, dt: float,
                 rated_velocity: np.ndarray | None = None) -> None:
        self.params, self.dt = params, float(dt)
        self.max_velocity = (np.full(len(q0), params.max_velocity) if rated_velocity is None
                             else np.minimum(params.max_velocity, rated_velocity))
        self.q = np.array(q0, dtype=float)
        self.qd = np.zeros_like(self.q)
        self.target = self.q.copy()
        self._previous_target = self.target.copy()
        if not params.ideal:
            wn = 2.0 * math.pi * params.bandwidth_hz
            A = np.array([[0.0, 1.0], [-wn * wn, -2.0 * params.damping * wn]])
            self._phi = expm(A * self.dt)  # state (q - target, q') over one period

    def step(self) -> np.ndarray:
        """One control period towards :attr:`target`; returns the new joint values."""
        p = self.params
        v = self.target_velocity()
        self._previous_target = self.target.copy()
        if p.ideal:
            self.q = self.target.copy()
            return self.q
        error = self.q - (self.target - v * self.dt)  # from the set-point at the period's start
        error_rate = self.qd - v
        new_error = self._phi[0, 0] * error + self._phi[0, 1] * error_rate
        qd = v + self._phi[1, 0] * error + self._phi[1, 1] * error_rate
        dv = p.max_acceleration * self.dt
        qd = np.minimum(np.maximum(qd, self.qd - dv), self.qd + dv)  # np.clip, cheaper
        qd = np.minimum(np.maximum(qd, -self.max_velocity), self.max_velocity)
        clipped = qd != v + self._phi[1, 0] * error + self._phi[1, 1] * error_rate
        self.q = np.where(clipped, self.q + 0.5 * (self.qd + qd) * self.dt,
                          self.target + new_error)
        self.qd = qd
        return self.q

    def target_velocity(self) -> np.ndarray:
        """The set-point's velocity over the coming period (rad/s, m/s) when it is fed forward
        (the change of :attr:`target` since the last period over ``dt``), else zero."""
        if not self.params.velocity_feedforward or self.dt <= 0.0:
            return np.zeros_like(self.target)
        return (self.target - self._previous_target) / self.dt

    def actuator_setpoint(self) -> np.ndarray:
        """MuJoCo's position actuator set-point, held over the coming period: the target (held
        from the period's start, as in :meth:`step`) or, with the velocity fed forward, the
        ramp's value at the period's start (where ``mj_step`` evaluates the force) led by that
        velocity times ``kv / kp`` (module docstring). Ends the period as :meth:`step` does."""
        v = self.target_velocity()
        start = self.target - v * self.dt
        self._previous_target = self.target.copy()
        return start + self.params.feedforward_gain * v

    def place(self, q: np.ndarray) -> None:
        """Put the joints at ``q``, at rest, with that target (a replayed state)."""
        self.q = np.array(q, dtype=float)
        self.qd = np.zeros_like(self.q)
        self.target = self.q.copy()
        self._previous_target = self.target.copy()
