"""The run loop's view of the cell: a :class:`typing.Protocol` of the few methods it calls, so
that the simulated world (:class:`cellsight.world.World`), a log replay or a real cell can
stand in.

:class:`Plant` is what a real cell offers the controller and the tracker (a clock, joint and
gripper commands, joint measurements, the jaws' opening and closed signal, camera images);
:class:`GroundTruth` is what only a simulator knows, which the run logs next to the estimates
(true poses, true visibility, whether the part is really held). Units: s, m, rad.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Protocol

import numpy as np

from cellsight.session.frames import FrameTruth, PartTruth
from cellsight.visibility import Views

if TYPE_CHECKING:
    from cellsight.world.faults import Faults
    from cellsight.world.grasp import Grasp
    from cellsight.world.truth import RayTruth


class Plant(Protocol):
    """The cell as the controller and the tracker see it."""

    @property
    def time(self) -> float:
        """Time (s) since the start of the run."""
        ...

    def step(self, setpoints: Mapping[str, np.ndarray] | None = None,
             gripper: Mapping[str, float] | None = None) -> None:
        """One control period: robot name -> joint set-point, and -> jaw opening command (m)."""
        ...

    def measured_joints(self) -> dict[str, np.ndarray]:
        """Robot name -> measured joint vector (rad, m)."""
        ...

    def jaw_openings(self) -> dict[str, float]:
        """Robot name -> measured jaw opening (m)."""
        ...

    def jaws_closed_on_part(self, robot: str) -> bool:
        """The gripper's signal: its jaws closed on a part."""
        ...

    def render(self, cameras: Sequence[int] | None = None, *, on_demand: bool = False,
               picture: bool = False) -> list:
        """One image per camera, in the cell's camera order; with ``cameras`` (indices), only
        theirs (None for the others). ``on_demand``: each read when the tracker reads it (an
        :class:`~cellsight.tracking.grabbing.OnDemandImage`, or an image). ``picture``: for a
        picture only, drawing nothing from the random streams the cameras' images use."""
        ...

    def close(self) -> None:
        """Release what the plant holds (renderer, devices)."""
        ...


class GroundTruth(Protocol):
    """What a simulator knows that the tracker must estimate; ``faults``: the faults it plays
    (:class:`~cellsight.world.faults.Faults`: whether a kidnapping moved its part, and a
    knock); ``truth``: its ray-cast truth, whose ``cell.cameras`` are the cameras where they
    truly are (the cell file's moved by the world's calibration errors and a knock)."""

    faults: Faults
    truth: RayTruth

    def true_joints(self) -> dict[str, np.ndarray]:
        """Robot name -> true joint vector (rad, m)."""
        ...

    def true_part_poses(self) -> dict[str, np.ndarray]:
        """Workpiece name -> true ``T_base_part``."""
        ...

    def true_views(self) -> Views:
        """Workpiece name -> what each camera truly sees of it (one view per camera)."""
        ...

    def true_corners(self) -> list[np.ndarray]:
        """Per camera, the pixels (N, 2) of the corners of everything in front of it (where a
        corner extractor could latch on)."""
        ...

    def collisions(self) -> list[dict]:
        """Every contact so far that is not the grasp: bodies, start and end (s), depth (mm)."""
        ...

    def grasp(self, robot: str) -> Grasp | None:
        """The grasp the robot really holds a workpiece with (the part, and the TCP's error
        from its grasp pose when the grasp engaged), or None while it holds nothing."""
        ...


class SimulatedCell(Plant, GroundTruth, Protocol):
    """A plant that also knows the truth: what :class:`~cellsight.experiments.ExperimentRun`
    drives and logs."""


def part_truth(world: GroundTruth, part: str) -> PartTruth:
    """The world's truth now about workpiece ``part``."""
    return PartTruth(world.true_part_poses()[part], world.true_views()[part])


def frame_truth(world: SimulatedCell, part: str, robot: str,
                others: Sequence[str] = ()) -> FrameTruth:
    """The world's truth now about workpiece ``part`` and robot ``robot``, and about the
    workpieces ``others`` (a line's other picks and its passing parts)."""
    poses, views = world.true_part_poses(), world.true_views()
    truths = {name: PartTruth(poses[name], views[name]) for name in {part, *others}}
    return FrameTruth(truths.pop(part), world.true_joints(), world.jaw_openings()[robot],
                      world.jaws_closed_on_part(robot), world.grasp(robot) is not None, truths)
