"""Run one of the paper's experiments end to end: world, tracker, task, control.

:class:`ExperimentRun` builds the parts and a :class:`~cellsight.session.run.RunSession` runs
them: the simulated cell's frames (:mod:`.simulated`: the world seen through
:class:`~cellsight.experiments.plant.SimulatedCell`, the simulated
:class:`~cellsight.world.World` by default, its grasping task and control) through the
:class:`~cellsight.tracking.Tracker`, into the sinks, in this order: the occlusion events of
``run.log`` (:mod:`cellsight.session.events`), ``frames.csv`` (:mod:`cellsight.session.rows`,
with the PnP baseline of :mod:`cellsight.session.baseline`), with ``live`` a Foxglove WebSocket
stream (:mod:`cellsight.export.live`), with ``record`` an MCAP file of the sensor data as a real
cell records it (:mod:`cellsight.recording.recorder`), ``keyframes.json`` +
``keyframes/*.png`` and ``views.mp4`` (rendered sensor; :mod:`.sinks`). ``metrics.json`` holds
the session's figures, the world's and the task's facts, and the run's: the realism profile and
every draw, the structure, the tracker, the cameras' checks and registration
(:meth:`ExperimentRun.facts`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cellsight.calibration.folder import calibrated_cell, read_calibration
from cellsight.errors import CellsightError
from cellsight.experiments.config import RunConfig
from cellsight.experiments.exposure import Exposures
from cellsight.experiments.identity import run_identity
from cellsight.experiments.monitors import knock_record
from cellsight.experiments.plant import SimulatedCell
from cellsight.experiments.scenario import Scenario, scenario
from cellsight.experiments.sensors import IdealExtractor
from cellsight.experiments.simulated import SimulatedRun, SimulatedSource
from cellsight.experiments.sinks import KeyFramesSink, VideoSink
from cellsight.export.live import LiveSink
from cellsight.export.rosbag import check_output
from cellsight.geometry.transforms import transform_points
from cellsight.model.cell import Cell
from cellsight.model.loader import load_cell
from cellsight.realism import Profile, draw_world
from cellsight.recording.recorder import RecordingSink
from cellsight.runfolder import FrameLog
from cellsight.runfolder.figures import position_rmse_in_arm_frame_mm
from cellsight.runfolder.picks import line_figures, part_log_name
from cellsight.session.baseline import PnPBaseline
from cellsight.session.events import OcclusionEvents
from cellsight.session.protocols import FrameSink
from cellsight.session.rows import FrameRows, FramesCsv
from cellsight.session.run import RunParts, RunSession
from cellsight.tracking.registration import RegistrationRule
from cellsight.tracking.setup import build_tracker, tracker_facts
from cellsight.world import World

log = logging.getLogger(__name__)

class ExperimentRun:
    """One experiment run (module docstring); :meth:`run` does it and returns the metrics.
    ``world``: the cell to run on (default: the simulated world of the scenario); ``sinks``:
    the caller's own, after the run's (:meth:`sinks`). The output folder is checked first
    (:func:`~cellsight.runfolder.check_out_folder`), cleared and created when the run
    starts."""

    def __init__(self, config: RunConfig, world: SimulatedCell | None = None,
                 sinks: Sequence[FrameSink] = ()) -> None:
        self.config, self.own_sinks = config, list(sinks)
        self.session = RunSession(config.out, config.overwrite, config.progress,
                                  ("RunConfig.out", "overwrite=True"))
        if config.record is not None:
            check_output(config.record, config.overwrite, Path(config.out), "--record")
        self.cell: Cell = load_cell(config.cell)
        self.draws = draw_world(config.realism, self.cell, config.seed)  # of the cell file
        if config.calibration is not None:  # the model side: what the calibration found
            self.cell = calibrated_cell(self.cell, config.calibration)
        self.scenario: Scenario = scenario(self.cell, config.experiment, self.draws.scenario)
        sc, cell = self.scenario, self.cell
        self.robot, self.part = sc.robot, sc.workpiece
        refused = config.sensor.cannot_run(cell, cell.source)
        if refused is not None:
            raise CellsightError(f"{refused}; run it with --sensor rendered")
        self.world: SimulatedCell = (
            world if world is not None
            else World(self.draws.cell, seed=config.seed, conveyor=sc.conveyors, tasks=sc.tasks,
                       errors=self.draws.errors))
        ideal = not config.sensor.takes_images
        exposures = Exposures(self.world, self.draws.trigger_skew_s, ideal, self.part.name,
                              config.full_frames or config.record is not None)
        end = (config.duration if config.duration is not None
               else config.max_duration * len(sc.picks))
        self.source = SimulatedSource(
            cell, sc, self.world, exposures, self.draws,
            SimulatedRun(end, config.duration is not None, config.tail_s, config.experiment,
                         f"experiment {config.experiment} ({sc.description}) on {cell.source}; "
                         f"seed {config.seed}; sensor {config.sensor}; "
                         f"{config.tracker.describe()}"),
            config.tracker.kinematic, config.seed)
        register = config.tracker.kinematic and not ideal
        self.tracker = build_tracker(
            cell, config.tracker, structure=config.structure, awaiting_registration=register,
            extractor=IdealExtractor(config.ideal_sigma_px, config.seed) if ideal else None)
        self.registration = (RegistrationRule().registration(cell, self.robot.name)
                             if register else None)

    def sinks(self) -> list[FrameSink]:
        """The run's sinks, in the order each frame's record reaches them; the caller's
        last."""
        cfg = self.config
        rows = FrameRows(self.robot, len(self.cell.cameras), cfg.sensor.takes_images)
        names = [p.name for p in self.scenario.picks]  # each pick's log, the first's frames.csv
        logged = self.scenario.picks + self.scenario.passing  # and each passing part's
        sinks: list[FrameSink] = [OcclusionEvents()] + [
            FramesCsv(rows, PnPBaseline.of(self.tracker, p.feature_points), p.name,
                      part_log_name(names, p.name), names) for p in logged]
        if cfg.live is not None:
            sinks.append(LiveSink(cfg.live))
        if cfg.record is not None:
            sinks.append(RecordingSink(cfg.record, cfg.record_jpeg))
        sinks.append(KeyFramesSink(next(iter(self.scenario.tasks), None)))
        if cfg.sensor.takes_images and cfg.video_every > 0:
            sinks.append(VideoSink(cfg.video_every))
        return sinks + self.own_sinks

    def run(self) -> dict:
        """Run the experiment; write everything; return the metrics (see
        :class:`~cellsight.session.run.RunSession`: a signal ends the run at the next frame,
        an exception is recorded and then propagates, a failed write is raised at the end)."""
        parts = RunParts(self.source, self.tracker, self.sinks(), self.registration, self.facts)
        return self.session.run(parts)

    def facts(self, frames: FrameLog) -> dict:
        """The run's facts for ``metrics.json``: how it was asked for (the experiment, seed,
        sensor, tracker, structure, realism and every draw, the calibration), the cameras'
        checks and registration, and the arm's own error where the cameras were registered
        to it."""
        cfg = self.config
        return {
            "experiment": cfg.experiment,
            "identity": run_identity(cfg),
            "calibration_folder": None if cfg.calibration is None else str(cfg.calibration),
            "calibration_errors": (None if cfg.calibration is None
                                   else read_calibration(cfg.calibration).get("errors")),
            "seed": cfg.seed,
            "sensor": cfg.sensor,
            **tracker_facts(cfg.tracker),
            "structure": cfg.structure,
            "realism": self.draws.profile.name,
            "realism_file": self.draws.profile.file,
            "realism_spec": None if isinstance(cfg.realism, Profile) else str(cfg.realism),
            "draws": self.draws.record,
            "cameras_dropped": {self.cell.cameras[c].name: round(t, 4)
                                for c, t in self.tracker.camera_check.dropped.items()},
            "knock": self._knock(),
            "registration": self._registration(),
            **_arm_error(self._home_error(), frames),
            **self._line(),
        }

    def _home_error(self) -> np.ndarray | None:
        """Where the cameras are registered to the grasping arm, the world's truth of that
        arm's own error at HOME (its TCP there less where its model puts it, m, base frame);
        None otherwise."""
        if self.registration is None or self.robot.home is None:
            return None
        return self.draws.tcp_error(self.robot, self.robot.home)

    def _line(self) -> dict:
        """A line's ``picks`` (None for one part), in order: each part, whether it was held
        when its Manipulate began (None: its turn never came that far), its failed grasp
        checks, and its figures from its own frame log; and its ``passing`` parts (None for
        none), each with its figures and when it entered and left the views
        (:func:`~cellsight.runfolder.picks.line_figures`)."""
        picks = [p.name for p in self.scenario.picks]
        passing = [p.name for p in self.scenario.passing]
        if len(picks) + len(passing) == 1:
            return {"picks": None, "passing": None}
        figures = line_figures(Path(self.config.out), picks, self._home_error(), passing)
        held, tasks = self.source.grasp.held, self.source.task.tasks
        return {
            "picks": [{"part": name, "picked": held[k] if k < len(held) else None,
                       "failed_grasp_checks": tasks[k].attempts if k < len(tasks) else 0,
                       **figures[name]} for k, name in enumerate(picks)],
            "passing": [{"part": name, **figures[name]} for name in passing] or None,
        }

    def _knock(self) -> dict | None:
        """The knocked camera's figures (:func:`~.monitors.knock_record`), if any."""
        knock = self.draws.errors.knock
        if knock is None:
            return None
        check = self.tracker.camera_check
        points = transform_points(self.part.T_base_part, self.part.feature_points)
        return knock_record(knock, check.dropped, check.recovered, self.cell.cameras,
                            self.world.truth.cell.cameras, points)

    def _registration(self) -> dict | None:
        """Each camera's registration to the gripper (:mod:`cellsight.tracking.registration`),
        for ``metrics.json``: its latest offset, its corners, when and where it was made
        (``home``, ``part``), its offset at HOME and the true camera's offset at the part's
        nominal pose (the median, over its feature points, of the true camera's pixel less the
        cell file's camera's, px)."""
        if self.registration is None:
            return None
        out = self.registration.record()
        points = transform_points(self.part.T_base_part, self.part.feature_points)
        for cam, true_cam in zip(self.cell.cameras, self.world.truth.cell.cameras, strict=True):
            gap = true_cam.project(points) - cam.project(points)
            out[cam.name]["true_offset_px"] = np.round(np.median(gap, axis=0), 3).tolist()
        return out


def _arm_error(error: np.ndarray | None, frames: FrameLog) -> dict:
    """The grasping arm's own ``error`` at HOME (m, :meth:`ExperimentRun._home_error`) as
    ``arm_home_error_mm`` (mm, base frame), and the position RMSE against the part's true
    positions moved by it (``position_rmse_arm_mm``:
    :func:`~cellsight.runfolder.figures.position_rmse_in_arm_frame_mm`); both None without
    it."""
    if error is None:
        return {"arm_home_error_mm": None, "position_rmse_arm_mm": None}
    return {"arm_home_error_mm": np.round(error * 1e3, 3).tolist(),
            "position_rmse_arm_mm": position_rmse_in_arm_frame_mm(frames, error)}


def run_experiment(config: RunConfig) -> dict:
    """Run one experiment (see :class:`ExperimentRun`) and return its metrics."""
    return ExperimentRun(config).run()
