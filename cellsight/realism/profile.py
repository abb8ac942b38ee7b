"""Realism profiles: the knobs of the world's departures from the cell file, read from YAML.

The built-in profiles (``exact``, ``lab``, ``harsh``) are in ``cellsight/data/realism.yaml``,
which documents the format; a user's file has the same shape (one profile at the top level, or
several under ``profiles:``, chosen as ``FILE:NAME``). Every knob's unit is in its name, its
default is the ``exact`` world's value, and a drawn knob states its distribution
(:class:`Distribution`). Any error (unknown knob, negative sigma, NaN, unknown distribution,
a missing profile) is a :class:`ProfileError` naming the file, the field and the value.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator

from cellsight.errors import CellFileError
from cellsight.fields import about
from cellsight.model.yaml_input import load_yaml, read_cell_text

BUILTIN_FILE = Path(__file__).resolve().parent.parent / "data" / "realism.yaml"
BUILTIN = ("exact", "lab", "harsh", "kidnap", "crossed", "ccir")


class ProfileError(CellFileError):
    """A realism profile that cannot be used: names the file, the field and the value."""


def _no_bool(value: object) -> object:
    if isinstance(value, bool):
        raise ValueError("a number, not a boolean")
    return value


Finite = Annotated[float, BeforeValidator(_no_bool), Field(allow_inf_nan=False)]
NonNegative = Annotated[float, BeforeValidator(_no_bool), Field(ge=0, allow_inf_nan=False)]
Probability = Annotated[float, BeforeValidator(_no_bool), Field(ge=0, le=1, allow_inf_nan=False)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


DRAWN = "knob's unit"  # the unit of a distribution's numbers: the knob's own



class Distribution(_Strict):
    """How a knob is drawn: ``fixed`` (``value``), ``normal`` (``mean``, ``sigma`` >= 0) or
    ``uniform`` (``low`` <= ``high``)."""

    dist: Literal["fixed", "normal", "uniform"] = about(
        ..., "How the knob is drawn, once per run from its seed (each element of a vector knob "
        "on its own): fixed (value), normal (mean, sigma) or uniform (low, high).", "-")
    value: Finite = about(0.0, "A fixed knob's value.", DRAWN)
    mean: Finite = about(0.0, "A normal knob's mean; default 0.", DRAWN)
    sigma: NonNegative = about(0.0, "A normal knob's standard deviation, >= 0.", DRAWN)
    low: Finite = about(0.0, "A uniform knob's lower bound (<= high).", DRAWN)
    high: Finite = about(0.0, "A uniform knob's upper bound.", DRAWN)

    @model_validator(mode="after")
    def _ordered(self) -> Distribution:
        if self.dist == "uniform" and self.low > self.high:
            raise ValueError(f"uniform needs low <= high, got low {self.low}, high {self.high}")
        return self

    def draw(self, rng: np.random.Generator, size: int | tuple[int, ...] = ()) -> np.ndarray:
        """Values of shape ``size`` (always drawn from ``rng``, so that the stream of draws
        does not depend on the values)."""
        u = rng.standard_normal(size) if self.dist == "normal" else rng.random(size)
        if self.dist == "normal":
            return self.mean + self.sigma * u
        if self.dist == "uniform":
            return self.low + (self.high - self.low) * u
        return np.full(size, self.value) if size != () else np.float64(self.value)

    @property
    def zero(self) -> bool:
        """Always 0: the knob changes nothing."""
        if self.dist == "normal":
            return self.mean == 0 and self.sigma == 0
        if self.dist == "uniform":
            return self.low == 0 and self.high == 0
        return self.value == 0


def _knob(value: object) -> object:
    if isinstance(value, bool):
        raise ValueError("a number or a distribution {dist: ...}, not a boolean")
    if isinstance(value, int | float):
        return {"dist": "fixed", "value": value}
    return value


Knob = Annotated[Distribution, BeforeValidator(_knob)]
ZERO = Distribution(dist="fixed")


class CameraKnobs(_Strict):
    """Per camera and axis: the extrinsic calibration's position error at the work area (mm,
    along the camera's axes; the work area is the part's start) and its rotation error (deg,
    about the camera's axes, turning the camera about the work area: a hand-eye calibration
    fitted there is most accurate there); focal length (%, fx and fy together); principal point
    (px, per axis); radial distortion k1 added to the camera's own."""

    position_mm: Knob = about(ZERO, "The world camera's position error at the work area (the "
                              "part's start), along each axis of the camera frame; drawn per "
                              "camera.", "mm")
    rotation_deg: Knob = about(ZERO, "The world camera's rotation error, a rotation vector in the "
                               "camera's axes turning it about the work area; drawn per camera.",
                               "deg")
    focal_percent: Knob = about(ZERO, "The world camera's focal length error, fx and fy "
                                "together (the pose absorbs it at the work area); drawn per "
                                "camera.", "%")
    principal_point_px: Knob = about(ZERO, "The world camera's principal point error, per image "
                                     "axis (x, y); drawn per camera.", "px")
    distortion_k1: Knob = about(ZERO, "Radial distortion k1 added to the camera's own in the "
                                "world; drawn per camera.", "-")


