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


class Distribution(_Strict):
    """How a knob is drawn: ``fixed`` (``value``), ``normal`` (``mean``, ``sigma`` >= 0) or
    ``uniform`` (``low`` <= ``high``)."""

    dist: Literal["fixed", "normal", "uniform"]
    value: Finite = 0.0
    mean: Finite = 0.0
    sigma: NonNegative = 0.0
    low: Finite = 0.0
    high: Finite = 0.0

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

    position_mm: Knob = ZERO
    rotation_deg: Knob = ZERO
    focal_percent: Knob = ZERO
    principal_point_px: Knob = ZERO
    distortion_k1: Knob = ZERO


class RobotKnobs(_Strict):
    """Per joint: encoder zero offsets (deg revolute, mm prismatic); per link: errors of the DH
    lengths a and d, or of a URDF joint origin per axis (mm); the base pose's position (mm, per
    axis) and rotation (deg, per axis); the measurement noise's standard deviation (rad, m) and
    the encoders' resolution (deg, mm; 0: none)."""

    encoder_offset_deg: Knob = ZERO
    encoder_offset_mm: Knob = ZERO
    link_length_mm: Knob = ZERO
    base_position_mm: Knob = ZERO
    base_rotation_deg: Knob = ZERO
    joint_noise_rad: NonNegative = 1e-4
    joint_noise_m: NonNegative = 1e-4
    encoder_resolution_deg: NonNegative = 0.0
    encoder_resolution_mm: NonNegative = 0.0


class ServoKnobs(_Strict):
    """Every joint's position servo: bandwidth (Hz; 0: ideal, no lag), damping ratio, velocity
    (deg/s, also mm/s for a prismatic joint) and acceleration (deg/s^2, mm/s^2) limits; and
    what moves the joints: ``analytic`` (the servo's own second-order loop in a kinematic
    world) or ``mujoco`` (MuJoCo's position actuators on the joints' rotor inertia, with the
    acceleration limit as a torque limit, contacts pushing back; needs a bandwidth); whether
    the drives feed the set-point's velocity forward (``velocity_feedforward``: a ramp is then
    followed without the steady lag ``2 damping / (2 pi bandwidth)`` times its speed)."""

    bandwidth_hz: NonNegative = 0.0
    damping: Annotated[float, BeforeValidator(_no_bool), Field(gt=0, allow_inf_nan=False)] = 1.0
    max_velocity_deg_s: Annotated[float, Field(gt=0)] = math.inf
    max_acceleration_deg_s2: Annotated[float, Field(gt=0)] = math.inf
    actuators: Literal["analytic", "mujoco"] = "analytic"
    velocity_feedforward: Annotated[bool, Field(strict=True)] = False

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

    part_size_mm: Knob = ZERO
    gripper_size_mm: Knob = ZERO
    grasp_seat_mm: Knob = ZERO
    grasp_seat_deg: Knob = ZERO
    slip_mm_s: Knob = ZERO
    support_height_mm: Knob = ZERO


class UnmodelledKnobs(_Strict):
    """Bodies the cell file does not know: a box left near the part (its probability per run,
    its size per axis, mm) and an operator's forearm reaching across a camera's line of sight to
    the part (probability per run, when it arrives and how long it stays, s; across which
    camera: ``forearm_camera``, its index in the cell file, -1: drawn)."""

    box_probability: Probability = 0.0
    box_size_mm: Knob = Distribution(dist="uniform", low=40.0, high=120.0)
    forearm_probability: Probability = 0.0
    forearm_start_s: Knob = Distribution(dist="uniform", low=5.0, high=40.0)
    forearm_duration_s: Knob = Distribution(dist="uniform", low=1.0, high=4.0)
    forearm_camera: Annotated[int, Field(strict=True, ge=-1)] = -1


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

    kidnap_probability: Probability = 0.0
    kidnap_time_s: Knob = Distribution(dist="uniform", low=3.0, high=6.0)
    kidnap_blind_s: Annotated[float, Field(gt=0, allow_inf_nan=False)] = 1.0
    kidnap_distance_mm: Knob = Distribution(dist="uniform", low=100.0, high=300.0)
    kidnap_direction_deg: Knob = Distribution(dist="uniform", low=0.0, high=360.0)
    kidnap_turn_deg: Knob = Distribution(dist="uniform", low=-45.0, high=45.0)
    knock_probability: Probability = 0.0
    knock_camera: Annotated[int, Field(strict=True, ge=-1)] = -1
    knock_time_s: Knob = Distribution(dist="uniform", low=15.0, high=30.0)
    knock_shift_mm: Knob = Distribution(dist="fixed", value=20.0)
    knock_rotation_deg: Knob = Distribution(dist="fixed", value=1.0)


