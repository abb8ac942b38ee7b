"""Run one of the paper's experiments end to end: world, tracker, task, control.

Per vision frame (26 Hz): the world's images (or, for the ideal sensor, the true projections)
and joint measurements -> :class:`~cellsight.tracking.Tracker` (BSP occlusion prediction at
the predicted pose, selection, windows, extraction, EKF) -> the grasping task's trajectory
planner; between frames, the 500 Hz control loop (interpolating filter + CLIK) drives the
world. Everything is written into the output directory as the run goes:

- ``frames.csv`` (:mod:`cellsight.experiments.framelog`), ``run.log`` (phase transitions,
  occlusion events, summary), ``keyframes.json`` + ``keyframes/*.png`` (camera views with
  overlays at the key moments), ``views.mp4`` (rendered sensor);
- at the end (also when interrupted): ``metrics.json``
  (:mod:`cellsight.experiments.metrics` plus the run's facts) and ``report.html``.
"""

from __future__ import annotations

import json
import logging
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from rich.progress import BarColumn, Progress, TextColumn

from cellsight.control import GraspTask, Phase
from cellsight.experiments.framelog import STAGES, WRONG_PX, FrameLog, bits, read_frames
from cellsight.experiments.metrics import frame_metrics
from cellsight.experiments.scenario import Scenario, scenario
from cellsight.experiments.sensors import FramePredictor, IdealExtractor
from cellsight.geometry.transforms import xyz_rpy_from_pose
from cellsight.model.cell import Cell
from cellsight.model.loader import load_cell
from cellsight.occlusion.predictor import VisibilityPredictor
from cellsight.occlusion.projection import ProjectionOnly
from cellsight.report.overlay import compose_views, draw_camera_overlay
from cellsight.report.run_report import write_report
from cellsight.report.video import VideoWriter
from cellsight.tracking import Observation, PartFrame, Tracker, estimate_pose, undistort_pixels
from cellsight.world import World
from cellsight.world.grasp import grasp_error

log = logging.getLogger(__name__)

Sensor = Literal["rendered", "ideal"]
ESTIMATED = ("acquired", "tracking", "predicting")  # tracker states with a usable estimate


@dataclass(frozen=True)
class RunConfig:
    """One run. ``duration`` (s of simulated time): None runs until the task is done (plus
    ``tail_s``), at most ``max_duration``. ``ideal_sigma_px``: pixel noise of the ideal
    sensor, per coordinate (0.2 px: the rendered sensor's corners lie a median 0.245 px from
    the true projection on the built-in cell, i.e. 0.21 px per coordinate).
    ``kinematic_prior``: while the jaws are closed on the part, the tracker predicts it by the
    gripper's motion measured from the joints (``holders`` of :meth:`Tracker.step`).
    ``video_every``: a frame of ``views.mp4`` every so many vision frames."""

    experiment: int
    out: Path
    cell: Path | None = None
    seed: int = 0
    sensor: Sensor = "rendered"
    occlusion_prediction: bool = True
    kinematic_prior: bool = False
    duration: float | None = None
    max_duration: float = 80.0
    tail_s: float = 1.0
    ideal_sigma_px: float = 0.2
    video_every: int = 2
    progress: bool = True


