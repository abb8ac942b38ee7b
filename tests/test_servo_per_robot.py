"""The servo follows the robot it drives: MuJoCo's actuators are tuned to each joint's whole
inertia (rotor and links) at the start, so a joint that moves heavy links (the built-in arm's
shoulder, a KR16's) follows the profile's second-order response as the light wrist does; a
URDF's rated joint speeds cap the profile's in the world and the CLIK's in the controller.
Oracles: the analytic step response ``1 - (1 + wn t) e^(-wn t)``, the URDF file's ``limit
velocity`` attributes read with lxml, the joint speeds MuJoCo integrates."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from cellsight import load_cell
from cellsight.control.clik import REVOLUTE_SPEED, default_joint_velocity_limits
from cellsight.model.urdf_files import resolve_uri
from cellsight.world import World
from cellsight.world.imperfections import Imperfections
from cellsight.world.servo import ServoParams

IIWA_URDF = "package://rtbdata/xacro/kuka_description/kuka_lbr_iiwa/urdf/lbr_iiwa_14_r820.urdf"


def _actuated(**servo) -> Imperfections:
    return Imperfections(servo=ServoParams(mujoco=True, **servo), noise_rad=0.0, noise_m=0.0)


@pytest.mark.parametrize("cell_name, robot, joint", [
    ("dual-arm", "R7AX", 1),  # its links add 3.6 kg m^2 to the rotor's 2
    ("kr16-cell", "KR16B", 1),  # 9.6 kg m^2: the whole arm stretched out beyond the shoulder
])
def test_a_joint_with_heavy_links_follows_the_profiles_step_response(cell_name, robot, joint):
    f = 3.0  # harsh's bandwidth
    wn = 2 * math.pi * f
    cell = load_cell(cell_name)
    world = World(cell, errors=_actuated(bandwidth_hz=f))
    home = cell.robot(robot).home
    step = home.copy()
    step[joint] += 0.02
    q = []
    for _ in range(400):
        world.step({robot: step})
        q.append(world.true_joints()[robot][joint] - home[joint])
    t = np.arange(1, 401) * world.dt_control
    analytic = 0.02 * (1 - (1 + wn * t) * np.exp(-wn * t))
    # the other joints' coupling and the integration leave a few percent of the step
    assert np.max(np.abs(np.array(q) - analytic)) < 0.05 * 0.02


def test_the_urdfs_rated_speeds_are_read():
    cell = load_cell("iiwa-cell")
    robot = cell.robot("IIWA_A")
    path = resolve_uri(IIWA_URDF, {}, Path(cell.source).parent)
    limits = etree.parse(str(path)).findall(".//joint/limit")
    np.testing.assert_array_equal(robot.max_velocity,
                                  [float(e.get("velocity")) for e in limits])
    np.testing.assert_array_equal(default_joint_velocity_limits(robot),
                                  np.minimum(REVOLUTE_SPEED, robot.max_velocity))
    assert default_joint_velocity_limits(robot)[0] < REVOLUTE_SPEED  # 85 deg/s, under 2 rad/s


def test_a_rated_speed_caps_the_profiles_in_the_world():
    cell = load_cell("iiwa-cell")
    robot = cell.robot("IIWA_A")
    a_max = math.radians(900.0)
    world = World(cell, errors=_actuated(bandwidth_hz=8.0, max_velocity=math.radians(150.0),
                                         max_acceleration=a_max))
    target = robot.home.copy()
    target[0] += 0.6
    q = []
    for _ in range(300):
        world.step({"IIWA_A": target})
        q.append(world.true_joints()["IIWA_A"][0])
    speed = np.abs(np.diff(q)).max() / world.dt_control
    # 1.48 rad/s, not the profile's 2.62: clipped after each step, within one step's acceleration
    rated = robot.max_velocity[0]
    assert 0.98 * rated < speed <= rated + 1.1 * a_max * world.dt_control
