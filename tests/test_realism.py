"""The realistic world (issue 21): each knob changes the world and not the model, against an
independent oracle (rendered images, forward kinematics, the servo's analytic response,
MuJoCo's contacts); bad profiles are refused with one line naming the file and the field."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from cellsight import load_cell
from cellsight.camera import camera_from_lens
from cellsight.experiments.scenario import scenario
from cellsight.experiments.sensors import IdealExtractor, IdealView
from cellsight.geometry.transforms import transform_points
from cellsight.occlusion.backends import visibility_predictor
from cellsight.realism import FrameClock, ProfileError, draw_world, load_profile
from cellsight.realism.profile import Profile, TimingKnobs
from cellsight.world import World
from cellsight.world.images import ImageEffects, Imager
from cellsight.world.imperfections import IDEAL, Imperfections
from cellsight.world.mjcf import GROUP_STATIC, tcp_site_name
from cellsight.world.servo import JointServo, ServoParams


@pytest.fixture(scope="module")
def cell():
    return load_cell()


def _profile(tmp_path: Path, body: dict, name: str = "p.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(body))
    return path


# ---- the exact world is the model --------------------------------------------------------


def test_exact_world_is_the_cell_file(cell):
    d = draw_world("exact", cell, 7)
    assert d.record == {} and d.errors == IDEAL or _same_errors(d.errors, IDEAL)
    for a, b in zip(d.cell.cameras, cell.cameras, strict=True):
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.T_base_cam, b.T_base_cam)
        assert a.dist is None and b.dist is None
    for a, b in zip(d.cell.robots, cell.robots, strict=True):
        q = a.home
        np.testing.assert_array_equal(a.tcp_pose(q), b.tcp_pose(q))
    np.testing.assert_array_equal(d.cell.workpieces[0].solid.vertices,
                                  cell.workpieces[0].solid.vertices)
    base = scenario(cell, 3)
    shifted = scenario(cell, 3, d.scenario)
    np.testing.assert_array_equal(base.conveyor.points, shifted.conveyor.points)
    assert base.conveyor.speed == shifted.conveyor.speed


def _same_errors(a: Imperfections, b: Imperfections) -> bool:
    return (all(not np.any(v) for v in a.encoder_offsets.values()) and a.servo == b.servo
            and a.noise_rad == b.noise_rad and a.images is None and not a.intruders
            and np.array_equal(a.grasp_seat, b.grasp_seat) and a.slip_m_s == 0)


def test_same_seed_same_draws_other_seed_other_scenario(cell):
    a, b, c = (draw_world("lab", cell, s) for s in (4, 4, 5))
    assert a.record == b.record and a.record != c.record
    assert "scenario.part_position_mm[part]" in a.record
    assert not np.allclose(a.scenario.shift, c.scenario.shift)
    sa, sc = scenario(cell, 3, a.scenario), scenario(cell, 3, c.scenario)
    assert sa.conveyor.speed != sc.conveyor.speed
    assert not np.allclose(sa.conveyor.points, sc.conveyor.points)
    np.testing.assert_allclose(sa.conveyor.points[0],
                               cell.experiments.conveyor_points[0] + a.scenario.shift)


def test_a_knob_draws_the_same_alone_and_in_the_whole_profile(cell, tmp_path):
    alone = _profile(tmp_path, {"cameras": {"position_mm": {"dist": "normal", "sigma": 3.0}}})
    one = draw_world(load_profile(alone), cell, 11).record
    whole = draw_world("harsh", cell, 11).record
    for key, value in one.items():
        assert whole[key] == value


# ---- each knob moves the world, never the model --------------------------------------------


def _bright_centroid(image: np.ndarray, centre: np.ndarray, half: int = 70) -> np.ndarray:
    """Centroid (u, v) of the bright part's pixels in a window around ``centre``."""
    u, v = np.round(centre).astype(int)
    window = image[v - half:v + half, u - half:u + half]
    rows, cols = np.nonzero(window > 200)
    return np.array([cols.mean() + u - half, rows.mean() + v - half])


def test_camera_extrinsic_error_moves_the_rendered_part_by_its_projection(cell, tmp_path):
    """2 mm along each camera axis: the part's blob in the rendered image moves by the pinhole
    projection of that shift (written out here, not the camera code), while the tracker's
    camera stays the cell file's."""
    path = _profile(tmp_path, {"cameras": {"position_mm": 2.0}})
    d = draw_world(load_profile(path), cell, 0)
    cam, built = cell.cameras[0], d.cell.cameras[0]
    np.testing.assert_allclose(np.linalg.inv(cam.T_base_cam) @ built.T_base_cam[:, 3],
                               [2e-3, 2e-3, 2e-3, 1.0], atol=1e-12)
    np.testing.assert_array_equal(load_cell().cameras[0].T_base_cam, cam.T_base_cam)
    part = cell.workpieces[0]
    points = part.feature_points @ part.T_base_part[:3, :3].T + part.T_base_part[:3, 3]
    p = (np.linalg.inv(cam.T_base_cam) @ np.c_[points, np.ones(len(points))].T)[:3].T
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]

    def pinhole(q):
        return np.c_[fx * q[:, 0] / q[:, 2] + cx, fy * q[:, 1] / q[:, 2] + cy]

    expected = (pinhole(p - 2e-3) - pinhole(p)).mean(axis=0)
    centre = pinhole(p).mean(axis=0)
    before = _bright_centroid(World(cell).render()[0], centre)
    after = _bright_centroid(World(d.cell).render()[0], centre)
    assert np.linalg.norm(expected) > 2.0
    np.testing.assert_allclose(after - before, expected, atol=0.25)


