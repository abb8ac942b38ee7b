"""
# Tracking a part from camera frames

The tracker turns camera frames into a pose estimate of each workpiece: at each frame it
predicts the part's pose (an extended Kalman filter), asks the occlusion predictor which
feature points each camera sees at that pose with the robots' measured joints, picks the
features worth measuring, searches small image windows around them for the corners, and
updates the filter with what it finds.

This tutorial drives it exactly as a real cell would, with images, joint readings and times,
except that the images come from the simulated world: the built-in cell's part rides the
conveyor while the second robot's forearm moves in front of one camera. The simulator knows
the part's true pose, so the estimate's error can be plotted frame by frame.
"""

# %%
# ## The world and the tracker
#
# `World(cell, ...)` is the MuJoCo simulation of the cell: here the conveyor carries the part
# along the cell file's experiment path, faster than the cell file's speed so that a short run
# shows something, and the second robot runs its own task: from one of the cell file's
# crossing waypoints to the next, which puts its forearm above the conveyor, between the first
# camera and the part's path. `Tracker.from_cell(cell, visibility_predictor(cell))` tracks
# every workpiece of the cell, acquiring it (a PnP fix) around its nominal pose.

import matplotlib.pyplot as plt
import numpy as np

from cellsight import load_cell
from cellsight.geometry.transforms import rotation_angle
from cellsight.occlusion.backends import visibility_predictor
from cellsight.rates import VISION_HZ
from cellsight.report.overlay import FeatureMarks, draw_camera_overlay
from cellsight.tracking import Tracker
from cellsight.world import ConveyorPath, Waypoint, World

cell = load_cell()
setup = cell.experiments
crossing = dict(setup.crossing_waypoints)  # time (s) -> joints of the crossing robot
conveyor = ConveyorPath(setup.conveyor_points, speed=0.05)
move_s = 0.8  # s: the crossing robot's move
world = World(cell, conveyor=conveyor,
              initial_joints={setup.crossing_robot: crossing[19.3]},
              tasks={setup.crossing_robot: [Waypoint(move_s, crossing[20.5])]})
tracker = Tracker.from_cell(cell, visibility_predictor(cell))
part = cell.workpiece(setup.workpiece)
print(f"conveyor speed {conveyor.speed} m/s ({conveyor.speed / setup.conveyor_speed:g} x the "
      f"cell file's); {setup.crossing_robot} moves from its 19.3 s crossing waypoint to its "
      f"20.5 s one in the first {move_s} s; frames at {VISION_HZ:g} Hz")

# %%
# ## The loop
#
# At each frame time `t`: advance the world to `t` (it steps at the control rate), grab one
# grayscale image per camera with `world.render()`, read the joints as the encoders give them
# with `world.measured_joints()`, and hand all three to `tracker.step`. The record of each part
# (`frame.parts[name]`) holds the status, the pose estimate `T_base_part` and its 12 x 12
# `covariance` (position first), and the per-camera masks: `visible` (predicted), `selected`,
# `measured` (NaN where no corner was found). A real cell's loop is the same three lines with
# its own grabber and controller.

duration = 2.0  # s
log = []
for k in range(int(round(duration * VISION_HZ))):
    t = k / VISION_HZ
    while world.time < t - 1e-9:
        world.step()
    images = world.render()
    frame = tracker.step(images, world.measured_joints(), t)
    rec = frame.parts[part.name]
    truth = world.true_part_poses()[part.name]
    row = {"t": t, "status": rec.status_text,
           "visible": rec.visible.sum(axis=1), "measured": np.isfinite(rec.measured[:, :, 0]).sum(
               axis=1), "truly_visible": [v.count for v in world.true_views()[part.name]]}
    if rec.T_base_part is not None:
        est = rec.T_base_part
        row["position_mm"] = 1e3 * np.linalg.norm(est[:3, 3] - truth[:3, 3])
        row["rotation_deg"] = np.degrees(rotation_angle(est[:3, :3].T @ truth[:3, :3]))
        row["sigma_mm"] = 1e3 * np.sqrt(np.trace(rec.covariance[:3, :3]))
    log.append(row)
    if k % 13 == 0:
        print(f"{t:5.2f} s {row['status']:9s} error {row.get('position_mm', np.nan):.3f} mm, "
              f"{row.get('rotation_deg', np.nan):.3f} deg; visible {row['visible']}, "
              f"measured {row['measured']}")