class RobotKnobs(_Strict):
    """Per joint: encoder zero offsets (deg revolute, mm prismatic); per link: errors of the DH
    lengths a and d, or of a URDF joint origin per axis (mm); the base pose's position (mm, per
    axis) and rotation (deg, per axis); the measurement noise's standard deviation (rad, m) and
    the encoders' resolution (deg, mm; 0: none)."""

    encoder_offset_deg: Knob = about(ZERO, "A revolute joint's encoder zero offset (it reads "
                                     "the true angle plus this); drawn per robot and joint.",
                                     "deg")
    encoder_offset_mm: Knob = about(ZERO, "A prismatic joint's encoder zero offset; drawn per "
                                    "robot and joint.", "mm")
    link_length_mm: Knob = about(ZERO, "Per joint, the errors of the DH a and d (a third value "
                                 "unused) or of the URDF joint origin's x, y, z; drawn per "
                                 "robot.", "mm")
    base_position_mm: Knob = about(ZERO, "The robot base's position error along each axis of its "
                                   "frame 0; drawn per robot.", "mm")
    base_rotation_deg: Knob = about(ZERO, "The robot base's rotation error, a rotation vector in "
                                    "its frame 0; drawn per robot.", "deg")
    joint_noise_rad: NonNegative = about(1e-4, "The standard deviation of the Gaussian noise on "
                                         "each revolute joint's reading.", "rad")
    joint_noise_m: NonNegative = about(1e-4, "The standard deviation of the Gaussian noise on "
                                       "each prismatic joint's reading.", "m")
    encoder_resolution_deg: NonNegative = about(0.0, "Revolute encoders' resolution: readings "
                                                "rounded to multiples of it; 0: none.", "deg")
    encoder_resolution_mm: NonNegative = about(0.0, "Prismatic encoders' resolution: readings "
                                               "rounded to multiples of it; 0: none.", "mm")


