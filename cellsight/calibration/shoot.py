"""The calibration motion in the simulated world: the robot carries the board through the
planned poses, each camera photographs it at every pose, the encoders are read.

Only what a real cell gives is kept: the images' detected board corners and the joints as the
encoders read them (offsets, resolution, noise). Between poses the robot moves along a
straight line in joint space with a quintic time law (zero velocity and acceleration at both
ends), no joint faster than ``speed`` (rad/s, m/s for a prismatic joint), then stands still
for ``settle_s`` before the cameras are triggered, as a calibration routine waits for the arm
to settle. The world is the seed's (its cameras, robots, servo, images and noise), without
the faults and unmodelled bodies of its profile: a calibration is done in a cleared cell.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from cellsight.calibration.solution import View
from cellsight.world import World

MIN_CORNERS = 6  # a view with fewer detected corners is dropped (solvePnP needs 4, with margin)


@dataclass(frozen=True)
class Motion:
    """How the robot moves between poses: joint ``speed`` (rad/s or m/s) and ``settle_s``."""

    speed: float = 0.5
    settle_s: float = 0.8


class MotionLog(Protocol):
    """What takes down the motion as a cell's recorder would (``calibrate --record``)."""

    def settled(self, world: World) -> None:
        """Halfway through the settling, before the shot: the encoders, read."""

    def shot(self, world: World, joints: dict[str, np.ndarray],
             images: list[np.ndarray]) -> None:
        """At the shot: every robot's ``joints`` as the encoders read them, and every camera's
        image."""


def _quintic(s: np.ndarray) -> np.ndarray:
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


def move(world: World, robot: str, q_from: np.ndarray, q_to: np.ndarray,
         motion: Motion, halfway: Callable[[], None] | None = None) -> None:
    """Drive ``robot`` from ``q_from`` to ``q_to`` (encoder terms) and let it settle;
    ``halfway`` is called halfway through the settling."""
    span = float(np.max(np.abs(q_to - q_from))) / motion.speed
    steps = max(int(np.ceil(1.875 * span / world.dt_control)), 1)  # quintic peak speed 1.875x
    for s in _quintic(np.arange(1, steps + 1) / steps):
        world.step({robot: q_from + (q_to - q_from) * s})
    settle = int(np.ceil(motion.settle_s / world.dt_control))
    for step in range(settle):
        if step == settle // 2 and halfway is not None:
            halfway()
        world.step({robot: q_to})


def photograph(world: World, robot: str, joints: np.ndarray, detect: Callable,
               motion: Motion = Motion(), start: np.ndarray | None = None,
               tick: Callable[[], None] | None = None,
               log: MotionLog | None = None) -> list[View]:
    """Every camera's view of the board at each pose ``joints`` (P, n) of ``robot``, in order,
    from ``start`` (default: where the encoders read it now); ``detect(gray) -> (ids,
    pixels)``; ``tick`` is called after each pose (a progress bar), ``log`` takes the motion
    down. A view with fewer than ``MIN_CORNERS`` corners is left out."""
    views: list[View] = []
    q = world.measured_joints()[robot] if start is None else np.asarray(start, dtype=float)
    halfway = None if log is None else (lambda: log.settled(world))
    for pose, target in enumerate(np.asarray(joints, dtype=float)):
        move(world, robot, q, target, motion, halfway)
        q = target
        encoders = world.measured_joints()
        read = encoders[robot]
        images = world.render()
        if log is not None:
            log.shot(world, encoders, images)
        for camera, image in enumerate(images):
            ids, pixels = detect(image)
            if len(ids) >= MIN_CORNERS:
                views.append(View(camera, robot, pose, read, ids, pixels))
        if tick is not None:
            tick()
    return views
