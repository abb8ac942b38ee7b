"""Every field of the cell file's, the realism profile's and ``metrics.json``'s schemas says what
it is and its unit (``description=``, ``json_schema_extra={"unit": ...}``), so that the reference
pages can be generated from the models alone; and documenting them changed no behaviour."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
import yaml
from pydantic import BaseModel, ValidationError

from cellsight.model.experiments_schema import (
    ConveyorSpec,
    CrossingSpec,
    ExperimentsSpec,
    PassingSpec,
    WaypointSpec,
)
from cellsight.model.schema import (
    BoxSpec,
    CalibrationFileSpec,
    CameraSpec,
    CellSpec,
    FingersSpec,
    GripperSpec,
    HandEyeSpec,
    LinkSpec,
    LookAtSpec,
    MeshSpec,
    PoseSpec,
    PrismSpec,
    RobotSpec,
    SegmentSpec,
    SolidSpec,
    StaticSpec,
    UrdfSpec,
    WorkpieceSpec,
)
from cellsight.realism.profile import (
    CameraKnobs,
    Distribution,
    FaultKnobs,
    GeometryKnobs,
    ImageKnobs,
    Profile,
    RobotKnobs,
    ScenarioKnobs,
    ServoKnobs,
    TimingKnobs,
    UnmodelledKnobs,
    load_profile,
)
from cellsight.runfolder.metric_sections import PassingFigures, PhaseAccuracy, PickFigures
from cellsight.runfolder.metrics import RunMetrics

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "docs" / "gen"))
from reference import models_of  # noqa: E402  the reference pages' walk over the models

DATA = Path(__file__).resolve().parent.parent / "cellsight" / "data"
CELL_FILES = sorted(p for p in DATA.glob("*.yaml")
                    if isinstance(d := yaml.safe_load(p.read_text()), dict) and "cameras" in d)
ROOTS = (CellSpec, Profile, RunMetrics)

# A knob's or a figure's unit is in its name: the longest matching suffix wins.
SUFFIX_UNITS = (("_dn_per_e", "DN/e-"), ("_deg_s2", "deg/s^2"), ("_deg_s", "deg/s"),
                ("_mm_s", "mm/s"), ("_percent", "%"), ("_deg", "deg"), ("_rad", "rad"),
                ("_hz", "Hz"), ("_ms", "ms"), ("_mm", "mm"), ("_px", "px"), ("_dn", "DN"),
                ("_s", "s"), ("_m", "m"))


def _fields() -> list[tuple[type[BaseModel], str]]:
    return [(model, name) for root in ROOTS for model in models_of(root)
            for name in model.model_fields]


def _unit(model: type[BaseModel], name: str) -> str:
    extra = model.model_fields[name].json_schema_extra
    return extra.get("unit", "") if isinstance(extra, dict) else ""


def test_the_walk_reaches_every_model_of_the_three_schemas():
    cell = {PoseSpec, BoxSpec, PrismSpec, SegmentSpec, MeshSpec, SolidSpec, LinkSpec, GripperSpec,
            FingersSpec,
            UrdfSpec, RobotSpec, WorkpieceSpec, StaticSpec, LookAtSpec, CalibrationFileSpec,
            HandEyeSpec, CameraSpec, ConveyorSpec, PassingSpec, WaypointSpec, CrossingSpec,
            ExperimentsSpec,
            CellSpec}
    profile = {Profile, Distribution, CameraKnobs, RobotKnobs, ServoKnobs, GeometryKnobs,
               UnmodelledKnobs, FaultKnobs, ImageKnobs, TimingKnobs, ScenarioKnobs}
    assert set(models_of(CellSpec)) == cell
    assert set(models_of(Profile)) == profile
    nested = [RunMetrics, PhaseAccuracy, PickFigures, PassingFigures]
    assert models_of(RunMetrics) == nested


@pytest.mark.parametrize(("model", "name"), _fields(),
                         ids=lambda x: x if isinstance(x, str) else x.__name__)
def test_every_field_has_a_description_and_a_unit(model: type[BaseModel], name: str):
    field = model.model_fields[name]
    assert isinstance(field.description, str) and field.description.strip(), \
        f"{model.__name__}.{name}: no description"
    assert _unit(model, name).strip(), f"{model.__name__}.{name}: no unit"


@pytest.mark.parametrize(("model", "name", "unit"), [
    (PoseSpec, "xyz", "m"), (PoseSpec, "rpy", "rad"), (BoxSpec, "size", "m"),
    (LinkSpec, "alpha", "rad"), (LinkSpec, "qlim", "rad (m for a prismatic joint)"),
    (RobotSpec, "home", "rad (m for a prismatic joint)"), (GripperSpec, "max_opening", "m"),
    (CameraSpec, "fx", "px"), (CameraSpec, "width", "px"), (CameraSpec, "lens_mm", "mm"),
    (CameraSpec, "name", "-"), (SolidSpec, "closed", "-"), (ConveyorSpec, "speed", "m/s"),
    (ConveyorSpec, "t_start", "s"), (WaypointSpec, "t", "s"),
    (CameraKnobs, "rotation_deg", "deg"), (CameraKnobs, "focal_percent", "%"),
    (ServoKnobs, "bandwidth_hz", "Hz"), (ServoKnobs, "max_acceleration_deg_s2", "deg/s^2"),
    (ImageKnobs, "shot_dn_per_e", "DN/e-"), (UnmodelledKnobs, "box_probability", "-"),
    (RunMetrics, "position_rmse_mm", "mm"), (RunMetrics, "orientation_rmse_deg", "deg"),
    (RunMetrics, "seed", "-"),
])
def test_units(model: type[BaseModel], name: str, unit: str):
    assert _unit(model, name) == unit


@pytest.mark.parametrize(("model", "name"), [
    (m, n) for root in (Profile, RunMetrics) for m in models_of(root) for n in m.model_fields
    if any(n.endswith(s) for s, _ in SUFFIX_UNITS)], ids=lambda x: getattr(x, "__name__", x))
def test_a_unit_in_the_name_is_the_fields_unit(model: type[BaseModel], name: str):
    """Knobs and figures carry their unit in their name (``_mm``, ``_percent``, ...)."""
    expected = next(unit for suffix, unit in SUFFIX_UNITS if name.endswith(suffix))
    assert _unit(model, name) == expected


def test_units_reach_the_json_schema():
    """A documentation generator reading the JSON schema finds the same units and text."""
    defs = CellSpec.model_json_schema()["$defs"]
    assert defs["PoseSpec"]["properties"]["xyz"]["unit"] == "m"
    assert defs["ConveyorSpec"]["properties"]["speed"]["unit"] == "m/s"
    assert defs["CameraSpec"]["properties"]["fx"]["description"]
    knobs = Profile.model_json_schema()["$defs"]["CameraKnobs"]["properties"]
    assert knobs["rotation_deg"]["unit"] == "deg"
    assert RunMetrics.model_json_schema()["properties"]["position_rmse_mm"]["unit"] == "mm"


# ---- the behaviour is the one before the fields were documented ------------------------------


def test_cell_defaults():
    pose = PoseSpec()
    assert pose.xyz == [0.0, 0.0, 0.0] and pose.rpy == [0.0, 0.0, 0.0]
    assert PoseSpec().xyz is not pose.xyz  # every instance its own list
    assert BoxSpec(size=[1, 2, 3]).center == [0.0, 0.0, 0.0]
    assert PrismSpec(polygon=[[0, 0], [1, 0], [0, 1]], height=1).z0 == 0.0
    assert SegmentSpec(start=[0, 0, 0], end=[1, 0, 0], width=0.1).height is None
    assert MeshSpec(file="a.stl").scale == 1.0
    solid = SolidSpec(box={"size": [1, 1, 1]})
    assert solid.closed is True and solid.pose is None and solid.features is None
    link = LinkSpec()
    assert (link.a, link.alpha, link.d, link.theta) == (0.0, 0.0, 0.0, 0.0)
    assert link.kind == "revolute" and link.qlim == [-math.pi, math.pi] and link.solids == []
    urdf = UrdfSpec(file="robot.urdf")
    assert urdf.geometry == "collision" and urdf.flange is None and urdf.scale == 1.0
    assert UrdfSpec(file="robot.urdf", scale="inch").metres == pytest.approx(0.0254)
    gripper = GripperSpec(palm=[solid], jaw=solid, max_opening=0.05)
    assert gripper.mount == PoseSpec() and gripper.tcp == [0.0, 0.0, 0.0]
    robot = RobotSpec(name="R", links=[{}], home=[0.0])
    assert robot.base == PoseSpec() and robot.base_solids == [] and robot.urdf is None
    assert robot.tool is None and robot.final is None
    assert LookAtSpec(eye=[1, 0, 0], target=[0, 0, 0]).up == [0.0, 0.0, 1.0]
    assert ConveyorSpec(points=[[0, 0], [1, 0]], speed=0.1).t_start == 0.0
    assert ExperimentsSpec() == ExperimentsSpec(robot=None, workpiece=None, conveyor=None,
                                                crossing=None)
    cell = CellSpec(cameras=[{"name": "c", "width": 4, "height": 3, "fx": 2, "pose": {}}])
    assert cell.name == "cell" and cell.packages == {} and cell.robots == []
    assert cell.workpieces == [] and cell.static == [] and cell.experiments is None
    camera = cell.cameras[0]
    assert camera.calibration is None and camera.fy is None and camera.dist is None


def test_profile_and_metrics_defaults():
    servo = ServoKnobs()
    assert servo.bandwidth_hz == 0.0 and servo.damping == 1.0
    assert servo.max_velocity_deg_s == math.inf and servo.max_acceleration_deg_s2 == math.inf
    assert servo.actuators == "analytic" and servo.velocity_feedforward is False
    robots = RobotKnobs()
    assert robots.joint_noise_rad == 1e-4 and robots.joint_noise_m == 1e-4
    assert robots.encoder_offset_deg == Distribution(dist="fixed")
    assert ImageKnobs().gain_period_s == 30.0 and ImageKnobs().jpeg_quality == 0
    assert UnmodelledKnobs().box_size_mm == Distribution(dist="uniform", low=40.0, high=120.0)
    assert UnmodelledKnobs().forearm_camera == -1
    faults = FaultKnobs()
    assert faults.kidnap_blind_s == 1.0 and faults.knock_camera == -1
    assert faults.knock_shift_mm == Distribution(dist="fixed", value=20.0)
    assert faults.kidnap_time_s == Distribution(dist="uniform", low=3.0, high=6.0)
    assert TimingKnobs().drop_percent == 0.0 and ScenarioKnobs().part_yaw_deg.zero
    profile = Profile()
    assert (profile.name, profile.file, profile.description, profile.sources) == (
        "exact", "<built-in>", "", [])
    assert profile == load_profile("exact").model_copy(
        update={"name": "exact", "file": "<built-in>", "description": ""})
    lab = load_profile("lab")
    assert lab.servo.bandwidth_hz == 8.0 and lab.cameras.position_mm.sigma == 1.0
    metrics = RunMetrics()
    assert metrics.metrics_version == 0 and metrics.seed is None and metrics.phases is None


def test_validation_is_unchanged():
    with pytest.raises(ValidationError, match="a number, not a boolean"):
        PoseSpec(xyz=[True, 0.0, 0.0])
    with pytest.raises(ValidationError, match="Extra inputs are not permitted"):
        PoseSpec(xyzw=[0.0, 0.0, 0.0])
    with pytest.raises(ValidationError):
        SolidSpec(box={"size": [1, 1, 1]}, closed=1)  # strict: 1 is not true
    with pytest.raises(ValidationError, match="exactly one of box, prism"):
        SolidSpec()
    with pytest.raises(ValidationError, match="qlim must be"):
        LinkSpec(qlim=[1.0, 0.0])
    with pytest.raises(ValidationError, match="give exactly one of pose, look_at or hand_eye"):
        CameraSpec(name="c", width=4, height=3, fx=2)
    with pytest.raises(ValidationError, match="not a boolean"):
        CameraKnobs(position_mm=True)
    with pytest.raises(ValidationError, match="actuators mujoco needs bandwidth_hz > 0"):
        ServoKnobs(actuators="mujoco")
    with pytest.raises(ValidationError):
        RunMetrics.model_validate({"seed": "three"})
    assert RunMetrics.model_validate({"seed": 3, "unknown": [1]}).model_extra == {"unknown": [1]}
    assert CameraKnobs(position_mm=2).position_mm == Distribution(dist="fixed", value=2.0)


@pytest.mark.parametrize("path", CELL_FILES, ids=lambda p: p.name)
def test_builtin_cell_files_validate_as_before(path: Path):
    raw = yaml.safe_load(path.read_text())
    spec = CellSpec.model_validate(raw)
    dump = spec.model_dump()
    assert CellSpec.model_validate(dump).model_dump() == dump
    assert [c.name for c in spec.cameras] == [c["name"] for c in raw["cameras"]]
    assert [r.name for r in spec.robots] == [r["name"] for r in raw.get("robots", [])]
    for robot, entry in zip(spec.robots, raw.get("robots", []), strict=True):
        assert robot.home == [float(q) for q in entry["home"]]
        assert robot.base.xyz == [float(v) for v in entry.get("base", {}).get("xyz", [0, 0, 0])]
