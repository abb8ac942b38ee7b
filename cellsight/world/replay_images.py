"""A simulated run's camera images, rendered again at its logged states (for
:func:`cellsight.export.mcap_run.export_mcap`)."""

from __future__ import annotations

import numpy as np

from cellsight.errors import CellsightError
from cellsight.runfolder.replay import RunData
from cellsight.world.replay import ReplayWorld


class ReplayImages:
    """The cameras' images of ``run``'s frames, rendered by a
    :class:`~cellsight.world.ReplayWorld` of the run's world (its cell as the realism profile
    drew it) without tasks, made on first use: the robots at their logged joints, the part at
    its true pose, the grasping robot's jaws at their logged opening."""

    def __init__(self, run: RunData) -> None:
        self.run = run
        self._world: ReplayWorld | None = None

    def render(self, k: int) -> list[np.ndarray]:
        """(H, W) uint8 per camera of frame ``k``."""
        run = self.run
        if self._world is None:
            self._world = ReplayWorld(run.world_cell())
        gripper = run.gripper
        openings = ({gripper: float(run.opening[k])}
                    if gripper and np.isfinite(run.opening[k]) else {})
        self._world.show_state({r: q[k] for r, q in run.joints.items()},
                               {run.part.name: run.T_true[k]}, openings)
        try:
            return self._world.render()
        except RuntimeError as exc:
            raise CellsightError(f"rendering the camera images failed ({exc}); pass "
                                 f"--no-images to export without them") from exc

    def close(self) -> None:
        if self._world is not None:
            self._world.close()
