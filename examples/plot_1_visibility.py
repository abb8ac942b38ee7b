"""
# Which feature points each camera sees

A tracker that measures corners in images must first know which corners are there to be
seen: a corner behind the part's own faces, or behind a robot's gripper or forearm, is not in
the image, and a window searched for it finds something else. The occlusion predictor answers
this for every feature point of every workpiece in every fixed camera, from the robots' joints
and the workpieces' poses alone, and names what hides each point that it does not see.

This tutorial takes the built-in dual-arm cell, puts its part at a pose on the conveyor and
the grasping robot's gripper around it, asks the predictor what each camera sees, then brings
a second robot across one camera's line of sight. Each answer is drawn over the image that the
simulated world renders for the same state, and checked against the world's own ray casts.
"""

# %%
# ## The cell
#
# `load_cell()` with no argument loads the built-in cell (`cellsight/data/dual_arm_cell.yaml`):
# two arms with parallel-jaw grippers, a conveyor on a table, two fixed cameras and one
# workpiece, a U-shaped prism whose corners are its feature points. The cell file's
# `experiments` section names the robot that grasps the part.

import matplotlib.pyplot as plt
import numpy as np

from cellsight import load_cell
from cellsight.control.ik import solve_ik
from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.model.grasp import grasp_pose
from cellsight.occlusion.backends import visibility_predictor
from cellsight.world import World

cell = load_cell()
part = cell.workpiece("part")
grasper = cell.robot(cell.experiments.robot)
for cam in cell.cameras:
    print(f"camera {cam.name}: {cam.width} x {cam.height} px, focal length {cam.focal_px:.0f} px")
for robot in cell.robots:
    print(f"robot {robot.name}: {robot.n_joints} joints")
print(f"workpiece {part.name}: {len(part.feature_names)} feature points; "
      f"grasped by {grasper.name}")

# %%
# ## A state of the cell
#
# A state is the robots' joints, the workpieces' poses and the grippers' jaw openings; what is
# left out stays at its nominal value (HOME joints, the cell file's part pose, open jaws).
# Here the part lies on the conveyor (its top is at z = 0.62 m in the cell file), turned by
# 0.5 rad, and the grasping robot holds its open gripper at the grasp: the joints come from
# inverse kinematics of the cell file's grasp pose, taking the configuration nearest HOME.

T_base_part = pose_from_xyz_rpy([0.62, 0.02, 0.62], [0.0, 0.0, 0.5])
T_base_tcp = T_base_part @ grasp_pose(part)
solutions = solve_ik(grasper, T_base_tcp).solutions
q_grasp = min(solutions, key=lambda s: np.linalg.norm(s.q - grasper.home)).q
print(f"{len(solutions)} IK branches reach the grasp; nearest HOME: {np.round(q_grasp, 3)}")

# %%
# ## What the predictor says
#
# `visibility_predictor(cell)` builds the cell's occlusion structures once; `predict(joints,
# part_poses)` answers per workpiece, one `CameraVisibility` per camera: `visible` (one flag
# per feature), `pixels` (where each feature projects), `reason` (`''` when visible, else
# `self` for a point behind its own part's faces, `behind` or `outside` for one out of the
# camera's view, or the label of the nearest object hiding it) and `near_occluder` (visible,
# but another object's silhouette passes within a few pixels of it: its image corner is not
# a clean corner, so the tracker does not pick it).

predictor = visibility_predictor(cell)
joints = {grasper.name: q_grasp}
views = predictor.predict(joints, {part.name: T_base_part})[part.name]


def print_views(views):
    """One line per camera: how many features it sees, then each hidden one and why."""
    for view in views:
        hidden = {part.feature_names[j]: r for j, r in enumerate(view.reason) if r}
        near = [part.feature_names[j] for j in np.flatnonzero(view.near_occluder)]
        print(f"{view.camera}: {view.count} of {len(view.visible)} visible; hidden: {hidden}; "
              f"next to an occluder: {near}")