class ServoKnobs(_Strict):
    """Every joint's position servo: bandwidth (Hz; 0: ideal, no lag), damping ratio, velocity
    (deg/s, also mm/s for a prismatic joint) and acceleration (deg/s^2, mm/s^2) limits; and
    what moves the joints: ``analytic`` (the servo's own second-order loop in a kinematic
    world) or ``mujoco`` (MuJoCo's position actuators on the joints' rotor inertia, with the
    acceleration limit as a torque limit, contacts pushing back; needs a bandwidth); whether
    the drives feed the set-point's velocity forward (``velocity_feedforward``: a ramp is then
    followed without the steady lag ``2 damping / (2 pi bandwidth)`` times its speed)."""

    bandwidth_hz: NonNegative = about(0.0, "Every joint's position-loop bandwidth (natural "
                                      "frequency wn = 2 pi bandwidth); 0: ideal, each joint at "
                                      "its set-point every control period.", "Hz")
    damping: Annotated[float, BeforeValidator(_no_bool), Field(gt=0, allow_inf_nan=False)] = (
        about(1.0, "The position loop's damping ratio zeta, > 0 (1: critically damped).", "-"))
    max_velocity_deg_s: Annotated[float, Field(gt=0)] = about(
        math.inf, "Every joint's speed limit (inf: none); converted as deg to rad for every "
        "joint, so a prismatic joint's limit is this times pi/180 in m/s.", "deg/s")
    max_acceleration_deg_s2: Annotated[float, Field(gt=0)] = about(
        math.inf, "Every joint's acceleration limit (inf: none; with mujoco, a torque limit), "
        "converted as deg to rad for every joint (a prismatic joint: times pi/180, m/s^2).",
        "deg/s^2")
    actuators: Literal["analytic", "mujoco"] = about(
        "analytic", "What moves the joints: analytic (the servo's own loop, kinematic world) or "
        "mujoco (MuJoCo's position actuators on rotor inertia, contacts pushing back; needs a "
        "bandwidth).", "-")
    velocity_feedforward: Annotated[bool, Field(strict=True)] = about(
        False, "The drives feed the set-point's velocity forward: a ramp is followed without "
        "the steady lag 2 damping / (2 pi bandwidth) times its speed.", "-")

    @model_validator(mode="after")
    def _actuated(self) -> ServoKnobs:
        if self.actuators == "mujoco" and self.bandwidth_hz == 0:
            raise ValueError("actuators mujoco needs bandwidth_hz > 0")
        return self


class GeometryKnobs(_Strict):
    """Size errors of the part and of the gripper's palm and jaws (mm, per axis of their own
    frames); where the part settles in the jaws when they clamp (mm along, deg about the TCP
    axes); the speed it then slips along the tool's approach axis (mm/s, absolute value); each
    static object's height error (mm along the base z axis, drawn per object: a table or a
    conveyor as built; a part resting on one at the start rises or sinks with it)."""

    part_size_mm: Knob = about(ZERO, "Change of the part's extents along the x, y, z axes of "
                               "its frame (scaled about its origin); drawn per workpiece.", "mm")
    gripper_size_mm: Knob = about(ZERO, "Change of the jaw's extents along its own axes, the "
                                  "palm and jaws scaled by the same factors; drawn per robot "
                                  "with a tool.", "mm")
    grasp_seat_mm: Knob = about(ZERO, "Where the part settles in the jaws when they clamp: a "
                                "shift along each TCP axis; drawn once per run.", "mm")
    grasp_seat_deg: Knob = about(ZERO, "How the part settles in the jaws when they clamp: a "
                                 "rotation vector about the TCP axes; drawn once per run.", "deg")
    slip_mm_s: Knob = about(ZERO, "The speed at which a held part slides along the tool's "
                            "approach axis (+z); its absolute value, drawn once per run.", "mm/s")
    support_height_mm: Knob = about(ZERO, "Each static object's height error along the base z "
                                    "axis, drawn per object; a part resting on one at its start "
                                    "rises or sinks with it.", "mm")


class UnmodelledKnobs(_Strict):
    """Bodies the cell file does not know: a box left near the part (its probability per run,
    its size per axis, mm) and an operator's forearm reaching across a camera's line of sight to
    the part (probability per run, when it arrives and how long it stays, s; across which
    camera: ``forearm_camera``, its index in the cell file, -1: drawn)."""

    box_probability: Probability = about(0.0, "Probability per run of a box left 15-30 cm from "
                                         "the part's start towards a camera drawn at random "
                                         "(0 to 1).", "-")
    box_size_mm: Knob = about(Distribution(dist="uniform", low=40.0, high=120.0),
                              "The box's size along each of its axes.", "mm")
    forearm_probability: Probability = about(0.0, "Probability per run of an operator's forearm "
                                             "(a 40 x 8 x 8 cm bar) across a camera's line of "
                                             "sight to the part (0 to 1).", "-")
    forearm_start_s: Knob = about(Distribution(dist="uniform", low=5.0, high=40.0),
                                  "When the forearm is in place (it slides in over the 0.5 s "
                                  "before), from the run's start.", "s")
    forearm_duration_s: Knob = about(Distribution(dist="uniform", low=1.0, high=4.0),
                                     "How long the forearm stays before it slides out.", "s")
    forearm_camera: Annotated[int, Field(strict=True, ge=-1)] = about(
        -1, "Whose view the forearm crosses: the camera's index in the cell file; -1: drawn.",
        "-")


