"""``metrics.json``, a run's facts and figures: its schema (:class:`RunMetrics`), its one writer
(:func:`write_metrics`) and its one reader (:func:`read_metrics`).

The file is a JSON object. ``metrics_version`` (:data:`METRICS_VERSION`) says which schema wrote
it; a file without one was written before versions and reads the same. Every field is optional
on reading (a run cut short writes what it has; ``cellsight compare`` takes any two), but a
field that is there must have its type: a hand-edited ``"seed": "three"`` or ``"phases": [1]``
is one :class:`~cellsight.runfolder.replay.RunDataError` naming the file and the field. Fields
the schema does not know are kept as they are. The figures' meaning and units are those of
:mod:`cellsight.runfolder.figures` (``*_mm`` in mm, ``*_deg`` in degrees, ``*_s`` in s).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, ValidationError

from cellsight.errors import CellsightError, short_repr
from cellsight.fields import about
from cellsight.runfolder.digest import file_digest, is_regular_file
from cellsight.runfolder.writes import write_file

METRICS_VERSION = 1
"""Version of the schema :func:`write_metrics` writes (``metrics_version``)."""


class RunDataError(CellsightError, ValueError):
    """A run folder that cannot be read or replayed: missing, unreadable, or inconsistent."""


Number = float | None  # JSON numbers (an int reads as a float); None where nothing was measured



class RunMetrics(BaseModel):
    """The typed fields of ``metrics.json`` (module docstring); others are kept as they are.
    ``phases``: phase -> figures of that phase; ``timing_ms``: stage -> median ms."""

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
    calibration_folder: str | None = about(
        None, "The cellsight calibrate folder the tracker and the task took the cameras and "
        "robot bases from (none: the cell file's).", "-")
    calibration_errors: dict | None = about(
        None, "That calibration's errors against the simulated world's truth, as its "
        "calibration.json gives them: per camera and per other robot's base (mm, deg, %, px).",
        "-")
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
    collisions: list[dict[str, Any]] | None = about(
        None, "Every collision: bodies, t_start_s and t_end_s (s), depth_mm (mm).", "-")
    collision_count: int | None = about(None, "How many collisions there were.", "-")
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
    frames: int | None = about(None, "The vision frames logged (rows of frames.csv).", "-")
    fewest_visible: dict[str, list[int]] | None = about(
        None, "Per task phase, per camera: the fewest feature points truly visible in any of its "
        "frames, each camera at its own worst frame (two cameras at 0 were not blinded at the "
        "same instant unless their worst frames coincide).", "-")
    evaluated_frames: int | None = about(
        None, "The evaluated frames: part in some camera's image, from the first estimate on, "
        "whole task.", "-")
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
    first_estimate_s: Number = about(
        None, "The time of the first frame with an estimate; none: never.", "s")
    in_view_fraction: Number = about(
        None, "Fraction of the frames from the first estimate on in which the part is in "
        "view.", "-")
    phases: dict[str, dict[str, Any]] | None = about(
        None, "Per task phase (approach, grasp, manipulate, release): the estimation figures over "
        "its evaluated frames.", "-")
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
    timing_ms: dict[str, Number] | None = about(
        None, "Tracker stage -> its median time per frame.", "ms")
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
    registration: dict[str, Any] | None = about(
        None, "Camera -> its registration to the gripper (offset, corners, when and where it "
        "was made); none: the cameras were not registered.", "px")
    arm_home_error_mm: list[float] | None = about(
        None, "For cameras registered to the grasping arm: the world's truth of that arm's own "
        "TCP error at HOME (x, y, z, base frame); none otherwise.", "mm")
    position_rmse_arm_mm: Number = about(
        None, "Position RMSE in the grasping arm's frame: against the part's true positions "
        "moved by the arm's own error at HOME (what the grasp needs); none when the cameras "
        "were not registered to the arm.", "mm")
    wall_s: Number = about(None, "Wall-clock time the run (or the tracking) took.", "s")
    interrupted: bool | None = about(
        None, "Whether a signal (SIGINT, SIGTERM) cut the run short.", "-")
    signal: str | None = about(None, "The signal that interrupted it.", "-")
    error: str | None = about(
        None, "Why the run failed (\"<type>: <message>\", failed writes included); none: it did "
        "not.", "-")
    t_end_s: Number = about(None, "The time of the last logged frame.", "s")
    cameras: list[str] | None = about(None, "The cameras' names, in the cell file's order.", "-")
    features: int | None = about(None, "How many feature points the part has.", "-")
    robot: str | None = about(None, "The grasping robot.", "-")
    workpiece: str | None = about(None, "The workpiece tracked and grasped.", "-")
    crossing_robot: str | None = about(
        None, "The robot crossing the cameras' views (experiment 3); none in the others.", "-")
    phase_intervals: list[list[str | float]] | None = about(
        None, "[phase, start, end] of every task phase entered, times in s.", "s")


_EXPECTED = {"dict_type": "expected an object", "int_type": "expected a whole number",
             "float_type": "expected a number", "string_type": "expected text",
             "bool_type": "expected true or false", "list_type": "expected a list"}
"""What a pydantic error type expects, in the words of a JSON file."""


def _located(data: dict, loc: tuple) -> tuple[str, object]:
    """The dotted field name and value at a pydantic error's ``loc`` in ``data`` (the parts
    naming union members rather than keys or indices are left out)."""
    names, value = [], data
    for part in loc:
        if isinstance(value, dict) and part in value or (
                isinstance(value, list) and isinstance(part, int) and part < len(value)):
            names.append(str(part))
            value = value[part]
    return ".".join(names), value


def _checked(data: object, path: Path) -> dict:
    """``data`` checked against :class:`RunMetrics`: the fields as they were, or one
    :class:`RunDataError` naming ``path`` and the first wrong field."""
    if not isinstance(data, dict):
        raise RunDataError(f"{path}: expected a JSON object of metrics, got "
                           f"{type(data).__name__} {short_repr(data)}")
    try:
        RunMetrics.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        field, value = _located(data, first["loc"])
        expected = _EXPECTED.get(first["type"], first["msg"].lower())
        raise RunDataError(f"{path}: field {field!r}: {expected}, got "
                           f"{short_repr(value)}") from None
    version = data.get("metrics_version", 0)
    if version > METRICS_VERSION:
        raise RunDataError(f"{path}: field 'metrics_version' is {version}: written by a newer "
                           f"cellsight (this one reads up to {METRICS_VERSION})")
    return data


def _json_object(path: Path, folder: Path) -> object:
    """The JSON value in ``path``; a :class:`RunDataError` naming it when it cannot be read."""
    if path.exists() and not is_regular_file(path):  # a FIFO would block for ever
        raise RunDataError(f"{path}: not a regular file (a folder, a FIFO or a device); "
                           f"expected the run's metrics.json")
    try:
        text = path.read_bytes()
    except (FileNotFoundError, NotADirectoryError) as exc:
        raise RunDataError(f"{path}: no metrics.json here (is {folder} a run's output "
                           f"folder?)") from exc
    except (OSError, ValueError) as exc:  # a folder, unreadable, a NUL in the name
        reason = getattr(exc, "strerror", None) or str(exc)
        raise RunDataError(f"{path}: cannot read it ({reason})") from exc
    try:
        return json.loads(text.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise RunDataError(f"{path}: not UTF-8 text") from exc
    except json.JSONDecodeError as exc:
        raise RunDataError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from exc
    except (ValueError, RecursionError) as exc:  # a number too long, nested too deeply
        shown = " ".join(str(exc).split())[:80]
        raise RunDataError(f"{path}: not usable JSON ({shown})") from exc


def read_metrics(folder: str | Path, missing_ok: bool = False) -> dict:
    """``<folder>/metrics.json`` as a dict, checked (module docstring); ``missing_ok``: ``{}``
    when the file is absent (a run cut short before writing it). Every problem is one
    :class:`RunDataError` naming the folder or the file."""
    folder = Path(folder)
    path = folder / "metrics.json"
    if missing_ok and not path.exists():
        return {}
    if not folder.is_dir():
        what = "it does not exist" if not folder.exists() else "it is not a folder"
        raise RunDataError(f"{folder}: no such run folder ({what}), so no metrics.json here; "
                           f"expected a run's output folder (cellsight run)")
    return _checked(_json_object(path, folder), path)


def checked_metrics(folder: Path, metrics: dict) -> dict:
    """``metrics`` as :func:`write_metrics` would write them into ``folder`` (with
    ``metrics_version``), checked against :class:`RunMetrics`; nothing is written."""
    out = {"metrics_version": METRICS_VERSION, **metrics}
    return _checked(out, Path(folder) / "metrics.json")


def write_metrics(folder: Path, metrics: dict) -> dict:
    """Write ``metrics`` as ``<folder>/metrics.json`` (with ``metrics_version`` and the
    ``frames_sha256`` of the folder's frames.csv, closed by then), checked against
    :class:`RunMetrics` first; returns what was written. The file is written whole or
    not at all (:func:`~cellsight.runfolder.writes.write_file`: a failure is a
    :class:`~cellsight.runfolder.writes.WriteError` and leaves no ``metrics.json`` of it)."""
    frames = file_digest(Path(folder) / "frames.csv")
    out = checked_metrics(folder, metrics if frames is None else
                          {**metrics, "frames_sha256": frames})
    write_file(Path(folder) / "metrics.json", json.dumps(out, indent=1))
    return out


def finished_metrics(folder: Path) -> dict | None:
    """The metrics of a finished run in ``folder`` (neither interrupted nor failed), else None:
    not run yet, cut short while writing, or not a run's metrics. A run that could not write
    one of its files (a full disk) is a failed one: its ``metrics.json``, written last, has the
    ``error``, or it has none (:mod:`cellsight.runfolder.writes`)."""
    try:
        metrics = read_metrics(folder)
    except RunDataError:
        return None
    return None if metrics.get("interrupted") or metrics.get("error") else metrics
