"""How the simulated cell differs from a perfect one, in numbers the world applies as it runs.

The world's geometry (cameras, robots, gripper and part as built, with their errors) is its own
:class:`~cellsight.model.Cell`; this holds the rest, the errors that act over time or in the
sensors. Every field's default is today's ideal world (:data:`IDEAL`), whose only error is the
joint measurement noise of 1e-4 rad (m for a prismatic joint).

- ``encoder_offsets``: robot name -> per-joint zero offset (rad, m): the encoder reads
  ``q_true + offset``; the servo closes its loop on the reading, so a set-point ``q`` puts the
  joint at ``q - offset``;
- ``quantum_rad`` / ``quantum_m``: encoder resolution (0: none); ``noise_rad`` / ``noise_m``:
  Gaussian measurement noise (standard deviation);
- ``servo``: the joints' position servo (:class:`~cellsight.world.servo.ServoParams`);
- ``grasp_seat``: where the part settles in the jaws when they clamp it, a pose in the TCP frame
  applied to the part's relative pose when the grasp engages; ``slip_m_s``: the part then slides
  along the tool's approach axis (+z) at this speed while held;
- ``intruders``: bodies the cell file does not know (:mod:`cellsight.world.intruders`);
- ``kidnap``: the part moved while every camera is blind, ``knock``: a camera knocked
  (:mod:`cellsight.world.faults`; None: never);
- ``images``: what the camera and grabber do to each image
  (:class:`~cellsight.world.images.ImageEffects`; None: clean renders);
- ``collision_depth_m``: the penetration (m) from which a contact is a collision event
  (None: :attr:`Imperfections.collision_threshold_m`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from cellsight.world.faults import Kidnap, Knock
from cellsight.world.images import ImageEffects
from cellsight.world.intruders import Intruder
from cellsight.world.servo import ServoParams


@dataclass(frozen=True)
class Imperfections:
    """The world's time- and sensor-side errors (module docstring)."""

    encoder_offsets: Mapping[str, np.ndarray] = field(default_factory=dict)
    quantum_rad: float = 0.0
    quantum_m: float = 0.0
    noise_rad: float = 1e-4
    noise_m: float = 1e-4
    servo: ServoParams = ServoParams()
    grasp_seat: np.ndarray = field(default_factory=lambda: np.eye(4))
    slip_m_s: float = 0.0
    intruders: tuple[Intruder, ...] = ()
    kidnap: Kidnap | None = None
    knock: Knock | None = None
    images: ImageEffects | None = None
    collision_depth_m: float | None = None

    @property
    def collision_threshold_m(self) -> float:
        """The penetration (m) from which a contact is an event: ``collision_depth_m`` if
        given; else 0 (any overlap) where MuJoCo's actuators move the joints, as contacts push
        back there, so a touch never grows deep and every overlap is a force; else 1 mm in a
        kinematic world, where solids pass through each other and the meshes' hulls graze."""
        if self.collision_depth_m is not None:
            return self.collision_depth_m
        return 0.0 if self.servo.mujoco else 1e-3


IDEAL = Imperfections()
"""Today's ideal world: exact encoders, an ideal servo, clean images, nothing unknown."""
