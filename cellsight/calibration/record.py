"""``cellsight calibrate --record FILE``: the calibration motion in the simulated world written
as a real cell records it, for ``cellsight calibrate FILE`` (:mod:`.recorded`) to calibrate
from, as it would from a real cell's recording.

An MCAP file of ROS 2 messages, the topics and conventions of ``cellsight run --record``
(:class:`~cellsight.recording.recorder.Recorder`): ``/joint_states`` (every robot's joints as
the encoders read them, ``<robot>/<joint>``, and the jaw openings of the robots that keep
their gripper) at each robot's start, halfway through each settling and at each shot; each
camera's image (mono8, or JPEG of a quality) and its ``camera_info`` (the cell file's) at each
shot. A real calibration routine records the same: the robot stands still a moment before the
cameras are triggered, and the joint states show it. Each robot's turn starts
:data:`GAP_S` after the last one ends, on one clock. No true pose is recorded; the
``cellsight`` metadata names the world (realism profile and seed) so that a calibration from
the file can be scored against that world's truth afterwards.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellsight.model import Cell
from cellsight.recording.recorder import Recorder
from cellsight.world import World

GAP_S = 1.0
"""Seconds between one robot's last shot and the next robot's start."""
EPOCH_S = 1_700_000_000.0
"""The recording's clock at the first robot's start (s from the Unix epoch)."""


class MotionRecorder:
    """Takes the calibration motion down into ``path`` (module docstring); ``jpeg``: the
    images' JPEG quality (None: lossless mono8)."""

    def __init__(self, path: Path, cell: Cell, world: dict[str, str],
                 jpeg: int | None = None) -> None:
        part = cell.workpieces[0].name if cell.workpieces else "none"
        self._recorder = Recorder(Path(path), cell, part, jpeg)
        self._world = world
        self._offset = EPOCH_S
        self._last = EPOCH_S - GAP_S

    def _t(self, world: World) -> float:
        return self._offset + world.time

    def start(self, world: World) -> None:
        """A robot's turn begins in ``world`` (its clock from 0): the joints where it stands."""
        self._offset = self._last + GAP_S - world.time
        self._recorder.joints(self._t(world), world.measured_joints(), world.jaw_openings())

    def settled(self, world: World) -> None:
        self._recorder.joints(self._t(world), world.measured_joints(), world.jaw_openings())

    def shot(self, world: World, joints: dict[str, np.ndarray],
             images: list[np.ndarray]) -> None:
        t = self._last = self._t(world)
        self._recorder.frame(t, images, None, joints, world.jaw_openings(), None)

    def close(self, complete: bool) -> None:
        """Finish the file and give it its name."""
        self._recorder.close(complete, {"motion": "cellsight calibrate", **self._world})
