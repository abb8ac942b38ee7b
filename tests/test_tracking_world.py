"""The whole tracking loop on the real parts: MuJoCo world images, the BSP occlusion
predictor, selection, windows, OpenCV corner extraction and the EKF, against the world's truth."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight import load_cell
from cellsight.occlusion.backends import visibility_predictor
from cellsight.rates import VISION_HZ
from cellsight.tracking import Tracker
from cellsight.world import ConveyorPath, World


def test_tracker_follows_a_moving_part_in_rendered_images() -> None:
    cell = load_cell()
    part = cell.workpieces[0]
    start = part.T_base_part[:2, 3]
    conveyor = ConveyorPath([start, start + [0.3, 0.05]], speed=0.03)
    world = World(cell, seed=3, conveyor=conveyor)
    predictor = visibility_predictor(cell)
    tracker = Tracker.from_cell(cell, predictor)
    errors, agreement = [], []
    try:
        for k in range(60):
            t = k / VISION_HZ
            while world.time < t - 1e-9:
                world.step({}, {})
            joints = world.measured_joints()
            frame = tracker.step(world.render(), joints, t)
            rec = frame.parts[part.name]
            T_true = world.true_part_poses()[part.name]
            truth = world.true_views()[part.name]
            predicted = predictor.predict(joints, {part.name: T_true})[part.name]
            agreement += [np.mean(p.visible == v.visible)
                          for p, v in zip(predicted, truth, strict=True)]
            if k >= 20:
                dR = Rotation.from_matrix(rec.T_base_part[:3, :3].T @ T_true[:3, :3])
                errors.append((np.linalg.norm(rec.T_base_part[:3, 3] - T_true[:3, 3]),
                               dR.magnitude()))
                assert rec.status == "tracking"
    finally:
        world.close()
    errors = np.array(errors)
    rmse = np.sqrt(np.mean(errors**2, axis=0))
    assert rmse[0] < 1.5e-3 and rmse[1] < np.radians(1.0)
    assert np.mean(agreement) == 1.0  # the BSP prediction at the true pose matches MuJoCo's rays