def test_encoder_offsets_and_resolution_are_in_the_readings_not_the_motion(cell):
    offset = np.radians([0.5, -0.2, 0.1, 0.0, 0.3, -0.4, 0.2])
    offset[0] = 0.002  # the track is prismatic: m
    errors = Imperfections(encoder_offsets={"R7AX": offset}, noise_rad=0.0, noise_m=0.0,
                           quantum_rad=math.radians(0.01))
    world = World(cell, errors=errors)
    robot = cell.robot("R7AX")
    np.testing.assert_allclose(world.true_joints()["R7AX"], robot.home - offset, atol=1e-12)
    reading = world.measured_joints()["R7AX"]
    assert np.all(np.abs(reading - robot.home) <= math.radians(0.01) / 2 + 1e-12)
    revolute = ~robot.chain.prismatic
    steps = reading[revolute] / math.radians(0.01)
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
    target = robot.home + 0.05
    world.step({"R7AX": target})
    np.testing.assert_allclose(world.true_joints()["R7AX"], target - offset, atol=1e-12)


def test_link_and_base_errors_move_the_world_robot_only(cell, tmp_path):
    path = _profile(tmp_path, {"robots": {"link_length_mm": 1.0, "base_position_mm": 2.0}})
    d = draw_world(load_profile(path), cell, 3)
    robot, built = cell.robot("R6AX"), d.cell.robot("R6AX")
    np.testing.assert_allclose(built.T_base_robot[:3, 3] - robot.T_base_robot[:3, 3],
                               robot.T_base_robot[:3, :3] @ np.full(3, 2e-3), atol=1e-12)
    for a, b in zip(built.chain.links, robot.chain.links, strict=True):
        assert a.a == pytest.approx(b.a + 1e-3) and a.d == pytest.approx(b.d + 1e-3)
    world = World(d.cell)
    T = world.scene.body_pose(world.scene.model.body("R6AX/6").id)
    np.testing.assert_allclose(T, built.link_poses(built.home)[-1], atol=1e-9)
    assert np.linalg.norm(T[:3, 3] - robot.link_poses(robot.home)[-1][:3, 3]) > 2e-3


def test_part_size_tolerance_changes_the_world_part(cell, tmp_path):
    path = _profile(tmp_path, {"geometry": {"part_size_mm": 0.5}})
    d = draw_world(load_profile(path), cell, 1)
    nominal, built = cell.workpieces[0].solid, d.cell.workpieces[0].solid
    np.testing.assert_allclose(np.ptp(built.vertices, axis=0) - np.ptp(nominal.vertices, axis=0),
                               5e-4, atol=1e-12)
    assert built.faces == nominal.faces and built.feature_names == nominal.feature_names


def test_a_support_built_higher_carries_the_part_up_with_it_in_the_world_only(cell, tmp_path):
    path = _profile(tmp_path, {"geometry": {"support_height_mm": {"dist": "normal",
                                                                  "sigma": 3.0}}})
    d = draw_world(load_profile(path), cell, 2)
    lift = {s.name: b.T_base_obj[2, 3] - s.T_base_obj[2, 3]
            for s, b in zip(cell.static, d.cell.static, strict=True)}
    for s in cell.static:
        assert lift[s.name] == pytest.approx(d.record[f"geometry.support_height_mm[{s.name}]"]
                                             * 1e-3, abs=1e-9)
    assert len({round(v, 9) for v in lift.values()}) == len(lift)  # drawn per object
    part, built = cell.workpieces[0], d.cell.workpieces[0]
    np.testing.assert_allclose(built.T_base_part - part.T_base_part,
                               np.pad([[lift["conveyor"]]], ((2, 1), (3, 0))), atol=1e-12)
    # MuJoCo's own geometry: the part stands on the world's belt, not the cell file's
    import mujoco  # after cellsight.world, which sets MUJOCO_GL

    world = World(d.cell)
    T = world.scene.body_pose(world.scene.model.body(part.name).id)
    np.testing.assert_allclose(T, built.T_base_part, atol=1e-9)
    bottom = transform_points(T, part.solid.vertices)
    low = bottom[np.argmin(bottom[:, 2])]
    groups = np.zeros(6, dtype=np.uint8)
    groups[GROUP_STATIC] = 1
    gap = mujoco.mj_ray(world.scene.model, world.scene.data, low + [0.0, 0.0, 0.01],
                        np.array([0.0, 0.0, -1.0]), groups, True, -1, np.zeros(1, np.int32))
    assert gap - 0.01 == pytest.approx(0.0, abs=1e-6)
    assert abs(lift["conveyor"]) > 1e-3  # the cell file's belt would be that far off


def test_an_arm_s_tcp_error_is_where_mujoco_puts_the_world_s_tcp(cell):
    """``WorldDraws.tcp_error``: where R7AX's TCP truly stands at HOME less where the cell
    file's arm puts it, against MuJoCo's own TCP site in the world built from the draws
    (``harsh``, seed 17: base, links, gripper and encoder offsets all drawn; 4.2 mm)."""
    d = draw_world("harsh", cell, 17)
    robot = cell.robot("R7AX")
    world = World(d.cell, errors=d.errors, initial_joints={robot.name: robot.home})
    q = world.true_joints()[robot.name]
    np.testing.assert_allclose(q, robot.home - d.errors.encoder_offsets[robot.name], atol=1e-12)
    site = world.scene.model.site(tcp_site_name(robot.name)).id
    expected = world.scene.site_pose(site)[:3, 3] - robot.tcp_pose(robot.home)[:3, 3]
    assert np.linalg.norm(expected) > 3e-3
    np.testing.assert_allclose(d.tcp_error(robot, robot.home), expected, atol=1e-7)