class FaultKnobs(_Strict):
    """Faults of a run. The part kidnapped (probability per run): at ``kidnap_time_s`` every
    camera goes blind for ``kidnap_blind_s`` (no frame arrives), and halfway through it the
    part, if no gripper holds it, is moved by ``kidnap_distance_mm`` towards
    ``kidnap_direction_deg`` (about the base z axis, from +x) and turned by ``kidnap_turn_deg``
    about the vertical through its origin; on the conveyor it rides on from there. A camera
    knocked (probability per run): at ``knock_time_s`` one camera (``knock_camera``, its index
    in the cell file; -1: drawn) moves by
    ``knock_shift_mm`` along a drawn direction and turns by ``knock_rotation_deg`` about a drawn
    axis of its own frame, for the rest of the run."""

    kidnap_probability: Probability = about(0.0, "Probability per run that the part is "
                                            "kidnapped (0 to 1).", "-")
    kidnap_time_s: Knob = about(Distribution(dist="uniform", low=3.0, high=6.0),
                                "When every camera goes blind, from the run's start.", "s")
    kidnap_blind_s: Annotated[float, Field(gt=0, allow_inf_nan=False)] = about(
        1.0, "How long no camera delivers a frame (> 0); the part is moved halfway through.",
        "s")
    kidnap_distance_mm: Knob = about(Distribution(dist="uniform", low=100.0, high=300.0),
                                     "How far the part is moved in the base x-y plane (unless a "
                                     "gripper holds it).", "mm")
    kidnap_direction_deg: Knob = about(Distribution(dist="uniform", low=0.0, high=360.0),
                                       "Where to, about the base z axis from +x; turned on by "
                                       "30 deg steps until a camera sees the part there.", "deg")
    kidnap_turn_deg: Knob = about(Distribution(dist="uniform", low=-45.0, high=45.0),
                                  "How far the part is turned about the vertical through its "
                                  "origin.", "deg")
    knock_probability: Probability = about(0.0, "Probability per run that a camera is knocked "
                                           "(0 to 1).", "-")
    knock_camera: Annotated[int, Field(strict=True, ge=-1)] = about(
        -1, "Which camera is knocked: its index in the cell file; -1: drawn.", "-")
    knock_time_s: Knob = about(Distribution(dist="uniform", low=15.0, high=30.0),
                               "When the camera is knocked, from the run's start; it stays so.",
                               "s")
    knock_shift_mm: Knob = about(Distribution(dist="fixed", value=20.0),
                                 "How far the camera moves, along a random direction.", "mm")
    knock_rotation_deg: Knob = about(Distribution(dist="fixed", value=1.0),
                                     "How far the camera turns, about a random axis of its own "
                                     "frame.", "deg")


