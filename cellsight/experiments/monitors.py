"""What the run watches and writes into ``run.log`` as it goes, besides the task's own phase
changes: the grasp (:class:`GraspMonitor`) and the kidnapping (:class:`KidnapMonitor`); what hides
the part is the session's (:mod:`cellsight.session.events`)."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from cellsight.camera import Camera
from cellsight.control import Phase
from cellsight.experiments.plant import GroundTruth
from cellsight.geometry.transforms import rotation_angle
from cellsight.world.faults import Knock

log = logging.getLogger(__name__)


class GraspMonitor:
    """The grasping robot's grasp: the TCP's error from the grasp pose when the grasp first
    engages (the world's own figure, :meth:`GroundTruth.grasp`), and whether the part is
    really held each time the task enters Manipulate (``held``: one entry a pick, in order;
    the grasp's success)."""

    def __init__(self, world: GroundTruth, robot: str) -> None:
        self.world = world
        self.robot = robot
        self.error_mm: float | None = None
        self.held: list[bool] = []

    def after_control_step(self, t: float) -> None:
        """Call after each control step (``t``: the world's time, s): logs the engagement."""
        grasp = self.world.grasp(self.robot) if self.error_mm is None else None
        if grasp is None:
            return
        self.error_mm = 1e3 * grasp.position_error_m
        log.info("t=%6.2f s grasp engaged: TCP %.1f mm, %.1f deg from the grasp pose",
                 t, self.error_mm, np.degrees(grasp.angle_error_rad))

    def after_vision(self, before: Phase, after: Phase) -> None:
        """Call after the task's vision update, with its phase before and after."""
        if before == Phase.GRASP and after == Phase.MANIPULATE:
            self.held.append(self.world.grasp(self.robot) is not None)


class KidnapMonitor:
    """How the tracker meets the kidnapping (:class:`~cellsight.world.faults.Kidnap`), from
    when the cameras see again (``t_back``):

    - ``noticed_s``: until the first frame whose status is ``lost`` or ``acquired`` (the
      tracker says its estimate is gone, or starts anew);
    - ``wrong_tracking_s``: how long it said ``tracking`` with the estimate more than
      ``wrong_mm`` off (a confident wrong pose; ``degraded`` is a warning), before it
      recovered;
    - ``visible_s``: when (from ``t_back``) some camera truly saw ``min_visible`` of its points;
    - from then, ``recovered_s``: until the first frame with an estimate within ``wrong_mm``,
      and ``reacquired_s``: within ``found_mm`` (None: never, by the end of the run);
    - ``before_mm``: the error in the last frame before the blind spell, ``settled_mm``: 1 s
      after it recovered (a world with calibration errors has an error of its own, wherever
      the part is).

    Logged in ``run.log`` as it happens; :meth:`record` for ``metrics.json``."""

    def __init__(self, kidnap, wrong_mm: float = 10.0, found_mm: float = 2.0,
                 min_visible: int = 4) -> None:
        self.kidnap = kidnap
        self.wrong_mm, self.found_mm, self.min_visible = wrong_mm, found_mm, min_visible
        self.times: dict[str, float] = {}
        self.errors: dict[str, float] = {}
        self.wrong_frames = 0

    def update(self, t: float, status: str, error_mm: float | None, n_visible: int) -> None:
        """One frame at ``t`` (s): the part's status, its position error (mm; None without an
        estimate) and the most points any camera truly sees."""
        k, times = self.kidnap, self.times
        if t < k.t_start - 1e-9 and error_mm is not None:
            self.errors["before"] = error_mm
        if t < k.t_back - 1e-9 or "settled" in times:
            return
        if "noticed" not in times and status in ("lost", "acquired"):
            times["noticed"] = t
            log.info("t=%6.2f s kidnapping noticed: the track is %s, %.2f s after the cameras "
                     "saw again", t, status, t - k.t_back)
        near = error_mm is not None and error_mm <= self.wrong_mm
        if status == "tracking" and error_mm is not None and not near and "recovered" not in times:
            self.wrong_frames += 1
        if "visible" not in times and n_visible >= self.min_visible:
            times["visible"] = t
        if "visible" in times and near and "recovered" not in times:
            times["recovered"] = t
            log.info("t=%6.2f s kidnapped part found again: %.2f mm off, %.2f s after it was "
                     "visible", t, error_mm, t - times["visible"])
        if "visible" in times and near and error_mm <= self.found_mm:
            times.setdefault("found", t)
        if "recovered" in times and t >= times["recovered"] + 1.0 - 1e-9:
            times["settled"] = t
            self.errors["settled"] = error_mm if error_mm is not None else float("nan")

    def record(self, vision_hz: float, moved: bool | None) -> dict:
        """The fault and the figures (module docstring), s and mm."""
        k, times = self.kidnap, self.times

        def since(event: str, start: str | None) -> float | None:
            t0 = k.t_back if start is None else times.get(start)
            return None if event not in times or t0 is None else round(times[event] - t0, 4)

        def error(name: str) -> float | None:
            value = self.errors.get(name)
            return None if value is None or math.isnan(value) else round(value, 3)

        return {**k.record(), "moved": moved, "noticed_s": since("noticed", None),
                "wrong_tracking_s": round(self.wrong_frames / vision_hz, 4),
                "visible_s": since("visible", None),
                "recovered_s": since("recovered", "visible"),
                "reacquired_s": since("found", "visible"),
                "before_mm": error("before"), "settled_mm": error("settled")}


def knock_record(knock: Knock, dropped: dict[int, float], recovered: dict[int, np.ndarray],
                 cameras: Sequence[Camera], true_cameras: Sequence[Camera],
                 points: np.ndarray) -> dict:
    """How the tracker met a knocked camera (:class:`~cellsight.world.faults.Knock`), for
    ``metrics.json``: the fault; ``detected_s``, from the knock until the tracker dropped that
    camera (None: never; negative: dropped before it was knocked); ``recovered``: the re-estimated
    pose's move from the cell file's (mm, deg), its error against the world's true camera
    (``true_cameras``; mm, deg) and the median distance (px) between the true camera's pixels of
    ``points`` (N, 3), base frame, and the re-estimated camera's (``error_px``)."""
    c = knock.camera
    out = {**knock.record(cameras[c].name), "detected_s": None, "recovered": None}
    if c in dropped:
        out["detected_s"] = round(dropped[c] - knock.t, 4)
    if c in recovered:
        T = recovered[c]
        fitted = replace(cameras[c], T_base_cam=T)
        gap = fitted.project(points) - true_cameras[c].project(points)
        out["recovered"] = {"moved": _pose_gap(cameras[c].T_base_cam, T),
                            "error": _pose_gap(true_cameras[c].T_base_cam, T),
                            "error_px": round(float(np.median(np.linalg.norm(gap, axis=1))), 3)}
    return out


def _pose_gap(A: np.ndarray, B: np.ndarray) -> dict:
    """How far pose ``B`` is from ``A``: position (mm) and rotation (deg)."""
    angle = np.degrees(rotation_angle(A[:3, :3].T @ B[:3, :3]))
    return {"mm": round(1e3 * float(np.linalg.norm(B[:3, 3] - A[:3, 3])), 3),
            "deg": round(float(angle), 4)}
