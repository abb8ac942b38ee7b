"""The simulated cell (the ground truth): a MuJoCo world generated from the cell model.

Robots follow joint set-points at the control rate (:data:`cellsight.rates.CONTROL_HZ`), a
conveyor carries the workpiece, pneumatic parallel grippers grasp it, a second robot may run
its own timed task, the fixed cameras are rendered offscreen as grayscale images, and the truth
(part poses, joints, what each camera sees by ray casts, as
:class:`~cellsight.visibility.CameraVisibility`) is read from MuJoCo. Modules: :mod:`.world`
(the :class:`World` and its robots), :mod:`.replay` (logged states put back, for replay),
:mod:`.grasp` (grippers), :mod:`.paths` (conveyor, robot tasks, workpiece motion),
:mod:`.truth` (ray casts), :mod:`.scene` (the shared MuJoCo state), :mod:`.mjcf` (the model),
:mod:`.render` (images). The system under test never imports this
package.
"""

from cellsight.world.gl import choose_gl_backend

choose_gl_backend()  # before MuJoCo is imported

from cellsight.world.paths import ConveyorPath, JointTask, Waypoint  # noqa: E402
from cellsight.world.replay import ReplayWorld  # noqa: E402
from cellsight.world.world import World  # noqa: E402

__all__ = ["ConveyorPath", "JointTask", "ReplayWorld", "Waypoint", "World", "choose_gl_backend"]