class ImageKnobs(_Strict):
    """What the camera does to the image (:mod:`cellsight.world.images`): read noise (grey
    levels), conversion gain for shot noise (DN per electron), slow gain drift (% amplitude,
    period s), defocus blur (px), vignetting (fraction lost in the corners), JPEG quality (0:
    none), exposure time (ms: motion blur of what moves while the shutter is open; 0: none)
    and interlaced fields (the even rows exposed 20 ms before the odd ones)."""

    read_noise_dn: NonNegative = about(0.0, "The standard deviation of the sensor's Gaussian read "
                                       "noise, in grey levels (0-255).", "DN")
    shot_dn_per_e: NonNegative = about(0.0, "Conversion gain for shot noise: grey level I gets "
                                       "noise of variance I times this.", "DN/e-")
    gain_drift_percent: NonNegative = about(0.0, "Amplitude of the slow sinusoidal drift of the "
                                            "lighting and gain (its phase drawn per run).", "%")
    gain_period_s: Annotated[float, Field(gt=0, allow_inf_nan=False)] = about(
        30.0, "The gain drift's period, > 0.", "s")
    defocus_px: NonNegative = about(0.0, "Defocus: the standard deviation of a Gaussian blur.",
                                    "px")
    vignetting: Annotated[float, Field(ge=0, lt=1)] = about(
        0.0, "Fraction of brightness lost in the image's corners (1 - v (r / r_corner)^2).", "-")
    jpeg_quality: Annotated[int, Field(strict=True, ge=0, le=100)] = about(
        0, "JPEG compression quality of the link, 1-100; 0: none.", "-")
    exposure_ms: NonNegative = about(0.0, "Exposure time: what moves is smeared over it (motion "
                                     "blur); 0: none.", "ms")
    interlaced: Annotated[bool, Field(strict=True)] = about(
        False, "Interlaced fields: the even rows exposed 20 ms before the odd ones.", "-")


class TimingKnobs(_Strict):
    """From exposure to the planner: latency (ms) with Gaussian jitter per frame (ms), and the
    share of frames lost (%); each camera's trigger skew (ms, drawn once per camera; its
    absolute value, at most a vision period less a control step: that camera exposes this long
    before the frame's time, as unsynchronised cameras do)."""

    latency_ms: NonNegative = about(0.0, "The delay from a frame's exposure until its estimate "
                                    "reaches the planner.", "ms")
    latency_jitter_ms: NonNegative = about(0.0, "The standard deviation of each frame's Gaussian "
                                           "latency jitter (the latency stays >= 0).", "ms")
    drop_percent: Annotated[float, BeforeValidator(_no_bool), Field(ge=0, le=100)] = about(
        0.0, "Share of frames whose images never arrive.", "%")
    trigger_skew_ms: Knob = about(ZERO, "How long before the frame's time a camera exposes: "
                                  "the absolute value, at most a vision period less a control "
                                  "step; drawn per camera.", "ms")


class ScenarioKnobs(_Strict):
    """What the seed draws of the experiment itself: the part's start position (mm, x and y)
    and yaw (deg), the conveyor's speed (% of the cell file's) and direction (deg), and, in
    experiment 3, the crossing robot's timing (s, all waypoints together) and poses (deg, per
    joint, all waypoints together)."""

    part_position_mm: Knob = about(ZERO, "Shift of the part's start in the base x-y plane (x, "
                                   "y), the conveyor's path moved with it; drawn per "
                                   "workpiece.", "mm")
    part_yaw_deg: Knob = about(ZERO, "Turn of the part's start about the base z axis through "
                               "its origin; drawn per workpiece.", "deg")
    conveyor_speed_percent: Knob = about(ZERO, "Change of the conveyor's speed, in % of the "
                                         "cell file's.", "%")
    conveyor_direction_deg: Knob = about(ZERO, "Turn of the conveyor's path about its first "
                                         "point.", "deg")
    crossing_time_s: Knob = about(ZERO, "Shift of all the crossing robot's waypoint times "
                                  "together (experiment 3).", "s")
    crossing_joint_deg: Knob = about(ZERO, "Shift of each of the crossing robot's joints, at "
                                     "all waypoints together (experiment 3).", "deg")


