"""What one simulated run is asked to be: :class:`RunConfig`, checked when it is made."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from cellsight.errors import CellsightError
from cellsight.export.live import parse_address
from cellsight.export.rosbag import check_jpeg
from cellsight.fields import NamedEnum
from cellsight.realism import Profile
from cellsight.trackers import DEFAULT_TRACKER, TrackerChoice
from cellsight.visibility import OBJECT_BVH, STRUCTURES

if TYPE_CHECKING:
    from cellsight.model.cell import Cell


class Sensor(NamedEnum):
    """What the simulated cameras give the tracker: ``rendered`` (MuJoCo's images, corners
    extracted by OpenCV) or ``ideal`` (the true projections with Gaussian pixel noise). A
    sensor equals, prints and serialises as its name."""

    RENDERED = "rendered"
    IDEAL = "ideal"

    @property
    def takes_images(self) -> bool:
        """Its cameras take images (to extract corners from, record, draw)."""
        return self is Sensor.RENDERED

    def cannot_run(self, cell: Cell, name: str) -> str | None:
        """Why this sensor cannot run ``cell`` (``name``: the cell as the message names it),
        or None: the ideal sensor draws one part, and a line has several picks."""
        picks = cell.picked_workpieces()
        if self is Sensor.IDEAL and len(picks) > 1:
            return f"{name} is a line ({len(picks)} picks) and the ideal sensor sees one part"
        return None


@dataclass(frozen=True)
class RunConfig:
    """One run. ``duration`` (s of simulated time): None runs until the task is done (plus
    ``tail_s``), at most ``max_duration`` for each part picked (a line's picks).
    ``ideal_sigma_px``: pixel noise of the ideal sensor, per coordinate (0.2 px: the rendered
    sensor's corners lie a median 0.245 px from the true projection on the built-in cell, i.e.
    0.21 px per coordinate).
    ``tracker``: the tracker (:class:`~cellsight.trackers.TrackerChoice`). The
    ``kinematic`` one (the default): while the jaws are closed on the part, it predicts it by
    the gripper's motion measured from the joints, and starts it where the gripper holds it (the
    grasp the task chose) when it is not tracked (``holders`` of :meth:`Tracker.step`); until
    the jaws first close on it, the part keeps the height, roll and pitch of the cell file's
    pose of it, lying on its conveyor or table (``supports``), and once they let it go, those
    of where it falls to from the gripper, onto the cell file's static objects; with the
    rendered sensor, the cameras are registered to the gripper at HOME and by the part
    (:mod:`cellsight.tracking.registration`). ``video_every``: a frame of ``views.mp4`` every so
    many vision frames (0: no video). ``full_frames``: the rendered cameras render every frame
    whole, instead of only the region the tracker reads (:mod:`cellsight.world.shots`; the
    same pixels, see :mod:`cellsight.world.render`). ``overwrite``: clear ``out`` first when it
    holds an earlier run (:func:`check_out_folder`; else a non-empty ``out`` is refused).
    ``record``: an MCAP file to record the sensor data in as the run goes
    (:mod:`cellsight.recording.recorder`; the rendered sensor only), its images JPEG of
    quality ``record_jpeg`` (None: lossless); a recorded run renders whole frames, so that the
    tracker reads the very pixels recorded.
    ``live``: ``[HOST:]PORT`` of a Foxglove WebSocket server streaming the run as it happens
    (:mod:`cellsight.export.live`). ``calibration``: a folder of ``cellsight calibrate`` whose
    cameras and robot bases the tracker and the task use instead of the cell file's
    (:mod:`cellsight.calibration.folder`); the world is still the one the seed draws from the
    cell file."""

    experiment: int
    out: Path
    cell: Path | None = None
    seed: int = 0
    sensor: Sensor | str = Sensor.RENDERED
    tracker: TrackerChoice = DEFAULT_TRACKER
    duration: float | None = None
    max_duration: float = 80.0
    tail_s: float = 1.0
    ideal_sigma_px: float = 0.2
    video_every: int = 2
    full_frames: bool = False
    progress: bool = True
    overwrite: bool = False
    realism: str | Path | Profile = "exact"
    structure: str = OBJECT_BVH
    record: Path | None = None
    record_jpeg: int | None = None
    live: str | None = None
    calibration: Path | None = None

    def __post_init__(self) -> None:
        check_jpeg(self.record_jpeg, "--record-jpeg")
        if self.live is not None:
            parse_address(self.live)
        try:
            object.__setattr__(self, "sensor", Sensor(self.sensor))
        except ValueError:
            raise CellsightError(f"RunConfig.sensor: expected one of "
                                 f"{', '.join(s.value for s in Sensor)}, got {self.sensor!r}")\
                from None
        if self.record is not None and not self.sensor.takes_images:
            raise CellsightError("--record: the ideal sensor takes no images to record; use the "
                                 "rendered sensor")
        duration = self.duration
        if duration is not None and not (duration > 0 and math.isfinite(duration)):
            raise CellsightError(f"RunConfig.duration: expected a positive, finite number of "
                                 f"seconds, got {duration!r}")
        if self.seed < 0:
            raise CellsightError(f"RunConfig.seed: expected a whole number >= 0, got {self.seed}")
        if self.structure not in STRUCTURES:
            raise CellsightError(f"RunConfig.structure: expected one of {', '.join(STRUCTURES)}, "
                                 f"got {self.structure!r}")