def test_unknown_forearm_hides_features_the_predictor_thinks_visible(cell, tmp_path):
    """harsh puts a forearm across a camera's line of sight: during its stay the ray-cast
    truth blames ``unknown.forearm`` for features the nominal predictor calls visible."""
    d = draw_world("harsh", cell, 0)
    arm = next(i for i in d.errors.intruders if i.name == "unknown.forearm")
    world = World(d.cell, errors=d.errors)
    while world.time < arm.t_in + 0.2:
        world.step()
    truth = world.true_views()["part"]
    blamed = [v for v in truth if "unknown.forearm" in v.reason]
    assert blamed, "the forearm hides nothing"
    predicted = visibility_predictor(cell).predict(world.true_joints(), world.true_part_poses())
    c = next(i for i, v in enumerate(truth) if "unknown.forearm" in v.reason)
    hidden = np.array([r == "unknown.forearm" for r in truth[c].reason])
    assert predicted["part"][c].visible[hidden].any()


def test_crossed_puts_the_forearm_across_camera_1_at_10_s(cell):
    """``crossed``: the forearm's camera is the profile's (index 0), not drawn, on every seed:
    the bar's centre lies on that camera's line of sight to the part, off the other's."""
    for seed in range(4):
        d = draw_world("crossed", cell, seed)
        arm = next(i for i in d.errors.intruders if i.name == "unknown.forearm")
        assert (arm.t_in, arm.t_out) == (10.0, 12.0)
        target = d.cell.workpieces[0].T_base_part[:3, 3] + [0.0, 0.0, 0.05]

        def off_line(cam, point=arm.T_in[:3, 3], target=target):
            sight = (cam.center - target) / np.linalg.norm(cam.center - target)
            return np.linalg.norm(np.cross(point - target, sight))

        assert off_line(d.cell.cameras[0]) < 1e-9 < 0.05 < off_line(d.cell.cameras[1])


def test_image_noise_matches_its_model_and_jpeg_and_vignetting_act():
    flat = np.full((200, 300), 128, np.uint8)
    effects = ImageEffects(read_noise_dn=1.5, shot_dn_per_e=0.05)
    out = Imager(effects, 0).apply([flat], 0.0)[0].astype(float)
    assert out.std() == pytest.approx(math.sqrt(1.5 ** 2 + 128 * 0.05 + 1 / 12), rel=0.05)
    dark = Imager(ImageEffects(vignetting=0.3), 0).apply([flat], 0.0)[0]
    assert dark[0, 0] == pytest.approx(128 * 0.7, abs=1) and dark[100, 150] >= 127
    jpeg = Imager(ImageEffects(jpeg_quality=30), 0).apply([np.tile(np.arange(300) % 256, (200, 1))
                                                          .astype(np.uint8)], 0.0)[0]
    assert 0 < np.abs(jpeg.astype(int) - np.arange(300) % 256).mean() < 10


def test_frame_clock_drops_and_delays_as_stated():
    clock = FrameClock(TimingKnobs(latency_ms=40, latency_jitter_ms=2, drop_percent=5), 3)
    frames = [clock.next() for _ in range(20000)]
    assert np.mean([f.dropped for f in frames]) == pytest.approx(0.05, abs=0.005)
    lat = np.array([f.latency_s for f in frames])
    assert lat.mean() == pytest.approx(0.040, abs=2e-4) and lat.std() == pytest.approx(0.002,
                                                                                        rel=0.05)
    assert FrameClock(TimingKnobs(), 3).ideal


# ---- the servo against its analytic response -----------------------------------------------


def test_servo_step_and_ramp_follow_the_second_order_response():
    dt, f = 1 / 500, 8.0
    wn = 2 * math.pi * f
    servo = JointServo(ServoParams(bandwidth_hz=f), np.zeros(1), dt)
    servo.target = np.ones(1)
    t = np.arange(1, 201) * dt
    q = np.array([servo.step()[0] for _ in t])
    analytic = 1 - (1 + wn * t) * np.exp(-wn * t)
    np.testing.assert_allclose(q, analytic, atol=1e-9)
    ramp = JointServo(ServoParams(bandwidth_hz=f), np.zeros(1), dt)
    v = 0.5
    for k in range(1, 1001):
        ramp.target = np.array([v * k * dt])
        ramp.step()
    assert v * 1000 * dt - ramp.q[0] == pytest.approx(2 * v / wn, rel=0.03)
    limited = JointServo(ServoParams(bandwidth_hz=f, max_velocity=0.1), np.zeros(1), dt)
    limited.target = np.ones(1)
    qs = np.array([limited.step()[0] for _ in range(500)])
    assert np.max(np.diff(qs)) <= 0.1 * dt + 1e-12