class Profile(_Strict):
    """One realism profile (module docstring). ``name`` and ``file`` say where it came from."""

    name: str = about("exact", "The profile's name: its name in the file (else the file's "
                      "stem), PROFILE-GROUP for groups of a built-in one.", "-")
    file: str = about("<built-in>", "The file it was read from (set on loading).", "-")
    description: str = about("", "What the profile stands for, in words.", "-")
    sources: list[str] = Field(default_factory=list, description="Where its figures come from: "
                               "references, or our own judgement.",
                               json_schema_extra={"unit": "-"})
    cameras: CameraKnobs = about(CameraKnobs(), "The cameras' calibration errors.", "-")
    robots: RobotKnobs = about(RobotKnobs(), "The robots' encoders, links and bases.", "-")
    servo: ServoKnobs = about(ServoKnobs(), "The joints' position servo.", "-")
    geometry: GeometryKnobs = about(GeometryKnobs(), "Sizes, the grasp's seat and slip, the "
                                    "static objects' heights.", "-")
    unmodelled: UnmodelledKnobs = about(UnmodelledKnobs(), "Bodies the cell file does not "
                                        "know.", "-")
    faults: FaultKnobs = about(FaultKnobs(), "The part kidnapped, a camera knocked.", "-")
    images: ImageKnobs = about(ImageKnobs(), "What the camera does to the image.", "-")
    timing: TimingKnobs = about(TimingKnobs(), "Latency, dropped frames, trigger skew.", "-")
    scenario: ScenarioKnobs = about(ScenarioKnobs(), "What the seed changes in the experiment "
                                    "itself.", "-")


GROUPS = ("cameras", "robots", "servo", "geometry", "unmodelled", "faults", "images", "timing",
          "scenario")
"""The knob groups; ``PROFILE/GROUP`` keeps only that group of a profile (a fault alone),
``PROFILE/GROUP+GROUP`` those groups."""


def load_profile(spec: str | Path | Profile = "exact") -> Profile:
    """A built-in profile by name (:data:`BUILTIN`), a YAML file holding one profile, or
    ``FILE:NAME`` for one of several under ``profiles:``; ``PROFILE/GROUP`` (``harsh/cameras``)
    keeps only that knob group of a built-in profile, the rest ``exact`` (one fault alone), and
    ``PROFILE/GROUP+GROUP`` (``harsh/images+scenario``) those groups together."""
    if isinstance(spec, Profile):
        return spec
    text = str(spec)
    base, _, group = text.partition("/")
    if base in BUILTIN and group:
        groups = group.split("+")
        for g in groups:
            if g not in GROUPS:
                raise ProfileError(text, "<group>", g, f"one of {', '.join(GROUPS)}, joined "
                                   "by + for several")
        whole = _from_file(BUILTIN_FILE, base)
        return Profile(name=f"{base}-{group}", file=whole.file,
                       description=f"only the {' and '.join(groups)} of {base}",
                       sources=whole.sources, **{g: getattr(whole, g) for g in groups})
    if text in BUILTIN:
        return _from_file(BUILTIN_FILE, text)
    path, _, name = text.rpartition(":") if ":" in text and not Path(text).exists() else (
        text, "", "")
    if not Path(path).is_file():
        raise ProfileError(text, "<file>", text, f"a built-in profile ({', '.join(BUILTIN)}) or "
                           "an existing YAML file (FILE or FILE:NAME)")
    return _from_file(Path(path), name or None)


def _from_file(path: Path, name: str | None) -> Profile:
    file = str(path)
    raw = load_yaml(read_cell_text(path), file)
    if not isinstance(raw, dict):
        raise ProfileError(file, "<root>", raw, "a mapping: one profile, or profiles: {NAME: ...}")
    field = "<root>"
    if "profiles" in raw:
        profiles = raw["profiles"]
        if not isinstance(profiles, dict) or not profiles:
            raise ProfileError(file, "profiles", profiles, "a mapping of profile names")
        if name is None and len(profiles) != 1:
            raise ProfileError(file, "profiles", sorted(profiles),
                               "one profile, or FILE:NAME to choose one")
        name = name or next(iter(profiles))
        if name not in profiles:
            raise ProfileError(file, "profiles", name, f"one of {', '.join(map(str, profiles))}")
        raw, field = profiles[name] or {}, f"profiles.{name}"
    elif name is not None:
        raise ProfileError(file, "profiles", name, "a profiles: mapping to choose NAME from")
    if not isinstance(raw, dict):
        raise ProfileError(file, field, raw, "a mapping of knob groups")
    try:
        return Profile.model_validate({**raw, "name": name or path.stem, "file": file})
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in err["loc"] if not str(p).startswith("function-"))
        where = f"{field}.{loc}" if field != "<root>" else loc
        raise ProfileError(file, where, err.get("input"), err["msg"]) from exc
