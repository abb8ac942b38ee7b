"""The simulated cell (the ground truth): a MuJoCo world generated from the cell model.

Robots follow joint set-points at 500 Hz, a conveyor carries the workpiece, pneumatic
parallel grippers grasp it, a second robot may run its own timed task, the fixed cameras are
rendered offscreen as grayscale images, and the truth (part poses, joints, feature visibility
by ray casts) is read from MuJoCo. The system under test never imports this package.
"""

from cellsight.world.gl import choose_gl_backend

choose_gl_backend()  # before MuJoCo is imported

from cellsight.world.paths import ConveyorPath, JointTask, Waypoint  # noqa: E402
from cellsight.world.world import World  # noqa: E402

__all__ = ["ConveyorPath", "JointTask", "Waypoint", "World", "choose_gl_backend"]