def test_servo_with_velocity_feedforward_follows_a_ramp_without_lag():
    """With the set-point's velocity fed forward, the ramp's steady lag 2 v / wn (1 cm here)
    is gone; the start of the ramp is a change of velocity, which the loop still takes
    ``1 - (1 + wn t) e^(-wn t)`` to follow (from rest, the error is ``v t e^(-wn t)``)."""
    dt, f, v = 1 / 500, 8.0, 0.5
    wn = 2 * math.pi * f
    ramp = JointServo(ServoParams(bandwidth_hz=f, velocity_feedforward=True), np.zeros(1), dt)
    errors = []
    for k in range(1, 1001):
        ramp.target = np.array([v * k * dt])
        ramp.step()
        errors.append(ramp.target[0] - ramp.q[0])
    t = np.arange(1, 1001) * dt
    np.testing.assert_allclose(errors, v * t * np.exp(-wn * t), atol=1e-9)
    assert abs(errors[-1]) < 1e-9 and 2 * v / wn > 0.009


def test_world_arm_lags_its_setpoints(cell):
    world = World(cell, errors=Imperfections(servo=ServoParams(bandwidth_hz=5.0), noise_rad=0.0,
                                             noise_m=0.0))
    home = cell.robot("R7AX").home
    target = home + 0.1
    world.step({"R7AX": target})
    lag = target - world.true_joints()["R7AX"]
    assert np.all(lag > 0.09)
    for _ in range(500):
        world.step({"R7AX": target})
    np.testing.assert_allclose(world.true_joints()["R7AX"], target, atol=1e-4)


def _actuated(**servo) -> Imperfections:
    return Imperfections(servo=ServoParams(mujoco=True, **servo), noise_rad=0.0, noise_m=0.0)


def test_mujoco_actuators_follow_the_servos_second_order_response(cell):
    """MuJoCo's position actuator on the wrist joint (its rotor and links, the gains set for
    both), integrated by mj_step: the step response and the ramp's lag of the analytic loop,
    the other joints held. The implicit integration of the actuator's damping (wn dt = 0.1)
    shortens the ramp's lag by 5 %."""
    f = 8.0
    wn = 2 * math.pi * f
    world = World(cell, errors=_actuated(bandwidth_hz=f))
    home = cell.robot("R7AX").home
    step = home.copy()
    step[6] += 0.1
    q = []
    for _ in range(200):
        world.step({"R7AX": step})
        q.append(world.true_joints()["R7AX"][6] - home[6])
    t = np.arange(1, 201) * world.dt_control
    analytic = 0.1 * (1 - (1 + wn * t) * np.exp(-wn * t))
    assert np.max(np.abs(np.array(q) - analytic)) < 0.002
    np.testing.assert_allclose(world.true_joints()["R7AX"][:6], home[:6], atol=1e-5)
    ramp = World(cell, errors=_actuated(bandwidth_hz=f))
    v = 0.5
    for k in range(1, 1001):
        target = home.copy()
        target[6] += v * k * ramp.dt_control
        ramp.step({"R7AX": target})
    lag = target[6] - ramp.true_joints()["R7AX"][6]
    assert lag == pytest.approx(2 * v / wn, rel=0.07)


def test_mujoco_actuators_with_velocity_feedforward_follow_a_ramp(cell):
    """The same ramp as above with the set-point's velocity fed forward (the actuator's
    set-point led by kv / kp times it): the lag falls from 2 v / wn (1 cm) to what the links'
    inertia and the integration leave, under a twentieth of it."""
    f, v = 8.0, 0.5
    wn = 2 * math.pi * f
    world = World(cell, errors=_actuated(bandwidth_hz=f, velocity_feedforward=True))
    home = cell.robot("R7AX").home
    for k in range(1, 1001):
        target = home.copy()
        target[6] += v * k * world.dt_control
        world.step({"R7AX": target})
    lag = target[6] - world.true_joints()["R7AX"][6]
    assert abs(lag) < 0.05 * 2 * v / wn


def test_a_joint_run_into_its_limit_overshoots_and_its_reading_is_accepted(cell):
    """A set-point that runs into a joint's limit at 2 rad/s and stops there at once, followed
    with the velocity fed forward: the joint overshoots by about v / (e w_n) (1.5e-2 rad at
    8 Hz), more than an encoder's offset, and the model still takes the reading (this broke
    `harsh` runs: "joint 6 = 2.2134 outside its limits")."""
    from cellsight.model.cell import JOINT_LIMIT_TOL

    f, v = 8.0, 2.0
    world = World(cell, errors=_actuated(bandwidth_hz=f, velocity_feedforward=True))
    robot = cell.robot("R7AX")
    limit = robot.chain.qlim[5, 1]
    q, over = robot.home.copy(), 0.0
    for k in range(1000):
        q[5] = min(robot.home[5] + v * world.dt_control * k, limit)
        world.step({"R7AX": q})
        over = max(over, world.true_joints()["R7AX"][5] - limit)
    assert over == pytest.approx(v / (math.e * 2 * math.pi * f), rel=0.1)
    assert 0.01 < over < JOINT_LIMIT_TOL
    reading = world.true_joints()["R7AX"].copy()
    reading[5] = limit + over
    np.testing.assert_array_equal(cell.snapshot({"R7AX": reading}).joints["R7AX"], reading)


def test_mujoco_actuators_limit_torque_and_velocity(cell):
    """A large step: the joint's acceleration stays within the torque limit's (the joint's
    inertia times the acceleration limit) and its speed within the velocity limit (clipped
    after each step: within one step's acceleration of it)."""
    a_max, v_max = math.radians(900.0), math.radians(150.0)
    world = World(cell, errors=_actuated(bandwidth_hz=8.0, max_velocity=v_max,
                                         max_acceleration=a_max))
    target = cell.robot("R7AX").home.copy()
    target[6] += 1.0
    q = []
    for _ in range(400):
        world.step({"R7AX": target})
        q.append(world.true_joints()["R7AX"][6])
    v = np.diff(q) / world.dt_control
    assert 0.9 * v_max < np.abs(v).max() <= v_max + a_max * world.dt_control * 1.01
    assert np.abs(np.diff(v[:20]) / world.dt_control).max() <= 1.1 * a_max