class ImageKnobs(_Strict):
    """What the camera does to the image (:mod:`cellsight.world.images`): read noise (grey
    levels), conversion gain for shot noise (DN per electron), slow gain drift (% amplitude,
    period s), defocus blur (px), vignetting (fraction lost in the corners), JPEG quality (0:
    none), exposure time (ms: motion blur of what moves while the shutter is open; 0: none)
    and interlaced fields (the even rows exposed 20 ms before the odd ones)."""

    read_noise_dn: NonNegative = 0.0
    shot_dn_per_e: NonNegative = 0.0
    gain_drift_percent: NonNegative = 0.0
    gain_period_s: Annotated[float, Field(gt=0, allow_inf_nan=False)] = 30.0
    defocus_px: NonNegative = 0.0
    vignetting: Annotated[float, Field(ge=0, lt=1)] = 0.0
    jpeg_quality: Annotated[int, Field(strict=True, ge=0, le=100)] = 0
    exposure_ms: NonNegative = 0.0
    interlaced: Annotated[bool, Field(strict=True)] = False


class TimingKnobs(_Strict):
    """From exposure to the planner: latency (ms) with Gaussian jitter per frame (ms), and the
    share of frames lost (%); each camera's trigger skew (ms, drawn once per camera; its
    absolute value, at most a vision period less a control step: that camera exposes this long
    before the frame's time, as unsynchronised cameras do)."""

    latency_ms: NonNegative = 0.0
    latency_jitter_ms: NonNegative = 0.0
    drop_percent: Annotated[float, BeforeValidator(_no_bool), Field(ge=0, le=100)] = 0.0
    trigger_skew_ms: Knob = ZERO


class ScenarioKnobs(_Strict):
    """What the seed draws of the experiment itself: the part's start position (mm, x and y)
    and yaw (deg), the conveyor's speed (% of the cell file's) and direction (deg), and, in
    experiment 3, the crossing robot's timing (s, all waypoints together) and poses (deg, per
    joint, all waypoints together)."""

    part_position_mm: Knob = ZERO
    part_yaw_deg: Knob = ZERO
    conveyor_speed_percent: Knob = ZERO
    conveyor_direction_deg: Knob = ZERO
    crossing_time_s: Knob = ZERO
    crossing_joint_deg: Knob = ZERO


class Profile(_Strict):
    """One realism profile (module docstring). ``name`` and ``file`` say where it came from."""

    name: str = "exact"
    file: str = "<built-in>"
    description: str = ""
    sources: list[str] = Field(default_factory=list)
    cameras: CameraKnobs = CameraKnobs()
    robots: RobotKnobs = RobotKnobs()
    servo: ServoKnobs = ServoKnobs()
    geometry: GeometryKnobs = GeometryKnobs()
    unmodelled: UnmodelledKnobs = UnmodelledKnobs()
    faults: FaultKnobs = FaultKnobs()
    images: ImageKnobs = ImageKnobs()
    timing: TimingKnobs = TimingKnobs()
    scenario: ScenarioKnobs = ScenarioKnobs()


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
