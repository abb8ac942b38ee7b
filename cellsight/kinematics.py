"""Serial-chain forward kinematics and the geometric Jacobian: DH chains and URDF-style chains.

:class:`KinematicChain` is what the cell, the world, the CLIK and the planner use; two chains
implement it:

- :class:`DHChain`, standard (distal) DH: ``A_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``. A
  revolute joint adds ``q_i`` to ``theta_i``, a prismatic joint adds ``q_i`` to ``d_i``; joint
  ``i`` acts about/along z of frame ``i-1``.
- :class:`SerialChain`, URDF-style: frame ``i`` (the child link of joint ``i``) is
  ``T_{i-1} @ origin_i @ M_i(q_i)``, ``M_i`` a rotation about (revolute) or a translation along
  (prismatic) the unit ``axis_i`` given in frame ``i``; joint ``i`` acts about/along that axis
  through the origin of frame ``i``. Its forward kinematics is a numba kernel.

Lengths in metres, angles in radians. Frame 0 is the chain base; frame ``i`` is attached to
link ``i``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np
from numba import njit

from cellsight.errors import KinematicsError, short_repr

JointKind = Literal["revolute", "prismatic"]


class KinematicChain(Protocol):
    """A serial chain of n joints (revolute: rad, prismatic: m), base frame 0, frames 1..n.

    ``qlim`` (n, 2) joint limits; ``kinds`` each joint's kind; ``prismatic`` (n,) bool.
    :meth:`fkine` gives the frames 0..n in the chain base frame, (n+1, 4, 4); frame ``i`` is the
    frame of the link moved by joint ``i``. :meth:`jacobian_at` gives the geometric Jacobian
    (6, n; rows: linear m/s, angular rad/s, chain base frame) of a point moving with frame n
    from those frames. :meth:`joint_placements` says, for a body tree (the MuJoCo model), where
    each frame sits in its parent at q = 0 and where its joint is, in the frame itself.
    """

    name: str
    qlim: np.ndarray
    joint_names: tuple[str, ...]
    """The joints' names, 1..n (a URDF's joint names; ``joint<i>`` otherwise)."""

    @property
    def n(self) -> int: ...

    @property
    def kinds(self) -> tuple[JointKind, ...]: ...

    @property
    def prismatic(self) -> np.ndarray: ...

    def check_q(self, q, *, check_limits: bool = False, tol: float = 1e-9) -> np.ndarray: ...

    def fkine(self, q) -> np.ndarray: ...

    def jacobian(self, q, T_last_tool: np.ndarray | None = None) -> np.ndarray: ...

    def jacobian_at(self, frames: np.ndarray, p_end: np.ndarray) -> np.ndarray: ...

    def joint_axes(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def random_q(self, rng: np.random.Generator) -> np.ndarray: ...

    def joint_placements(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


def check_joint_vector(name: str, qlim: np.ndarray, q, check_limits: bool = False,
                       tol: float = 1e-9) -> np.ndarray:
    """Validate a joint vector for the chain ``name`` with limits ``qlim`` (n, 2): real numbers
    (not words, not complex), length n, finite, and (if asked) inside the limits within
    ``tol``; a :class:`KinematicsError` naming the chain."""
    n = len(qlim)
    if (type(q) is np.ndarray and q.dtype == np.float64 and q.shape == (n,)
            and np.isfinite(q).all() and (not check_limits or (
                (q >= qlim[:, 0] - tol).all() and (q <= qlim[:, 1] + tol).all()))):
        return q  # the control and vision rates' case: a float vector, finite, within limits
    if np.iscomplexobj(q):
        raise KinematicsError(f"{name}: joint values must be real numbers, got complex "
                              f"{short_repr(q)}")
    try:
        q = np.asarray(q, dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        raise KinematicsError(f"{name}: expected {n} joint values (numbers), got "
                              f"{short_repr(q)}") from exc
    if q.shape != (n,):
        raise KinematicsError(f"{name}: expected {n} joint values, got {q.size}")
    bad = np.flatnonzero(~np.isfinite(q))
    if bad.size:
        i = int(bad[0])
        raise KinematicsError(f"{name}: joint {i + 1} is not finite (q[{i}] = {q[i]})")
    if check_limits:
        lo, hi = qlim[:, 0] - tol, qlim[:, 1] + tol
        out = np.flatnonzero((q < lo) | (q > hi))
        if out.size:
            i = int(out[0])
            raise KinematicsError(
                f"{name}: joint {i + 1} = {q[i]:.6g} outside its limits "
                f"[{qlim[i, 0]:.6g}, {qlim[i, 1]:.6g}]"
            )
    return q


@njit(cache=True)
def geometric_jacobian(axes: np.ndarray, origins: np.ndarray, p_end: np.ndarray,
                       prismatic: np.ndarray) -> np.ndarray:
    """Geometric Jacobian (6, n) of the point ``p_end`` (m) from each joint's unit axis and a
    point on it, ``axes`` and ``origins`` (n, 3), all in one frame: rows 0-2 linear velocity,
    3-5 angular; a prismatic joint moves along its axis (a numba kernel: called at the
    control rate)."""
    n = axes.shape[0]
    J = np.empty((6, n))
    for i in range(n):
        x, y, z = axes[i, 0], axes[i, 1], axes[i, 2]
        if prismatic[i]:
            J[0, i], J[1, i], J[2, i] = x, y, z
            J[3, i] = J[4, i] = J[5, i] = 0.0
            continue
        rx, ry, rz = p_end[0] - origins[i, 0], p_end[1] - origins[i, 1], p_end[2] - origins[i, 2]
        J[0, i] = y * rz - z * ry  # axis x (point - origin)
        J[1, i] = z * rx - x * rz
        J[2, i] = x * ry - y * rx
        J[3, i], J[4, i], J[5, i] = x, y, z
    return J


@dataclass(frozen=True)
class DHLink:
    """One DH link: constant parameters (m, rad), joint kind and joint limits ``qlim`` (lo, hi)."""

    a: float = 0.0
    alpha: float = 0.0
    d: float = 0.0
    theta: float = 0.0
    kind: JointKind = "revolute"
    qlim: tuple[float, float] = (-np.pi, np.pi)

    def __post_init__(self) -> None:
        if self.kind not in ("revolute", "prismatic"):
            raise KinematicsError(
                f"DHLink kind must be 'revolute' or 'prismatic', got {self.kind!r}"
            )
        values = (self.a, self.alpha, self.d, self.theta, *self.qlim)
        if not all(np.isfinite(v) for v in values):
            raise KinematicsError(f"DHLink parameters must be finite, got {values}")
        if self.qlim[0] >= self.qlim[1]:
            raise KinematicsError(f"DHLink qlim must be (lo, hi) with lo < hi, got {self.qlim}")

    @property
    def is_prismatic(self) -> bool:
        return self.kind == "prismatic"


class DHChain:
    """A serial chain of :class:`DHLink`.

    >>> chain = DHChain([DHLink(a=1.0), DHLink(a=1.0)])
    >>> chain.fkine([0.0, 0.0])[-1][:3, 3]
    array([2., 0., 0.])
    """

    def __init__(self, links: Sequence[DHLink], name: str = "chain") -> None:
        if len(links) == 0:
            raise KinematicsError(f"{name}: a DH chain needs at least one link")
        self.links = tuple(links)
        self.name = name
        self.joint_names = tuple(f"joint{i}" for i in range(1, len(self.links) + 1))
        self._a = np.array([lk.a for lk in self.links])
        self._alpha = np.array([lk.alpha for lk in self.links])
        self._d = np.array([lk.d for lk in self.links])
        self._theta = np.array([lk.theta for lk in self.links])
        self._prismatic = np.array([lk.is_prismatic for lk in self.links])
        self.qlim = np.array([lk.qlim for lk in self.links], dtype=float)

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.links)

    def check_q(self, q, *, check_limits: bool = False, tol: float = 1e-9) -> np.ndarray:
        """Validate a joint vector: length n, finite, and (if asked) inside the limits."""
        return check_joint_vector(self.name, self.qlim, q, check_limits, tol)

    @property
    def kinds(self) -> tuple[JointKind, ...]:
        return tuple(lk.kind for lk in self.links)

    @property
    def prismatic(self) -> np.ndarray:
        """(n,) bool: which joints are prismatic."""
        return self._prismatic.copy()

    def link_transforms(self, q) -> np.ndarray:
        """The n DH matrices ``A_i(q_i)``, shape (n, 4, 4)."""
        q = self.check_q(q)
        A = np.zeros((self.n, 4, 4))
        for i in range(self.n):
            _dh_matrix(self._a, self._alpha, self._d, self._theta, self._prismatic, q, i, A[i])
        return A

    def fkine(self, q) -> np.ndarray:
        """Poses of frames 0..n in the chain base frame, shape (n+1, 4, 4); frame 0 = identity."""
        q = self.check_q(q)
        out = np.empty((self.n + 1, 4, 4))
        dh_fkine_kernel(self._a, self._alpha, self._d, self._theta, self._prismatic, q, out)
        return out

    def jacobian(self, q, T_last_tool: np.ndarray | None = None) -> np.ndarray:
        """Geometric Jacobian (6, n) of the last frame (or of a tool frame fixed to it), in the
        chain base frame: rows 0-2 linear velocity (m/s), rows 3-5 angular velocity (rad/s)."""
        T = self.fkine(q)
        p_end = T[-1][:3, 3] if T_last_tool is None else (T[-1] @ T_last_tool)[:3, 3]
        return self.jacobian_at(T, p_end)

    def jacobian_at(self, frames: np.ndarray, p_end: np.ndarray) -> np.ndarray:
        """Geometric Jacobian (6, n) of the point ``p_end`` (chain base frame, m) moving with
        the last frame, from the frames (n+1, 4, 4) of :meth:`fkine` (so that a caller that
        needs both pays for one forward kinematics)."""
        return geometric_jacobian(frames[:-1, :3, 2], frames[:-1, :3, 3],
                                  np.asarray(p_end, dtype=float), self._prismatic)

    def joint_axes(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every joint's unit axis and a point on it, (n, 3) each, chain base frame, from the
        frames of :meth:`fkine`: joint i turns about z of frame i-1, through its origin."""
        return frames[:-1, :3, 2].copy(), frames[:-1, :3, 3].copy()

    def random_q(self, rng: np.random.Generator) -> np.ndarray:
        """A uniformly random joint vector inside the limits."""
        return rng.uniform(self.qlim[:, 0], self.qlim[:, 1])

    def joint_placements(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At q = 0: frame i in frame i-1 (``A_i(0)``, (n, 4, 4)), and joint i's origin (m) and
        unit axis in frame i ((n, 3) each): the z axis of frame i-1, written in frame i."""
        A0 = self.link_transforms(np.zeros(self.n))
        pos = np.array([-A[:3, :3].T @ A[:3, 3] for A in A0])
        axis = np.array([A[:3, :3].T[:, 2] for A in A0])
        return A0, pos, axis


@njit(cache=True)
def _dh_matrix(a: np.ndarray, alpha: np.ndarray, d: np.ndarray, theta: np.ndarray,
               prismatic: np.ndarray, q: np.ndarray, i: int, A: np.ndarray) -> None:
    """Link ``i``'s DH matrix ``A_i(q[i])`` (standard DH: ``Rz(theta) Tz(d) Tx(a) Rx(alpha)``,
    the joint adding to ``theta`` or, prismatic, to ``d``) into ``A`` (4, 4, zero below the
    rotation but for ``A[3, 3] = 1``)."""
    th = theta[i] + (0.0 if prismatic[i] else q[i])
    di = d[i] + (q[i] if prismatic[i] else 0.0)
    ct, st, ca, sa = np.cos(th), np.sin(th), np.cos(alpha[i]), np.sin(alpha[i])
    A[0, 0], A[0, 1], A[0, 2], A[0, 3] = ct, -st * ca, st * sa, a[i] * ct
    A[1, 0], A[1, 1], A[1, 2], A[1, 3] = st, ct * ca, -ct * sa, a[i] * st
    A[2, 0], A[2, 1], A[2, 2], A[2, 3] = 0.0, sa, ca, di
    A[3, 0], A[3, 1], A[3, 2], A[3, 3] = 0.0, 0.0, 0.0, 1.0


@njit(cache=True)
def _mul4(X: np.ndarray, Y: np.ndarray, out: np.ndarray) -> None:
    """``out = X @ Y`` for 4x4 matrices, written out (``out`` distinct from both)."""
    for r in range(4):
        for col in range(4):
            acc = 0.0
            for k in range(4):
                acc += X[r, k] * Y[k, col]
            out[r, col] = acc


@njit(cache=True)
def dh_fkine_kernel(a: np.ndarray, alpha: np.ndarray, d: np.ndarray, theta: np.ndarray,
                    prismatic: np.ndarray, q: np.ndarray, out: np.ndarray) -> None:
    """Frames 0..n of a :class:`DHChain` into ``out`` (n+1, 4, 4): ``out[0] = I``,
    ``out[i+1] = out[i] @ A_i(q[i])`` (:func:`_dh_matrix`)."""
    A = np.empty((4, 4))
    out[0] = 0.0
    for k in range(4):
        out[0, k, k] = 1.0
    for i in range(q.shape[0]):
        _dh_matrix(a, alpha, d, theta, prismatic, q, i, A)
        _mul4(out[i], A, out[i + 1])


@njit(cache=True)
def serial_fkine_kernel(origins: np.ndarray, axes: np.ndarray, prismatic: np.ndarray,
                        q: np.ndarray, out: np.ndarray) -> None:
    """Frames 0..n of a :class:`SerialChain` into ``out`` (n+1, 4, 4): ``out[0] = I``,
    ``out[i+1] = out[i] @ origins[i] @ M_i(q[i])`` (Rodrigues' rotation about ``axes[i]``, or a
    translation along it for a prismatic joint)."""
    n = q.shape[0]
    A = np.empty((4, 4))
    M = np.empty((4, 4))
    out[0] = 0.0
    for k in range(4):
        out[0, k, k] = 1.0
    for i in range(n):
        x, y, z = axes[i, 0], axes[i, 1], axes[i, 2]
        M[:] = 0.0
        M[3, 3] = 1.0
        if prismatic[i]:
            M[0, 0] = M[1, 1] = M[2, 2] = 1.0
            M[0, 3], M[1, 3], M[2, 3] = x * q[i], y * q[i], z * q[i]
        else:
            c, s = np.cos(q[i]), np.sin(q[i])
            v = 1.0 - c
            M[0, 0], M[0, 1], M[0, 2] = c + x * x * v, x * y * v - z * s, x * z * v + y * s
            M[1, 0], M[1, 1], M[1, 2] = y * x * v + z * s, c + y * y * v, y * z * v - x * s
            M[2, 0], M[2, 1], M[2, 2] = z * x * v - y * s, z * y * v + x * s, c + z * z * v
        _mul4(origins[i], M, A)
        _mul4(out[i], A, out[i + 1])


class SerialChain:
    """A URDF-style serial chain (module docstring): per joint a fixed ``origin`` (4x4, frame i
    at q = 0 in frame i-1), a unit ``axis`` in frame i, a kind and limits; ``link_names`` names
    frames 0..n (the URDF's links), ``joint_names`` the joints 1..n (the URDF's joints; default
    ``joint1`` .. ``joint<n>``).

    >>> chain = SerialChain(np.eye(4)[None], [[0.0, 0.0, 1.0]], ["revolute"], [(-3.0, 3.0)])
    >>> bool(np.allclose(chain.fkine([np.pi / 2])[-1][:2, 0], [0.0, 1.0]))
    True
    """

    def __init__(self, origins, axes, kinds, qlim, name: str = "chain",
                 link_names: tuple[str, ...] | None = None,
                 joint_names: tuple[str, ...] | None = None) -> None:
        self.origins = np.ascontiguousarray(origins, dtype=float).reshape(-1, 4, 4)
        n = len(self.origins)
        if n == 0:
            raise KinematicsError(f"{name}: a serial chain needs at least one joint")
        axes = np.asarray(axes, dtype=float).reshape(n, 3)
        norms = np.linalg.norm(axes, axis=1)
        if not np.all(np.isfinite(self.origins)) or not np.all(norms > 1e-12):
            raise KinematicsError(f"{name}: origins must be finite and axes non-zero")
        self._axes = np.ascontiguousarray(axes / norms[:, None])
        self._kinds: tuple[JointKind, ...] = tuple(kinds)
        if len(self._kinds) != n or any(k not in ("revolute", "prismatic") for k in self._kinds):
            raise KinematicsError(f"{name}: need {n} joint kinds 'revolute' or 'prismatic', "
                                  f"got {self._kinds}")
        self.qlim = np.array(qlim, dtype=float).reshape(n, 2)
        if not np.all(np.isfinite(self.qlim)) or np.any(self.qlim[:, 0] >= self.qlim[:, 1]):
            raise KinematicsError(f"{name}: joint limits must be finite (lo, hi), lo < hi")
        self._prismatic = np.array([k == "prismatic" for k in self._kinds])
        self.name = name
        self.link_names = tuple(link_names) if link_names else tuple(
            f"link{i}" for i in range(n + 1))
        self.joint_names = tuple(joint_names) if joint_names else tuple(
            f"joint{i}" for i in range(1, n + 1))

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.origins)

    @property
    def kinds(self) -> tuple[JointKind, ...]:
        return self._kinds

    @property
    def prismatic(self) -> np.ndarray:
        """(n,) bool: which joints are prismatic."""
        return self._prismatic.copy()

    @property
    def axes(self) -> np.ndarray:
        """(n, 3) unit joint axes, each in its own frame i."""
        return self._axes.copy()

    def check_q(self, q, *, check_limits: bool = False, tol: float = 1e-9) -> np.ndarray:
        """Validate a joint vector: length n, finite, and (if asked) inside the limits."""
        return check_joint_vector(self.name, self.qlim, q, check_limits, tol)

    def fkine(self, q) -> np.ndarray:
        """Poses of frames 0..n in the chain base frame, shape (n+1, 4, 4); frame 0 = identity."""
        q = self.check_q(q)
        out = np.empty((self.n + 1, 4, 4))
        serial_fkine_kernel(self.origins, self._axes, self._prismatic, q, out)
        return out

    def jacobian(self, q, T_last_tool: np.ndarray | None = None) -> np.ndarray:
        """Geometric Jacobian (6, n) of frame n (or of a tool frame fixed to it), chain base
        frame: rows 0-2 linear velocity (m/s), rows 3-5 angular velocity (rad/s)."""
        T = self.fkine(q)
        p_end = T[-1][:3, 3] if T_last_tool is None else (T[-1] @ T_last_tool)[:3, 3]
        return self.jacobian_at(T, p_end)

    def jacobian_at(self, frames: np.ndarray, p_end: np.ndarray) -> np.ndarray:
        """Geometric Jacobian (6, n) of the point ``p_end`` (chain base frame, m) moving with
        frame n, from the frames (n+1, 4, 4) of :meth:`fkine`."""
        axes, points = self.joint_axes(frames)
        return geometric_jacobian(axes, points, np.asarray(p_end, dtype=float), self._prismatic)

    def joint_axes(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every joint's unit axis and a point on it, (n, 3) each, chain base frame, from the
        frames of :meth:`fkine`: joint i moves along / about its axis in frame i, through
        frame i's origin."""
        return (frames[1:, :3, :3] @ self._axes[:, :, None])[:, :, 0], frames[1:, :3, 3].copy()

    def random_q(self, rng: np.random.Generator) -> np.ndarray:
        """A uniformly random joint vector inside the limits."""
        return rng.uniform(self.qlim[:, 0], self.qlim[:, 1])

    def joint_placements(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At q = 0: frame i in frame i-1 (the joint origins, (n, 4, 4)), and joint i's origin
        (m, the frame's own: zero) and unit axis in frame i ((n, 3) each)."""
        return self.origins.copy(), np.zeros((self.n, 3)), self._axes.copy()