def test_lab_and_harsh_drive_the_joints_by_mujocos_actuators_with_feedforward(cell):
    """`lab` and `harsh` (and the profiles built on `lab`) move the joints by MuJoCo's
    actuators with the set-point's velocity fed forward, and report every overlap as a
    collision; `exact` keeps the ideal servo and its 1 mm threshold."""
    for name in ("lab", "harsh", "kidnap", "crossed", "ccir"):
        errors = draw_world(name, cell, 3).errors
        servo = errors.servo
        assert servo.mujoco and servo.velocity_feedforward and servo.bandwidth_hz > 0, name
        assert errors.collision_threshold_m == 0.0  # contacts push back: any overlap counts
    exact = draw_world("exact", cell, 3).errors
    assert exact.servo.ideal and exact.collision_threshold_m == 1e-3


def test_mujoco_contacts_push_the_arm_back(cell):
    """R6AX driven into the table: in the kinematic world it sinks 10 cm into it; with MuJoCo's
    actuators (`lab`'s torque and speed limits) the table stops it within a few centimetres,
    short of its set-point, and the contact is still reported."""
    down = cell.robot("R6AX").home.copy()
    down[1] += 1.2  # shoulder forward and down: the arm into the table
    depth = {}
    for mujoco in (False, True):
        world = World(cell, errors=_actuated(bandwidth_hz=8.0, max_velocity=math.radians(150),
                                             max_acceleration=math.radians(900))
                      if mujoco else IDEAL)
        for _ in range(600):
            world.step({"R6AX": down})
        hits = [h for h in world.collisions() if "table" in h["bodies"]]
        depth[mujoco] = max(h["depth_mm"] for h in hits)
        if mujoco:
            assert down[1] - world.true_joints()["R6AX"][1] > 0.05
    assert depth[False] > 50.0 and 1.0 < depth[True] < 25.0


# ---- collisions ----------------------------------------------------------------------------


def test_staged_crash_is_reported_and_a_quiet_cell_reports_none(cell):
    quiet = World(cell)
    for _ in range(50):
        quiet.step()
    assert quiet.collisions() == []
    world = World(cell)
    down = cell.robot("R6AX").home.copy()
    down[1] += 1.2  # shoulder forward and down: the arm into the table
    for _ in range(200):
        world.step({"R6AX": down})
    hits = world.collisions()
    assert hits and any(b.startswith("R6AX") for h in hits for b in h["bodies"])
    assert all(h["depth_mm"] > 1.0 for h in hits)


def test_a_carriage_out_of_line_with_its_track_rides_it(cell):
    """`harsh` seed 19 draws R7AX's base a little out of line with its track: driven 0.3 m
    along it, the carriage sinks into the track. Its base and carriage within 5 mm of the track
    at the start make a mount: the carriage arrives and no collision is counted (before, its
    contact's friction held it 26 cm short, and every grasp of the seed failed)."""
    d = draw_world("harsh", cell, 19)
    world = World(d.cell, seed=19, errors=d.errors)
    q = cell.robot("R7AX").home.copy()
    q[0] -= 0.31
    for _ in range(1500):
        world.step({"R7AX": q})
    assert abs(world.true_joints()["R7AX"][0] - q[0]) < 1e-3
    assert not [h for h in world.collisions() if "track" in h["bodies"]]


def test_a_flickering_contact_is_one_episode_and_old_reports_merge_alike(cell):
    """MuJoCo's contact list stood in by a script of when R6AX's wrist touches the table:
    touching 0-50 ms, apart 50-80 ms, touching again to 200 ms, apart, then again from 500 ms
    to 520 ms. Apart for less than APART_S is the same episode; the old one-episode-per-touch
    report merges into the same episodes."""
    from cellsight.world.contacts import APART_S, merge_episodes

    world = World(cell)
    monitor = world.contacts
    model = world.scene.model
    pair = tuple(sorted((model.geom("R6AX.link5").id, model.geom("table.1").id)))
    touching = [(0.0, 0.05), (0.08, 0.2), (0.5, 0.52)]
    t_now = [0.0]
    monitor._geom_pairs = lambda depth: ([(pair, 1e-4)] if any(a <= t_now[0] < b
                                                                for a, b in touching) else [])
    raw = []  # what one episode per touch would have said
    for k in range(400):
        t = t_now[0] = k * 0.002
        monitor.check(t)
        for a, b in touching:
            if abs(t - a) < 1e-9:
                raw.append({"bodies": ["R6AX.link5", "table"], "t_start_s": a, "t_end_s": b,
                            "depth_mm": 0.1})
    report = monitor.report()
    assert [(c["t_start_s"], c["t_end_s"]) for c in report] == [(0.0, 0.2), (0.5, 0.52)]
    assert 0.08 - 0.05 < APART_S < 0.5 - 0.2
    assert [(c["t_start_s"], c["t_end_s"]) for c in merge_episodes(raw)] == \
        [(c["t_start_s"], c["t_end_s"]) for c in report]


# ---- the honest ideal sensor ---------------------------------------------------------------


