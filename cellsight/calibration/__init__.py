"""Cell calibration: a ChArUco board on a robot flange, the cell's cameras and robot bases."""

POSES_PER_CAMERA = 16
"""Poses planned per camera and robot by default (:func:`.cell_plan.plan_poses`). In the
``lab`` world (seeds 0-3), 16 against 8: the cameras' images of the work area 0.24 px off
(worst 0.36) instead of 0.44 (1.04), the second robot's base 0.27 mm off at the work area
instead of 0.45, for 26 s of calibration instead of 18 s; 24 and 32 gained no more than the
seeds' spread."""
