"""
# Realism profiles: how far the simulated cell departs from its model

A cell file is a model: the cameras' calibration, the robots' kinematics, the part's size and
start are all a little off in a real cell. A realism profile says by how much. Each run of an
experiment draws, from the profile and its seed, a world of its own (the cell as built, the
imperfections of its sensors and actuators, the scenario's shifts), while the predictor, the
tracker and the planner keep the nominal cell file, as they would in a real cell.

This tutorial reads the built-in `lab` and `harsh` profiles, looks at what one seed draws,
measures what the drawn camera errors mean in pixels across 20 seeds, and compares one
camera's image in the `exact` world with the `harsh` one.
"""

# %%
# ## Two profiles
#
# `load_profile` takes a built-in name (`exact`, `lab`, `harsh`, ...), a YAML file, or
# `PROFILE/GROUP` for one knob group of a built-in profile alone (`harsh/cameras`). Every knob's
# unit is in its name; a drawn knob states its distribution. `exact` is all zeros: the world
# is the cell file.

import matplotlib.pyplot as plt
import numpy as np

from cellsight import load_cell
from cellsight.geometry.transforms import invert_pose, transform_points
from cellsight.model.grasp import grasp_pose
from cellsight.realism import draw_world, load_profile
from cellsight.world import World

profiles = {name: load_profile(name) for name in ("lab", "harsh")}
for profile in profiles.values():
    print(f"{profile.name}: {profile.description}")
    for knob, dist in profile.cameras:
        print(f"  cameras.{knob}: {dist.dist}, sigma {dist.sigma:g}")

# %%
# ## What a seed draws
#
# `draw_world(profile, cell, seed)` (what `cellsight run --realism lab --seed N` uses, and
# `cellsight realism lab --seed N` prints) returns the run's world: `cell` (the cell as built),
# `errors` (the world's imperfections: encoders, servo, images, faults...), `scenario` (the
# part's start shift, the conveyor's speed...) and `record`, every drawn value in its knob's
# units, as `metrics.json` stores it. Each knob draws from its own stream, seeded by the seed
# and the knob's name: the same seed draws the same camera errors whether the other knob
# groups are on or not, which the last line checks.

cell = load_cell()
draws = draw_world("lab", cell, seed=0)
for key, value in draws.record.items():
    if key.startswith("cameras."):
        print(f"{key}: {value}")
print(f"... and {sum(not k.startswith('cameras.') for k in draws.record)} other draws "
      f"(robots, geometry, scenario, images...)")
print(f"scenario: part start shifted {1e3 * draws.scenario.shift} mm, "
      f"turned {np.degrees(draws.scenario.yaw):.2f} deg")
alone = draw_world("lab/cameras", cell, seed=0).record
print("seed 0's camera draws, lab/cameras alone vs whole lab: identical ->",
      alone == {k: v for k, v in draws.record.items() if k.startswith("cameras.")})

# %%
# ## Camera errors in pixels, across 20 seeds
#
# What matters to a tracker is where a point appears in the image against where the cell
# file's camera puts it. Project the part's feature points through the nominal camera and
# through the world's camera (`draws.cell.cameras`), at two places: the part's start on the
# conveyor, which is where the profile's calibration was fitted (its work area), and the
# part held by the grasping robot at its FINAL joints, beside the conveyor.

part = cell.workpiece(cell.experiments.workpiece)
robot = cell.robot(cell.experiments.robot)
places = {
    "start": part.T_base_part,
    "FINAL": robot.tcp_pose(robot.final) @ invert_pose(grasp_pose(part)),
}
for name, T in places.items():
    print(f"part at {name}: {np.round(T[:3, 3], 3)} m")
apart = np.linalg.norm(places["FINAL"][:3, 3] - places["start"][:3, 3])
print(f"FINAL is {apart:.2f} m from the start")
seeds = range(20)
shift_px = {}  # (profile, place) -> (seeds, cameras) mean pixel shift of the features
for pname in profiles:
    worlds = [draw_world(pname, cell, seed) for seed in seeds]
    for place, T in places.items():
        points = transform_points(T, part.feature_points)
        shift_px[pname, place] = np.array([
            [np.linalg.norm(built.project(points) - nominal.project(points), axis=1).mean()
             for nominal, built in zip(cell.cameras, w.cell.cameras, strict=True)]
            for w in worlds])
for (pname, place), px in shift_px.items():
    print(f"{pname:5s} at {place:5s}: mean shift {px.mean():.2f} px, median "
          f"{np.median(px):.2f} px, largest {px.max():.2f} px (20 seeds x 2 cameras)")