def test_ideal_sensor_returns_a_corner_or_nothing_for_a_hidden_feature():
    pixels = np.array([[[100.0, 100.0], [300.0, 300.0]]])
    visible = np.array([[False, True]])
    sensor = IdealExtractor(0.0, 0)
    plan = SimpleNamespace(features=np.array([0, 1]),  # the two fields the extractor reads
                           boxes=np.array([[84, 84, 117, 117], [284, 284, 317, 317]]))
    corners = np.array([[100.0, 100.0], [108.0, 95.0], [400.0, 5.0]])
    found = sensor.extract(0, IdealView(pixels[0], visible[0], corners), plan)
    np.testing.assert_allclose(found[0], [108.0, 95.0])  # the occluder's corner, not its own
    np.testing.assert_allclose(found[1], [300.0, 300.0])
    assert 0 not in sensor.extract(0, IdealView(pixels[0], visible[0], corners[:1]), plan)
    assert sensor.extract(0, None, plan) == {}


# ---- bad profiles --------------------------------------------------------------------------


@pytest.mark.parametrize("body, field", [
    ({"cameras": {"position_mmm": 1.0}}, "cameras.position_mmm"),
    ({"cameras": {"position_mm": {"dist": "normal", "sigma": -1.0}}}, "cameras.position_mm"),
    ({"robots": {"joint_noise_rad": float("nan")}}, "robots.joint_noise_rad"),
    ({"images": {"read_noise_dn": {"dist": "cauchy", "sigma": 1.0}}}, "images.read_noise_dn"),
    ({"geometry": {"part_size_mm": {"dist": "gamma"}}}, "geometry.part_size_mm"),
    ({"timing": {"drop_percent": 150}}, "timing.drop_percent"),
    ({"images": {"exposure_ms": -4.0}}, "images.exposure_ms"),
    ({"images": {"interlaced": "yes"}}, "images.interlaced"),
    ({"servo": {"actuators": "mujoco"}}, "servo"),
    ({"servo": {"actuators": "hydraulic", "bandwidth_hz": 8}}, "servo.actuators"),
])
def test_bad_profile_names_file_and_field(tmp_path, body, field):
    path = _profile(tmp_path, body)
    with pytest.raises(ProfileError) as err:
        load_profile(path)
    message = str(err.value)
    assert str(path) in message and field in message and "\n" not in message


def test_bad_profile_on_the_command_line_runs_nothing(tmp_path):
    path = _profile(tmp_path, {"profiles": {"mine": {"servo": {"bandwidth": 3}}}})
    out = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "cellsight.cli", "run", "1", "--realism",
                           f"{path}:mine", "--out", str(out), "--quiet"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and not out.exists()
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "profiles.mine.servo.bandwidth" in lines[0]


def test_builtin_profiles_load_and_lab_cites_its_sources():
    profiles = {name: load_profile(name) for name in ("exact", "lab", "harsh")}
    assert profiles["exact"] == Profile(name="exact", file=profiles["exact"].file,
                                        description=profiles["exact"].description)
    assert len(profiles["lab"].sources) >= 5
    assert profiles["harsh"].unmodelled.forearm_probability == 1.0
    assert profiles["harsh"].timing.drop_percent == 5.0


def test_exact_profile_world_steps_and_renders_as_the_default_world(cell):
    d = draw_world("exact", cell, 2)
    sc = scenario(cell, 3, d.scenario)
    a = World(cell, seed=2, conveyor=sc.conveyor, tasks=sc.tasks)
    b = World(d.cell, seed=2, conveyor=sc.conveyor, tasks=sc.tasks, errors=d.errors)
    for _ in range(40):
        a.step({"R7AX": cell.robot("R7AX").home + 0.01})
        b.step({"R7AX": cell.robot("R7AX").home + 0.01})
    for name in ("R7AX", "R6AX"):
        np.testing.assert_array_equal(a.measured_joints()[name], b.measured_joints()[name])
    for x, y in zip(a.render(), b.render(), strict=True):
        np.testing.assert_array_equal(x, y)


def test_camera_rotation_error_turns_the_camera_about_the_work_area(cell, tmp_path):
    """A calibration fitted in the work area: turning the camera about it leaves the work
    point's pixel where it was, and moves the optical centre by distance x angle."""
    path = _profile(tmp_path, {"cameras": {"rotation_deg": 0.1}})
    d = draw_world(load_profile(path), cell, 0)
    work = cell.workpieces[0].T_base_part[:3, 3]
    for cam, built in zip(cell.cameras, d.cell.cameras, strict=True):
        np.testing.assert_allclose(built.project(work[None]), cam.project(work[None]), atol=1e-6)
        moved = np.linalg.norm(built.center - cam.center)
        assert moved == pytest.approx(np.linalg.norm(cam.center - work) * math.radians(0.1)
                                      * math.sqrt(2), rel=0.3)