class _KeyMoments:
    """The frames worth a picture: each key has a score per frame; the best frame so far is
    drawn and saved (``keyframes/<key>.png``, listed in ``keyframes.json``)."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.folder = out / "keyframes"
        self.folder.mkdir(parents=True, exist_ok=True)
        self.best: dict[str, dict] = {}

    def offer(self, key: str, score: float, t: float, caption: str,
              draw: Callable[[str], np.ndarray]) -> None:
        """Keep this frame for ``key`` if it beats the best so far (``score`` > 0)."""
        if score <= 0 or score <= self.best.get(key, {}).get("score", 0):
            return
        cv2.imwrite(str(self.folder / f"{key}.png"), cv2.cvtColor(draw(caption), cv2.COLOR_RGB2BGR))
        self.best[key] = {"name": key, "t": round(t, 3), "caption": caption,
                          "file": f"keyframes/{key}.png", "score": score}
        ordered = sorted(self.best.values(), key=lambda k: k["t"])
        (self.out / "keyframes.json").write_text(json.dumps(ordered, indent=1))


class ExperimentRun:
    """One experiment run (module docstring); :meth:`run` does it and returns the metrics."""

    def __init__(self, config: RunConfig) -> None:
        self.config = config
        self.cell: Cell = load_cell(config.cell)
        self.scenario: Scenario = scenario(self.cell, config.experiment)
        self.out = Path(config.out)
        self.out.mkdir(parents=True, exist_ok=True)
        sc, cell = self.scenario, self.cell
        self.robot, self.part = sc.robot, sc.workpiece
        self.world = World(cell, seed=config.seed, conveyor=sc.conveyor, tasks=sc.tasks)
        source = VisibilityPredictor(cell) if config.occlusion_prediction else ProjectionOnly(cell)
        self.predictor = FramePredictor(source)
        self.ideal = (IdealExtractor(config.ideal_sigma_px, config.seed)
                      if config.sensor == "ideal" else None)
        self.tracker = Tracker.from_cell(cell, self.predictor, self.ideal)
        self.task = GraspTask(self.robot, self.part)
        self.cameras = cell.cameras
        self.labels = {o.name: o.label for o in cell.objects}
        self.crossing = next(iter(sc.tasks), None)
        self._pnp: tuple[float, np.ndarray] | None = None  # (t, T_base_part) of the last fix
        self._events: dict[int, tuple] = {}
        self._grasp_error_mm: float | None = None
        self._held_at_manipulate = False

    # --- per frame ------------------------------------------------------------------------------

    def _truth(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[list[str]]]:
        """True part pose, pixels (C, F, 2), visibility (C, F) and occluder labels."""
        T = self.world.true_part_poses()[self.part.name]
        points = self.part.feature_points @ T[:3, :3].T + T[:3, 3]
        pixels = np.stack([cam.project(points) for cam in self.cameras])
        visible = np.array(self.world.true_visibility()[self.part.name])
        occluders = [
            ["self" if o == self.part.name else self.labels.get(o, o) for o in per_cam]
            for per_cam in self.world.true_occluders()[self.part.name]
        ]
        return T, pixels, visible, occluders

    def _pnp_baseline(self, t: float, rec: PartFrame) -> np.ndarray | None:
        """Per-frame multi-camera PnP on this frame's measurements; a frame with too few holds
        the last fix for at most the tracker's ``lost_after_s``."""
        obs = []
        for c, cam in enumerate(self.cameras):
            ids = np.flatnonzero(np.all(np.isfinite(rec.measured[c]), axis=1))
            if len(ids):
                obs.append(Observation(self.tracker.models[c], c, ids,
                                       self.part.feature_points[ids],
                                       undistort_pixels(cam, rec.measured[c, ids])))
        fix = estimate_pose(obs, sigma_px=self.tracker.config.sigma_px) if obs else None
        if fix is not None:
            self._pnp = (t, fix.T_base_part)
        if self._pnp is None or t - self._pnp[0] > self.tracker.config.lost_after_s:
            return None
        return self._pnp[1]

    def _log_occlusions(self, t: float, reasons: list[list[str]]) -> None:
        """A line in the log (predicted visibility) whenever the set of what hides the part
        from a camera changes, or the count of visible points crosses 3 or 1."""
        for c, per_feature in enumerate(reasons):
            hidden = Counter(r for r in per_feature if r)
            n_visible = sum(1 for r in per_feature if not r)
            state = (frozenset(hidden), min(n_visible, 3), n_visible == 0)
            if self._events.get(c) == state:
                continue
            self._events[c] = state
            text = ", ".join(f"{label} {n}" for label, n in sorted(hidden.items()))
            log.info("t=%6.2f s %-10s %s: %d/%d visible%s", t, self.task.phase,
                     self.cameras[c].name, n_visible, len(per_feature),
                     f"; hidden: {text}" if text else "")

    def _row(self, t: float, frame, rec: PartFrame, truth, pnp, reasons) -> dict:
        T_true, pixels, visible, occluders = truth
        row: dict[str, object] = {"t": round(t, 5), "phase": str(self.task.phase),
                                  "stage": self.task.stage, "status": rec.status}
        estimate = rec.T_base_part if rec.status in ESTIMATED else None
        for prefix, T in (("true", T_true), ("est", estimate), ("pnp", pnp)):
            if T is not None:
                xyz, rpy = xyz_rpy_from_pose(T)
                row.update(zip([f"{prefix}_{a}" for a in ("x", "y", "z")], xyz, strict=True))
                row.update(zip([f"{prefix}_{a}" for a in ("roll", "pitch", "yaw")], rpy,
                               strict=True))
        name = self.robot.name
        tcp = self.robot.tcp_pose(self.world.true_joints()[name])[:3, 3]
        row.update(gripper_x=tcp[0], gripper_y=tcp[1], gripper_z=tcp[2],
                   jaw_opening=self.world.jaw_openings()[name],
                   jaws_closed=int(self.world.jaws_closed_on_part(name)),
                   grasped=int(self.world.grasped(name)))
        for c in range(len(self.cameras)):
            k = c + 1
            measured = np.all(np.isfinite(rec.measured[c]), axis=1)
            err = np.linalg.norm(rec.measured[c, measured] - pixels[c, measured], axis=1)
            wrong = np.zeros_like(measured)
            wrong[measured] = ~(err <= WRONG_PX)
            plan = rec.windows[c]
            row.update({
                f"vis_pred_c{k}": bits(rec.visible[c]), f"vis_true_c{k}": bits(visible[c]),
                f"sel_c{k}": bits(rec.selected[c]), f"meas_c{k}": bits(measured),
                f"rej_c{k}": bits(rec.rejected[c]), f"wrong_c{k}": bits(wrong),
                f"occ_pred_c{k}": ";".join(reasons[c]),
                f"occ_true_c{k}": ";".join(occluders[c]),
                f"grab_c{k}": 0.0 if plan is None else plan.fraction,
                f"err_px_c{k}": (float(np.median(err))
                                 if len(err) and self.ideal is None else None),
            })
        times = frame.timings
        ms = {s: 1e3 * times.get(s, 0.0) for s in STAGES}
        ms["ekf"] = 1e3 * (times["predict"] + times["update"])
        row.update({f"t_{s}_ms": round(v, 4) for s, v in ms.items()})
        return row

    def _draw(self, images, rec: PartFrame, visible_true: np.ndarray, caption: str,
              scale: float) -> np.ndarray:
        if images is None:
            images = self.world.render()
        views = []
        for c, cam in enumerate(self.cameras):
            plan = rec.windows[c]
            views.append(draw_camera_overlay(
                images[c], pixels=rec.pixels[c], visible=rec.visible[c],
                selected=rec.selected[c], measured=rec.measured[c], rejected=rec.rejected[c],
                boxes=np.zeros((0, 4), int) if plan is None else plan.boxes, title=cam.name,
                truth_visible=visible_true[c]))
        return compose_views(views, scale=scale, caption=caption)

    def _offer_key_moments(self, keys: _KeyMoments, t: float, images, rec: PartFrame,
                           reasons: list[list[str]], visible_true: np.ndarray) -> None:
        if rec.status not in ESTIMATED:
            return
        phase = str(self.task.phase)

        def draw(caption: str) -> np.ndarray:
            return self._draw(images, rec, visible_true, caption, 1.0)

        def counts(prefix: str) -> list[int]:
            return [sum(r.startswith(prefix) for r in per_cam) for per_cam in reasons]

        head = f"t = {t:.2f} s, {phase}"
        self_hidden = counts("self")
        if "start" not in keys.best:
            keys.offer("start", 1, t, f"{head}: first estimate; self-occluded points: "
                       + ", ".join(f"{cam.name} {n}" for cam, n in
                                   zip(self.cameras, self_hidden, strict=True)), draw)
        gripper = counts(f"{self.robot.name}.gripper")
        if phase == Phase.GRASP:
            keys.offer("gripper", sum(gripper), t, f"{head}: the gripper hides "
                       + ", ".join(f"{n} points from {cam.name}" for cam, n in
                                   zip(self.cameras, gripper, strict=True)), draw)
        if self.crossing is not None:
            for c, n in enumerate(counts(f"{self.crossing}.")):
                left = sum(1 for r in reasons[c] if not r)
                keys.offer(f"crossing_{self.cameras[c].name}", n, t,
                           f"{head}: {self.crossing} hides {n} points from "
                           f"{self.cameras[c].name}, {left} visible", draw)

    # --- the run ----------------------------------------------------------------------------

    def run(self) -> dict:
        """Run the experiment; write everything; return the metrics (also on Ctrl-C)."""
        cfg = self.config
        handler = logging.FileHandler(self.out / "run.log", mode="w")
        handler.setFormatter(logging.Formatter("%(message)s"))
        root = logging.getLogger("cellsight")
        root.addHandler(handler)
        root.setLevel(logging.INFO)
        frames = FrameLog(self.out / "frames.csv", len(self.cameras))
        video = None
        if cfg.sensor == "rendered" and cfg.video_every > 0:
            video = VideoWriter(self.out / "views.mp4", fps=26.0 / cfg.video_every)
        keys = _KeyMoments(self.out)
        wall = time.perf_counter()
        interrupted = True
        log.info("experiment %d (%s) on %s; seed %d; sensor %s; occlusion prediction %s%s",
                 cfg.experiment, self.scenario.description, self.cell.source, cfg.seed,
                 cfg.sensor, "on" if cfg.occlusion_prediction else "off",
                 "; kinematic prior on" if cfg.kinematic_prior else "")
        try:
            self._loop(frames, video, keys)
            interrupted = False
        finally:
            frames.close()
            if video is not None:
                video.close()
            self.world.close()
            metrics = self._metrics(time.perf_counter() - wall, interrupted)
            root.removeHandler(handler)
            handler.close()
            write_report(self.out)
        return metrics

    def _loop(self, frames: FrameLog, video: VideoWriter | None, keys: _KeyMoments) -> None:
        cfg, world, task, name = self.config, self.world, self.task, self.robot.name
        end = cfg.duration if cfg.duration is not None else cfg.max_duration
        done_at = None
        k = 0
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                      TextColumn("t = {task.completed:5.1f} / {task.total:.0f} s"),
                      TextColumn("{task.fields[phase]:>10}"),
                      disable=not cfg.progress, transient=False) as progress:
            bar = progress.add_task(f"experiment {cfg.experiment}", total=end, phase="")
            while True:
                t = world.time
                if t > end + 1e-9 or (done_at is not None and t >= done_at + cfg.tail_s):
                    break
                self._vision_frame(k, t, frames, video, keys)
                k += 1
                if done_at is None and task.phase in (Phase.DONE, Phase.FAILED):
                    done_at = t
                progress.update(bar, completed=min(t, end), phase=str(task.phase))
                next_frame = k / 26.0
                while world.time < next_frame - 1e-9:
                    q, opening = task.step_control(world.time, world.measured_joints()[name])
                    world.step({name: q}, {name: opening})
                    self._watch_grasp()

    def _vision_frame(self, k: int, t: float, frames: FrameLog, video, keys) -> None:
        world, name = self.world, self.robot.name
        joints = world.measured_joints()
        self.predictor.openings = world.jaw_openings()
        truth = self._truth()
        images = world.render() if self.config.sensor == "rendered" else None
        if self.ideal is not None:
            self.ideal.set_truth(truth[1], truth[2])
        holders = None
        if self.config.kinematic_prior and world.jaws_closed_on_part(name):
            holders = {self.part.name: self.robot.tcp_pose(joints[name])}
        frame = self.tracker.step(images, joints, t, holders)
        rec = frame.parts[self.part.name]
        pose = rec.T_base_part if rec.status in ESTIMATED else None
        velocity = None if pose is None else rec.state[6:9]
        before = self.task.phase
        self.task.update_vision(t, pose, joints[name], world.jaws_closed_on_part(name), velocity)
        if before == Phase.GRASP and self.task.phase == Phase.MANIPULATE:
            self._held_at_manipulate = world.grasped(name)
        reasons = [v.reason for v in self.predictor.last[self.part.name]]
        self._log_occlusions(t, reasons)
        pnp = self._pnp_baseline(t, rec)
        frames.write(self._row(t, frame, rec, truth, pnp, reasons))
        self._offer_key_moments(keys, t, images, rec, reasons, truth[2])
        if video is not None and k % self.config.video_every == 0:
            caption = f"t = {t:5.2f} s   {self.task.phase}   tracker: {rec.status}"
            video.add(self._draw(images, rec, truth[2], caption, 0.5))

    def _watch_grasp(self) -> None:
        """Record the TCP's error from the part's grasp pose when the grasp engages."""
        name = self.robot.name
        if self._grasp_error_mm is None and self.world.grasped(name):
            T_tcp = self.robot.tcp_pose(self.world.true_joints()[name])
            T_grasp = (self.world.true_part_poses()[self.part.name]
                       @ self.world.grasp_pose(self.part.name))
            position, angle = grasp_error(T_tcp, T_grasp)
            self._grasp_error_mm = 1e3 * position
            log.info("t=%6.2f s grasp engaged: TCP %.1f mm, %.1f deg from the grasp pose",
                     self.world.time, self._grasp_error_mm, np.degrees(angle))

    def _metrics(self, wall_s: float, interrupted: bool) -> dict:
        cfg = self.config
        rows = list(read_frames(self.out / "frames.csv"))
        t_end = float(rows[-1]["t"]) if rows else 0.0
        metrics = {
            "experiment": cfg.experiment,
            "description": self.scenario.description,
            "cell": self.cell.source,
            "seed": cfg.seed,
            "sensor": cfg.sensor,
            "occlusion_prediction": cfg.occlusion_prediction,
            "kinematic_prior": cfg.kinematic_prior,
            "grasp_success": bool(self._held_at_manipulate),
            "grasp_position_error_mm": self._grasp_error_mm,
            "final_phase": str(self.task.phase),
            "failed_grasp_checks": self.task.attempts,
            **frame_metrics(rows, len(self.cameras)),
            "wall_s": round(wall_s, 2),
            "interrupted": interrupted,
            "cameras": [c.name for c in self.cameras],
            "features": len(self.part.feature_points),
            "robot": self.robot.name,
            "workpiece": self.part.name,
            "crossing_robot": self.crossing,
            "phase_intervals": [[str(p), round(a, 3), round(b, 3)]
                       for p, a, b in self.task.phase_intervals(t_end)],
        }
        (self.out / "metrics.json").write_text(json.dumps(metrics, indent=1))
        log.info("metrics: %s", json.dumps({k: v for k, v in metrics.items()
                                            if not isinstance(v, list | dict)}))
        return metrics


def run_experiment(config: RunConfig) -> dict:
    """Run one experiment (see :class:`ExperimentRun`) and return its metrics."""
    return ExperimentRun(config).run()