print_views(views)

# %%
# Two corners on the part's underside are hidden by the part itself in both cameras, and the
# open jaws, reaching down on both sides of the part, hide more of them.
#
# ## The same state in the simulated world, and its truth
#
# `World(cell, initial_joints=...)` builds the MuJoCo world of the cell in that state;
# `place_part` puts the part at its pose, `render()` gives one grayscale image per camera and
# `true_views()` what each camera truly sees there, by ray casts in MuJoCo (same answer
# type as the predictor's). The predictor is a separate computation on the cell's polygons,
# so their agreement is a check, not a tautology.


def world_check(joints, views):
    """Render the state in the world and count the features whose predicted visibility
    matches the ray casts; returns the images."""
    world = World(cell, initial_joints=joints)
    try:
        world.place_part(part.name, T_base_part)
        images = world.render()
        truth = world.true_views()[part.name]
    finally:
        world.close()
    agree = sum(int(np.sum(p.visible == t.visible)) for p, t in zip(views, truth, strict=True))
    total = sum(len(p.visible) for p in views)
    print(f"predicted visibility matches the ray casts for {agree} of {total} "
          f"(camera, feature) pairs")
    return images


images = world_check(joints, views)

# %%
# ## Drawing the answer over the images
#
# Each feature is drawn where the predictor projects it: a green disc when predicted visible,
# a red ring when hidden, numbered as in the cell file (`f1` ... `f16`); a visible feature next
# to an occluder gets an orange edge. The images are cropped around the part.


def draw(images, views, title):
    fig, axes = plt.subplots(1, len(views), figsize=(11, 4.6))
    for ax, image, view in zip(axes, images, views, strict=True):
        uv = view.pixels
        ax.imshow(image, cmap="gray", vmin=0, vmax=255)
        ok = view.visible
        ax.scatter(*uv[ok].T, s=40, c="#2ca02c", edgecolors=np.where(
            view.near_occluder[ok], "#ff7f0e", "#2ca02c"), linewidths=1.5, label="visible")
        ax.scatter(*uv[~ok].T, s=60, facecolors="none", edgecolors="#d62728", linewidths=1.8,
                   label="hidden")
        for j, (u, v) in enumerate(uv):
            ax.annotate(str(j + 1), (u, v), xytext=(4, -4), textcoords="offset points",
                        color="yellow", fontsize=8)
        (u0, v0), (u1, v1) = uv.min(axis=0) - 90, uv.max(axis=0) + 90
        ax.set(xlim=(u0, u1), ylim=(v1, v0),
               title=f"{view.camera}: {view.count} of {len(ok)} visible")
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0].legend(loc="lower left", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()


draw(images, views, f"{grasper.name}'s open gripper at the grasp")

# %%
# ## A second robot crosses a line of sight
#
# The cell file's experiment 3 sends the other robot across the cameras' views on timed joint
# waypoints. At the waypoint of 20.5 s its forearm passes between one camera and the part; the
# reasons now name a link of that robot.

crosser = cell.robot(cell.experiments.crossing_robot)
t_cross, q_cross = next((t, q) for t, q in cell.experiments.crossing_waypoints if t == 20.5)
joints_cross = {grasper.name: q_grasp, crosser.name: q_cross}
views_cross = predictor.predict(joints_cross, {part.name: T_base_part})[part.name]
print(f"{crosser.name} at its {t_cross} s waypoint {np.round(q_cross, 3)}:")
print_views(views_cross)
images_cross = world_check(joints_cross, views_cross)
draw(images_cross, views_cross, f"... and {crosser.name} at its {t_cross} s crossing waypoint")

# %%
# The same call answers the command line's `cellsight visibility --joints ... --part-pose ...`
# (a table per camera, or `--json`). The tracker asks it at every frame, with the measured
# joints and its own predicted part pose, and windows only the features predicted visible and
# clear of occluders' silhouettes.
