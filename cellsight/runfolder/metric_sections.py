"""The sections of ``metrics.json`` (for :mod:`.metrics`): what was run, the task, the
accuracy, the visibility and measurements, the timing, the health and the calibration, each a
typed model; :class:`RunMetrics` is all of them, one flat JSON object. Units in the names:
``*_mm``, ``*_deg``, ``*_s``, ``*_px``; ``Number``: a JSON number, None where nothing was
measured."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict

from cellsight.fields import about

Number = float | None  # JSON numbers (an int reads as a float); None where nothing was measured


class RunFacts(BaseModel):
    """What was run and on what: the experiment, the cell and its files, the seed, the sensor,
    the tracker, the structure, the realism profile and its draws, the cameras, the part and
    the robots."""

    model_config = ConfigDict(extra="allow", strict=True)

    metrics_version: int = about(
        0, "The schema version that wrote the file; 0: written before versions.", "-")
    experiment: int | None = about(
        None, "The paper's experiment run: 1 (part still), 2 (on the conveyor) or 3 (and a robot "
        "crossing); none for a tracked recording.", "-")
    description: str | None = about(
        None, "What was run, in words: the experiment's description, or the recording "
        "tracked.", "-")
    cell: str | None = about(None, "The cell file the run used (its path).", "-")
    cell_sha256: str | None = about(
        None, "SHA-256 (hex) over the cell file and every file it points to; none when one cannot "
        "be read.", "-")
    frames_sha256: str | None = about(
        None, "SHA-256 (hex) of frames.csv as the run closed it: what reads the run back checks "
        "that frames.csv is still that file.", "-")
    identity: dict | None = about(
        None, "Every input that shapes the run (experiment, seed, sensor, tracker options, "
        "structure, duration and limits, the cell's, the realism profile's and the "
        "calibration's SHA-256, cellsight's version): a sweep reuses the run only when its own "
        "run's identity is the same.", "-")
    cell_files: dict[str, str | None] | None = about(
        None, "SHA-256 of the run folder's copy of the cell file and of every file the cell "
        "points to (file -> digest; none: unreadable).", "-")
    seed: int | None = about(
        None, "The run's seed: the realism profile's draws and the world's noise.", "-")
    sensor: str | None = about(
        None, "What the tracker saw: rendered (images), ideal (true projections plus pixel noise) "
        "or recorded.", "-")
    tracker: str | None = about(
        None, "The tracker: kinematic (the images, the kinematic prior and the cameras' "
        "registration to the gripper) or plain (the paper's, from the images alone); none: a run "
        "from before the choice, read by kinematic_prior.", "-")
    occlusion_prediction: bool | None = about(
        None, "Whether the tracker predicted occlusions (false: the projection-only "
        "baseline).", "-")
    kinematic_prior: bool | None = about(
        None, "Whether the tracker used the kinematic prior (a held part follows the "
        "gripper).", "-")
    unknown_occluders: bool | None = about(
        None, "Whether the tracker learned where bodies the cell file does not know hide the "
        "part (experimental).", "-")
    camera_offsets_px: float | None = about(
        None, "The prior of each camera's calibration error, estimated as an image offset (0: the "
        "calibration trusted; experimental).", "px")
    structure: str | None = about(
        None, "The occlusion predictor's structure: object-bvh or frame-bsp.", "-")
    realism: str | None = about(None, "The realism profile's name.", "-")
    realism_file: str | None = about(None, "The file the realism profile came from.", "-")
    realism_spec: str | None = about(
        None, "The realism profile as asked for (NAME, FILE, FILE:NAME, NAME/GROUP); none when "
        "given as an object.", "-")
    draws: dict[str, Any] | None = about(
        None, "Every draw of the realism profile: knob (and what it was drawn for) -> value(s) in "
        "the knob's own unit, or event -> whether it happened.", "knob's unit")
    cameras: list[str] | None = about(None, "The cameras' names, in the cell file's order.", "-")
    features: int | None = about(None, "How many feature points the part has.", "-")
    robot: str | None = about(None, "The grasping robot.", "-")
    workpiece: str | None = about(None, "The workpiece tracked and grasped.", "-")
    crossing_robot: str | None = about(
        None, "The robot crossing the cameras' views (experiment 3); none in the others.", "-")


class LinePartFigures(BaseModel):
    """One part of a line: its figures from its own frame log
    (:mod:`cellsight.runfolder.picks`)."""

    model_config = ConfigDict(extra="allow", strict=True)

    part: str = about(..., "The workpiece.", "-")
    position_rmse_mm: Number = about(
        None, "Its position RMSE over its evaluated frames (in view, estimated), the whole "
        "run.", "mm")
    position_rmse_arm_mm: Number = about(
        None, "The same in the grasping arm's frame (with the cameras registered to it).", "mm")
    max_error_tracking_mm: Number = about(
        None, "Its largest error while its status said tracking.", "mm")
    confident_wrong_frames: int | None = about(
        None, "Its evaluated frames more than 10 mm off while its status said tracking.", "-")
    identity_swaps: int | None = about(
        None, "Its frames with the estimate nearer another logged part's true position than "
        "its own, and more than 10 mm from its own.", "-")


class PickFigures(LinePartFigures):
    """One pick of a line (the cell file's ``experiments.picks``): whether it was picked, and
    its figures."""

    picked: bool | None = about(
        None, "Whether it was truly held when its Manipulate began (none: its turn never came "
        "that far).", "-")
    failed_grasp_checks: int = about(0, "Its failed grasp checks.", "-")


class PassingFigures(LinePartFigures):
    """One passing part of a line (the cell file's ``experiments.passing``): carried through
    the views, not picked; its figures, and its entry and exit."""

    entered_s: Number = about(
        None, "When it entered the views (a feature truly in some camera's image; none: "
        "never).", "s")
    whole_in_view_s: Number = about(
        None, "When every feature of it was first in one camera's image (none: never).", "s")
    left_s: Number = about(
        None, "When it left them (none: never, or still in view at the end).", "s")
    acquired_after_s: Number = about(
        None, "From whole_in_view_s to its first estimate after entering (negative: estimated "
        "before; none: never estimated, or never wholly in view).", "s")
    tracking_out_of_view_frames: int | None = about(
        None, "Its frames said tracking while no camera could see it.", "-")


class TaskMetrics(BaseModel):
    """How the grasping task went: the grasp, the phases, the checks, the collisions and what
    ended the run."""

    model_config = ConfigDict(extra="allow", strict=True)

    grasp_success: bool | None = about(
        None, "Whether the part was truly held when the task entered manipulate.", "-")
    grasp_position_error_mm: Number = about(
        None, "The TCP's distance from the part's grasp pose when the grasp first engaged (the "
        "world's truth); none: it never engaged.", "mm")
    ended_by: str | None = about(
        None, "What ended the run: the task done (and its tail), the task failed, the "
        "--duration asked for, or the time limit (max_duration) with the task not done.", "-")
    last_setback: str | None = about(
        None, "The task's last step back, in words, with its time: a grasp check that failed, "
        "a pose not reached, the part lost (none: it never stepped back).", "-")
    final_phase: str | None = about(
        None, "The task's phase at the end of the run (done, failed, ...).", "-")
    failed_grasp_checks: int | None = about(
        None, "How many grasp checks failed (jaws not closed on the part at its grasp).", "-")
    phase_intervals: list[list[str | float]] | None = about(
        None, "[phase, start, end] of every task phase entered, times in s.", "s")
    collisions: list[dict[str, Any]] | None = about(
        None, "Every collision: bodies, t_start_s and t_end_s (s), depth_mm (mm).", "-")
    collision_count: int | None = about(None, "How many collisions there were.", "-")
    picks: list[PickFigures] | None = about(
        None, "A line's picks, in order, each with its own figures (none: one part).", "-")
    passing: list[PassingFigures] | None = about(
        None, "A line's passing parts, each with its own figures (none: no passing part).", "-")


class PhaseAccuracy(BaseModel):
    """The estimation figures over a span of evaluated frames (the whole task, or one of its
    phases): errors against the truth, the PnP baseline's, and the time lost in view."""

    model_config = ConfigDict(extra="allow", strict=True)

    evaluated_frames: int | None = about(
        None, "The evaluated frames of the span: part in some camera's image, from the first "
        "estimate on.", "-")
    position_rmse_mm: Number = about(
        None, "RMS distance between the estimated and true part-frame origin (base frame) over "
        "the evaluated frames with an estimate.", "mm")
    orientation_rmse_deg: Number = about(
        None, "RMS of the angle of R_est^T R_true over the evaluated frames with an "
        "estimate.", "deg")
    max_position_error_mm: Number = about(
        None, "The largest position error over the evaluated frames with an estimate.", "mm")
    pnp_position_rmse_mm: Number = about(
        None, "The per-frame PnP baseline's position RMSE, over the evaluated frames where it has "
        "a pose.", "mm")
    pnp_orientation_rmse_deg: Number = about(
        None, "The per-frame PnP baseline's orientation RMSE, over the evaluated frames where it "
        "has a pose.", "deg")
    lost_in_view_s: Number = about(
        None, "Time of evaluated frames without an estimate (one vision period each).", "s")


class AccuracyMetrics(PhaseAccuracy):
    """How well the part was known: errors against the truth, over the run, per phase
    (:class:`PhaseAccuracy` each) and in the arm's frame, and the PnP baseline's."""

    model_config = ConfigDict(extra="allow", strict=True)

    frames: int | None = about(None, "The vision frames logged (rows of frames.csv).", "-")
    first_estimate_s: Number = about(
        None, "The time of the first frame with an estimate; none: never.", "s")
    in_view_fraction: Number = about(
        None, "Fraction of the frames from the first estimate on in which the part is in "
        "view.", "-")
    phases: dict[str, PhaseAccuracy] | None = about(
        None, "Per task phase (approach, grasp, manipulate, release): the estimation figures over "
        "its evaluated frames.", "-")
    arm_home_error_mm: list[float] | None = about(
        None, "For cameras registered to the grasping arm: the world's truth of that arm's own "
        "TCP error at HOME (x, y, z, base frame); none otherwise.", "mm")
    position_rmse_arm_mm: Number = about(
        None, "Position RMSE in the grasping arm's frame: against the part's true positions "
        "moved by the arm's own error at HOME (what the grasp needs); none when the cameras "
        "were not registered to the arm.", "mm")


class VisibilityMetrics(BaseModel):
    """What the cameras saw and measured: the prediction's accuracy, the measurements, the
    wrong corners, the pixels grabbed."""

    model_config = ConfigDict(extra="allow", strict=True)

    fewest_visible: dict[str, list[int]] | None = about(
        None, "Per task phase, per camera: the fewest feature points truly visible in any of its "
        "frames, each camera at its own worst frame (two cameras at 0 were not blinded at the "
        "same instant unless their worst frames coincide).", "-")
    visibility_accuracy: Number = about(
        None, "Fraction of in-view frame x camera x feature labels where the predicted visibility "
        "equals the truth.", "-")
    visibility_accuracy_all: Number = about(
        None, "The same over every label, out-of-view ones included.", "-")
    false_visible: int | None = about(
        None, "Labels predicted visible but truly hidden, over every label.", "-")
    false_hidden: int | None = about(
        None, "Labels predicted hidden but truly visible, over every label.", "-")
    measurements: int | None = about(None, "Features measured, over all frames and cameras.", "-")
    rejected_measurements: int | None = about(None, "Measurements the EKF's gate rejected.", "-")
    wrong_measurements: int | None = about(
        None, "Measurements more than WRONG_PX from the feature's true projection (another image "
        "point).", "-")
    wrong_accepted: int | None = about(
        None, "Wrong measurements not rejected and used by the filter.", "-")
    pixels_grabbed_fraction: Number = about(
        None, "Mean over frames and cameras of the fraction of pixels grabbed.", "-")
    extraction_error_px_median: Number = about(
        None, "Median over frames and cameras of each frame's median extraction error; none: no "
        "frame has one (ideal sensor).", "px")


class TimingMetrics(BaseModel):
    """How long it took: the tracker's stages, the wall time, the run's last frame."""

    model_config = ConfigDict(extra="allow", strict=True)

    timing_ms: dict[str, Number] | None = about(
        None, "Tracker stage -> its median time per frame.", "ms")
    wall_s: Number = about(None, "Wall-clock time the run (or the tracking) took.", "s")
    t_end_s: Number = about(None, "The time of the last logged frame.", "s")


class HealthMetrics(BaseModel):
    """How the run and the tracker held up: degraded spans, confident wrong frames, dropped
    frames and cameras, the faults and how the run ended."""

    model_config = ConfigDict(extra="allow", strict=True)

    degraded_s: Number = about(
        None, "Seconds of frames whose tracker status was degraded.", "s")
    degraded_episodes: int | None = about(
        None, "How many times the status became degraded.", "-")
    confident_wrong_frames: int | None = about(
        None, "Evaluated frames more than CONFIDENT_WRONG_MM (10 mm) off while the status said "
        "tracking: the failure that matters most.", "-")
    max_error_tracking_mm: Number = about(
        None, "The largest position error over the evaluated frames whose status said "
        "tracking.", "mm")
    frames_dropped: int | None = about(
        None, "Vision frames whose images never arrived (dropped, or blind while the part was "
        "kidnapped; a recording's gaps).", "-")
    kidnap: dict[str, Any] | None = about(
        None, "The kidnapping and how the tracker met it (times in s, distances in mm, angles in "
        "deg); none without one.", "-")
    knock: dict[str, Any] | None = about(
        None, "The knocked camera and how the tracker met it (s, mm, deg, px); none without "
        "one.", "-")
    cameras_dropped: dict[str, Any] | None = about(
        None, "Camera name -> when the tracker's camera check dropped it from the filter.", "s")
    interrupted: bool | None = about(
        None, "Whether a signal (SIGINT, SIGTERM) cut the run short.", "-")
    signal: str | None = about(None, "The signal that interrupted it.", "-")
    error: str | None = about(
        None, "Why the run failed (\"<type>: <message>\", failed writes included); none: it did "
        "not.", "-")


class CalibrationMetrics(BaseModel):
    """The cell's calibration: the calibration folder used and its errors, and each camera's
    registration to the gripper."""

    model_config = ConfigDict(extra="allow", strict=True)

    calibration_folder: str | None = about(
        None, "The cellsight calibrate folder the tracker and the task took the cameras and "
        "robot bases from (none: the cell file's).", "-")
    calibration_errors: dict | None = about(
        None, "That calibration's errors against the simulated world's truth, as its "
        "calibration.json gives them: per camera and per other robot's base (mm, deg, %, px).",
        "-")
    registration: dict[str, Any] | None = about(
        None, "Camera -> its registration to the gripper (offset, corners, when and where it "
        "was made); none: the cameras were not registered.", "px")


SECTIONS = (RunFacts, TaskMetrics, AccuracyMetrics, VisibilityMetrics, TimingMetrics,
            HealthMetrics, CalibrationMetrics)
"""The sections of a run's metrics, in the order the reference lists them."""


class RunMetrics(RunFacts, TaskMetrics, AccuracyMetrics, VisibilityMetrics, TimingMetrics,
                 HealthMetrics, CalibrationMetrics):
    """The typed fields of ``metrics.json``, section by section (:data:`SECTIONS`), one flat
    JSON object as before; other keys are kept as they are. ``phases``: phase -> figures of
    that phase; ``timing_ms``: stage -> median ms. :meth:`section` gives one section of a run's
    metrics."""

    model_config = ConfigDict(extra="allow", strict=True)

    def section(self, kind: type[BaseModel]) -> BaseModel:
        """The run's figures of one section (one of :data:`SECTIONS`)."""
        return kind.model_validate({name: getattr(self, name) for name in kind.model_fields})