# %%
# The tracker's status: `acquired` at the first frame (the PnP fix), then `tracking` while
# measurements are accepted; `coasting`, `degraded` or `lost` say when they are not, or when
# the track looks inconsistent.

final = log[-1]
statuses = sorted({r["status"] for r in log})
print(f"statuses seen: {statuses}")
print(f"final ({final['t']:.2f} s): {final['status']}; position error "
      f"{final['position_mm']:.3f} mm, rotation error {final['rotation_deg']:.3f} deg, "
      f"position sigma {final['sigma_mm']:.3f} mm")
for c, cam in enumerate(cell.cameras):
    print(f"{cam.name} at the last frame: hidden by {sorted({r for r in rec.reasons[c] if r})}")
errors = np.array([r["position_mm"] for r in log])
print(f"position error over the run: mean {errors.mean():.3f} mm, max {errors.max():.3f} mm")
agree = sum(np.array_equal(r["visible"], r["truly_visible"]) for r in log)
print(f"frames whose predicted visible counts (at the predicted pose) equal the ray-cast "
      f"counts (at the true pose): {agree} of {len(log)}")

# %%
# ## The error against the truth
#
# Top: the estimate's position error against the simulator's truth, and the filter's own
# one-sigma position uncertainty (the root of the covariance's position trace). Bottom: per
# camera, the features predicted visible (solid) and those measured (dashed): the tracker
# measures only a few well-spread features per camera, and as the part rides in under the
# crossing robot's arm in the first camera's view (the printed reasons at the last frame) it
# keeps going on what remains.

t = np.array([r["t"] for r in log])
fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
ax1.plot(t, errors, label="position error")
ax1.plot(t, [r["sigma_mm"] for r in log], "--", label="filter's 1-sigma")
ax1.set(ylabel="mm", title=f"{part.name}: estimate against the simulator's truth")
ax1.legend()
ax1.grid(alpha=0.3)
for c, cam in enumerate(cell.cameras):
    line, = ax2.plot(t, [r["visible"][c] for r in log], label=f"{cam.name} predicted visible")
    ax2.plot(t, [r["measured"][c] for r in log], "--", color=line.get_color(),
             label=f"{cam.name} measured")
ax2.set(xlabel="time [s]", ylabel="features")
ax2.legend(ncol=2, fontsize=8)
ax2.grid(alpha=0.3)
fig.tight_layout()

# %%
# ## The last frame, as the tracker saw it
#
# `cellsight.report.overlay.draw_camera_overlay` draws a record over a camera's image (what
# `cellsight run` writes into its key frames and video): green discs predicted visible, red
# rings predicted hidden, yellow rings selected, blue windows searched, cyan crosses measured
# (orange when the filter's gate rejected them), a magenta square where the prediction
# disagrees with the ray-cast truth. The views are cropped around the part.

truth_views = world.true_views()[part.name]
world.close()
fig, axes = plt.subplots(1, len(cell.cameras), figsize=(11, 4.6))
for c, (cam, ax) in enumerate(zip(cell.cameras, axes, strict=True)):
    plan = rec.windows[c]
    marks = FeatureMarks(rec.pixels[c], rec.predicted_visible[c], rec.selected[c],
                         rec.measured[c], rec.rejected[c], truth_views[c].visible)
    drawn = draw_camera_overlay(images[c], marks, title=cam.name,
                                boxes=np.zeros((0, 4), int) if plan is None else plan.boxes)
    (u0, v0), (u1, v1) = (np.nanmin(rec.pixels[c], axis=0) - 80,
                          np.nanmax(rec.pixels[c], axis=0) + 80)
    ax.imshow(drawn)
    ax.set(xlim=(u0, u1), ylim=(v1, v0), title=f"{cam.name}, around the part")
    ax.set_axis_off()
fig.suptitle(f"t = {final['t']:.2f} s: {final['status']}")
fig.tight_layout()