for place in places:
    ratio = shift_px["harsh", place].mean() / shift_px["lab", place].mean()
    print(f"at {place}: harsh's mean shift is {ratio:.1f} x lab's")

# %%
# Each dot below is one seed and one camera, the black bars the medians. The `harsh`
# profile's camera sigmas are three times `lab`'s (printed above), and the printed ratios of
# the mean shifts follow them. The calibration is fitted at the start, but its error is
# not confined there: at FINAL, the printed shifts are of the same size. A tracker that keeps
# the cell file's cameras sees each corner a few pixels from where it predicts it, which is
# what its windows, its gate, the default tracker's registration of the cameras to the
# gripper and (experimental, `--experimental camera-offsets`, which sets
# `TrackerConfig.camera_offsets_px`) its camera-offset estimates have to absorb.

fig, ax = plt.subplots(figsize=(9, 4.5))
rng = np.random.default_rng(0)
labels = []
for i, ((pname, place), px) in enumerate(shift_px.items()):
    for c, cam in enumerate(cell.cameras):
        jitter = i + (c - 0.5) * 0.3 + rng.uniform(-0.06, 0.06, len(px))
        ax.scatter(jitter, px[:, c], s=14, color=f"C{c}",
                   label=cam.name if i == 0 else None)
    ax.hlines(np.median(px), i - 0.35, i + 0.35, color="k", lw=1)
    labels.append(f"{pname}\npart at {place}")
ax.set_xticks(range(len(labels)), labels)
ax.set(ylabel="mean feature shift [px]", ylim=(0, None),
       title="where the world's cameras see the part, against the cell file's cameras")
ax.legend(title="camera")
ax.grid(alpha=0.3, axis="y")
fig.tight_layout()

# %%
# ## The image in `exact` and in `harsh`
#
# The world of a draw is `World(draws.cell, errors=draws.errors, seed=...)`. Its images carry
# the profile's image effects (vignetting, defocus, gain drift, shot and read noise, JPEG), and
# its part, cameras and conveyor are where the draw put them. The same crop of the first
# camera's image, around where the cell file's camera sees the part, in the `exact` world and
# in `harsh`'s world of seed 0:

harsh = draw_world("harsh", cell, seed=0)
print(f"harsh seed 0 image effects: {harsh.errors.images}")
crops = {}
for pname, world in (("exact", World(cell)), ("harsh", World(harsh.cell, errors=harsh.errors,
                                                                seed=0))):
    try:
        image = world.render(cameras=[0])[0]
    finally:
        world.close()
    uv = cell.cameras[0].project(transform_points(part.T_base_part, part.feature_points))
    (u0, v0), (u1, v1) = (uv.min(axis=0) - 60).astype(int), (uv.max(axis=0) + 60).astype(int)
    crops[pname] = image[v0:v1, u0:u1].astype(float)
world_part = harsh.cell.workpiece(part.name)
seen = transform_points(world_part.T_base_part, world_part.feature_points)
moved = np.linalg.norm(harsh.cell.cameras[0].project(seen) - uv, axis=1)
print(f"the part's corners appear {moved.mean():.1f} px (mean) from where the cell file puts "
      f"them: camera error and the part's shifted start together")
difference = crops["harsh"] - crops["exact"]
print(f"crop {crops['exact'].shape[1]} x {crops['exact'].shape[0]} px: grey levels differ by "
      f"{np.abs(difference).mean():.1f} on average (exact's mean level "
      f"{crops['exact'].mean():.1f})")

fig, axes = plt.subplots(1, 3, figsize=(11, 3.6))
for ax, (pname, crop) in zip(axes, crops.items(), strict=False):
    ax.imshow(crop, cmap="gray", vmin=0, vmax=255)
    ax.set_title(f"{cell.cameras[0].name}, {pname}")
limit = np.abs(difference).max()
shown = axes[2].imshow(difference, cmap="coolwarm", vmin=-limit, vmax=limit)
axes[2].set_title("harsh - exact (grey levels)")
fig.colorbar(shown, ax=axes[2], fraction=0.046)
for ax in axes:
    ax.set_axis_off()
fig.tight_layout()

# %%
# The part appears away from where the cell file says (by the printed mean, its camera's
# error and its shifted start together) and the image is noisier and softer: the tracker,
# which keeps the cell file's cameras and the part's nominal start, has to cope with all of
# it. `cellsight sweep --realism lab harsh` runs the experiments
# over many seeds of each profile.