def test_held_part_predictor_agrees_with_the_ray_truth_from_every_side():
    """Issue 21, item 5: with the jaws closed on the part and the arm moving, the predictor at
    the true state and MuJoCo's rays agree on every feature, seen by 40 cameras around the held
    part (the run-level disagreements come from the tracker's pose error, not the model)."""
    from cellsight.geometry.transforms import invert_pose, look_at
    from cellsight.model import Cell

    base = load_cell()
    robot = base.robot("R7AX")
    T = robot.tcp_pose(robot.home) @ invert_pose(World(base).grippers.grasp_pose("part"))
    rng = np.random.default_rng(0)
    eyes = rng.normal(size=(40, 3))
    cams = [camera_from_lens(768, 576, look_at(T[:3, 3] + 1.2 * e / np.linalg.norm(e),
                                               T[:3, 3]), 16, 0.0083, name=f"c{i}")
            for i, e in enumerate(eyes)]
    cell = Cell(base.name, base.robots, base.workpieces, base.static, cams, base.source)
    world = World(cell)
    world.place_part("part", T)
    while world.time < 0.4:
        world.step({"R7AX": robot.home}, {"R7AX": 0.0})
    assert world.grasp("R7AX") is not None
    predictor = visibility_predictor(cell)
    checked = 0
    for k in range(8):
        q = robot.home + 0.03 * np.sin(np.arange(robot.n_joints) + k)
        for _ in range(5):
            world.step({"R7AX": q}, {"R7AX": 0.0})
        truth = world.true_views()["part"]
        pred = predictor.predict(world.true_joints(), world.true_part_poses(),
                                 world.jaw_openings())["part"]
        for t, p in zip(truth, pred, strict=True):
            inside = t.status == 0
            np.testing.assert_array_equal(p.visible[inside], t.visible[inside])
            checked += inside.sum()
    assert checked > 3000


def test_intrinsic_errors_are_absorbed_at_the_work_area_not_elsewhere(cell, tmp_path):
    """Calibrated with wrong intrinsics, the hand-eye result turns the camera so that the work
    area still projects right; 20 cm away the focal error shows."""
    path = _profile(tmp_path, {"cameras": {"principal_point_px": 5.0, "focal_percent": 1.0}})
    d = draw_world(load_profile(path), cell, 0)
    work = cell.workpieces[0].T_base_part[:3, 3]
    away = work + [0.2, 0.0, 0.1]
    for cam, built in zip(cell.cameras, d.cell.cameras, strict=True):
        assert built.K[0, 2] == cam.K[0, 2] + 5.0 and built.K[0, 0] == pytest.approx(
            1.01 * cam.K[0, 0])
        np.testing.assert_allclose(built.project(work[None]), cam.project(work[None]), atol=1e-6)
        assert np.linalg.norm(built.project(away[None]) - cam.project(away[None])) > 1.0
        np.testing.assert_allclose(built.center, cam.center, atol=1e-12)


def test_acquisition_search_visits_the_nominal_first_then_rings_outwards():
    from cellsight.tracking.acquisition import PnPAcquisition

    acq = PnPAcquisition(search_m=0.01, search_step_m=0.005)
    base = np.eye(4)
    offsets = [acq.guess(base, k)[:2, 3] for k in range(25)]
    np.testing.assert_array_equal(offsets[0], [0.0, 0.0])
    radii = [np.hypot(*o) for o in offsets]
    assert radii == sorted(radii) and len({tuple(np.round(o, 9)) for o in offsets}) == 25
    np.testing.assert_array_equal(acq.guess(base, 25), acq.guess(base, 0))
    assert max(radii) == pytest.approx(0.01 * math.sqrt(2))


@pytest.mark.slow
def test_same_seed_and_profile_give_identical_metrics(tmp_path):
    from cellsight.experiments import RunConfig, run_experiment

    def run(folder: str, seed: int) -> dict:
        m = run_experiment(RunConfig(3, tmp_path / folder, sensor="ideal", seed=seed,
                                     realism="harsh", duration=1.0, progress=False))
        return {k: v for k, v in m.items()
                if k not in ("wall_s", "timing_ms", "frames_sha256")}  # frames.csv: stage times

    a, b, c = run("a", 6), run("b", 6), run("c", 7)
    assert a == b and a["draws"] and a["realism"] == "harsh"
    assert c["draws"] != a["draws"]


def test_a_skewed_camera_is_exposed_before_the_frame(cell):
    """Camera 2 triggered 10 ms early sees the moving part where it was 10 ms before the
    frame (the ray-cast truth of that instant), camera 1 where it is at the frame."""
    from cellsight.experiments.exposure import Exposures
    from cellsight.experiments.plant import part_truth
    from cellsight.world import ConveyorPath

    path = ConveyorPath([(0.55, 0.0), (0.85, 0.0)], speed=0.2)
    world = World(cell, conveyor=path)
    exposures = Exposures(world, np.array([0.0, 0.010]), True, "part")
    t_frame, seen = 0.1, {}
    while world.time < t_frame - 1e-9:
        exposures.before_step(t_frame)
        if abs(world.time - (t_frame - 0.010)) < 1e-9:
            seen["early"] = part_truth(world, "part").pixels[1].copy()
        world.step()
    out = exposures.frame()
    now = part_truth(world, "part").pixels
    np.testing.assert_array_equal(out[0].pixels, now[0])
    np.testing.assert_array_equal(out[1].pixels, seen["early"])
    assert np.abs(out[1].pixels - now[1]).max() > 1.0  # 2 mm of conveyor travel
    assert exposures.stamps[0] is None and exposures.stamps[1] == pytest.approx(t_frame - 0.010)


