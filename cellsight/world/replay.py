"""A simulated cell for replaying logged states (``cellsight view``, ``cellsight export``)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from cellsight.world.world import World


class ReplayWorld(World):
    """A :class:`World` without tasks, put in logged states at once by :meth:`show_state`
    (nothing is simulated between them)."""

    def show_state(self, joints: Mapping[str, np.ndarray],
                   part_poses: Mapping[str, np.ndarray],
                   openings: Mapping[str, float] | None = None) -> None:
        """Put the cell in a logged state: robot name -> joint vector (rad, m; robots left out
        stay), workpiece name -> ``T_base_part`` (resting there, held by nobody), robot name ->
        jaw opening (m)."""
        self.robots.place(joints)
        for name, T in part_poses.items():
            self.place_part(name, T)
        for name, opening in (openings or {}).items():
            self.grippers.set_opening(name, opening)
        self.scene.sync()
