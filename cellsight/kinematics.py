"""Denavit–Hartenberg forward kinematics and the geometric Jacobian.

Standard (distal) DH: ``A_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``. A revolute joint adds
``q_i`` to ``theta_i``, a prismatic joint adds ``q_i`` to ``d_i``. Lengths in metres, angles in
radians. Frame 0 is the chain base; frame ``i`` is attached to link ``i``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from cellsight.errors import KinematicsError

JointKind = Literal["revolute", "prismatic"]


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
        q = np.asarray(q, dtype=float).ravel()
        if q.shape != (self.n,):
            raise KinematicsError(f"{self.name}: expected {self.n} joint values, got {q.size}")
        bad = np.flatnonzero(~np.isfinite(q))
        if bad.size:
            i = int(bad[0])
            raise KinematicsError(f"{self.name}: joint {i + 1} is not finite (q[{i}] = {q[i]})")
        if check_limits:
            lo, hi = self.qlim[:, 0] - tol, self.qlim[:, 1] + tol
            out = np.flatnonzero((q < lo) | (q > hi))
            if out.size:
                i = int(out[0])
                raise KinematicsError(
                    f"{self.name}: joint {i + 1} = {q[i]:.6g} outside its limits "
                    f"[{self.qlim[i, 0]:.6g}, {self.qlim[i, 1]:.6g}]"
                )
        return q

    def link_transforms(self, q) -> np.ndarray:
        """The n DH matrices ``A_i(q_i)``, shape (n, 4, 4)."""
        q = self.check_q(q)
        theta = self._theta + np.where(self._prismatic, 0.0, q)
        d = self._d + np.where(self._prismatic, q, 0.0)
        ct, st = np.cos(theta), np.sin(theta)
        ca, sa = np.cos(self._alpha), np.sin(self._alpha)
        A = np.zeros((self.n, 4, 4))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st * ca, st * sa, self._a * ct
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st, ct * ca, -ct * sa, self._a * st
        A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa, ca, d
        A[:, 3, 3] = 1.0
        return A

    def fkine(self, q) -> np.ndarray:
        """Poses of frames 0..n in the chain base frame, shape (n+1, 4, 4); frame 0 = identity."""
        A = self.link_transforms(q)
        T = np.empty((self.n + 1, 4, 4))
        T[0] = np.eye(4)
        for i in range(self.n):
            T[i + 1] = T[i] @ A[i]
        return T

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
        z = frames[:-1, :3, 2].T  # joint axes, (3, n)
        r = p_end[:, None] - frames[:-1, :3, 3].T  # joint origin -> point, (3, n)
        J = np.empty((6, self.n))
        J[0] = z[1] * r[2] - z[2] * r[1]  # z x r, written out: np.cross costs ten times more
        J[1] = z[2] * r[0] - z[0] * r[2]
        J[2] = z[0] * r[1] - z[1] * r[0]
        J[3:] = z
        J[:3, self._prismatic] = z[:, self._prismatic]
        J[3:, self._prismatic] = 0.0
        return J

    def random_q(self, rng: np.random.Generator) -> np.ndarray:
        """A uniformly random joint vector inside the limits."""
        return rng.uniform(self.qlim[:, 0], self.qlim[:, 1])