def test_one_knob_group_alone_keeps_its_harsh_strength_and_nothing_else(cell):
    alone = load_profile("harsh/timing")
    harsh = load_profile("harsh")
    assert alone.timing == harsh.timing and alone.cameras == Profile().cameras
    d, whole = draw_world(alone, cell, 3), draw_world(harsh, cell, 3)
    assert d.record and all(k.startswith("timing.") for k in d.record)
    assert all(whole.record[k] == v for k, v in d.record.items())
    with pytest.raises(ProfileError, match="lighting"):
        load_profile("harsh/lighting")
    pair = load_profile("harsh/timing+images")
    assert pair.timing == harsh.timing and pair.images == harsh.images
    assert pair.cameras == Profile().cameras and pair.name == "harsh-timing+images"
    both = draw_world(pair, cell, 3).record
    assert all(whole.record[k] == v for k, v in both.items())
    assert {k.split(".")[0] for k in both} == {"timing", "images"}
    with pytest.raises(ProfileError, match="lighting"):
        load_profile("harsh/timing+lighting")


@pytest.mark.slow
def test_a_run_folder_replays_the_world_its_profile_drew(tmp_path):
    from cellsight.experiments import RunConfig, run_experiment
    from cellsight.runfolder import load_run

    for realism in ("lab", "exact"):
        run_experiment(RunConfig(1, tmp_path / realism, sensor="ideal", seed=4, realism=realism,
                                 duration=0.2, progress=False))
    lab, exact = load_run(tmp_path / "lab"), load_run(tmp_path / "exact")
    drawn = draw_world("lab", lab.cell, 4).cell
    for a, b in zip(lab.world_cell().cameras, drawn.cameras, strict=True):
        np.testing.assert_array_equal(a.T_base_cam, b.T_base_cam)
        assert not np.array_equal(a.T_base_cam, lab.cell.camera(a.name).T_base_cam)
    assert exact.world_cell() is exact.cell


def test_a_joint_at_its_limit_read_through_an_offset_encoder_is_accepted(cell):
    """An encoder offset on a joint standing at its limit reads beyond it: the model takes the
    reading (as read, not clipped); far beyond, it is still bad input."""
    from cellsight.errors import KinematicsError
    from cellsight.model.cell import JOINT_LIMIT_TOL

    robot = cell.robot("R7AX")
    q = robot.home.copy()
    q[5] = robot.chain.qlim[5, 1] + math.radians(0.1)
    snap = cell.snapshot({"R7AX": q})
    np.testing.assert_array_equal(snap.joints["R7AX"], q)
    q[5] = robot.chain.qlim[5, 1] + 2 * JOINT_LIMIT_TOL
    with pytest.raises(KinematicsError, match="joint 6"):
        cell.snapshot({"R7AX": q})


def test_mujoco_rays_agree_with_the_predictor_on_random_held_and_placed_parts():
    """Issue 21, item 5, the scale bench's disagreements: MuJoCo's rays hit the world's floor
    plane (not in the cell file) under parts that random joints carried below it. Random held
    parts now stay above the floor, and MuJoCo and the predictor (both with a 0.1 mm surface
    tolerance, MuJoCo's along the ray, the predictor's across it) agree on every ray in view
    except where the ray meets a surface within 2 mm of the feature (a feature on or a hair
    inside another solid, e.g. a random held part pressed 0.05 mm into a jaw): those are
    ambiguous, counted, and rare."""
    import mujoco

    from cellsight.occlusion.scale_cells import scale_cell
    from cellsight.occlusion.scenarios import random_snapshots
    from cellsight.world.replay import ReplayWorld

    tol = 1e-4
    cell = scale_cell(3, 3, 2)
    snapshots = random_snapshots(cell, 40, seed=7)
    predictor = visibility_predictor(cell, near_px=0.0, surface_tolerance=tol)
    world = ReplayWorld(cell)
    model, data = world.scene.model, world.scene.data
    floor = model.geom("floor").id
    checked, held, ambiguous = 0, 0, 0
    for s in snapshots:
        world.show_state(s.joints, s.part_poses, s.openings)
        views = predictor.predict_snapshot(s)
        for part in cell.workpieces:
            T = s.part_poses[part.name]
            points = part.feature_points @ T[:3, :3].T + T[:3, 3]
            in_hand = any(np.linalg.norm(T[:3, 3] - r.tcp_pose(s.joints[r.name])[:3, 3]) < 0.1
                          for r in cell.robots if r.tool is not None)
            for c, cam in enumerate(cell.cameras):
                vec = points - cam.center
                length = np.linalg.norm(vec, axis=1)
                geom, dist = np.empty(len(points), np.int32), np.empty(len(points))
                mujoco.mj_multiRay(model, data, cam.center, (vec / length[:, None]).ravel(),
                                   None, 1, -1, geom, dist, None, len(points), 100.0)
                hit = (dist >= 0) & (dist < length - tol)
                seen = cam.sees(points)
                assert not np.any(seen & hit & (geom == floor))
                near = hit & (length - dist < 2e-3)
                differ = seen & (hit == views[part.name][c].visible)
                assert not np.any(differ & ~near)
                ambiguous += int((differ & near).sum())
                checked += int(seen.sum())
                held += int(seen.sum()) if in_hand else 0
    assert checked > 2000 and held > 300
    assert ambiguous <= 0.005 * checked


def test_the_realism_command_prints_each_knob_as_the_file_writes_it(capsys):
    from cellsight.cli import main

    assert main(["realism", "lab"]) == 0
    out = capsys.readouterr().out
    rows = {line.split("│")[1].strip(): [c.strip() for c in line.split("│")[2:4]]
            for line in out.splitlines() if line.count("│") == 4}
    assert rows["actuators"] == ["mujoco", "analytic"]
    assert rows["velocity_feedforward"] == ["true", "false"]
    assert rows["bandwidth_hz"] == ["8", "0"]
