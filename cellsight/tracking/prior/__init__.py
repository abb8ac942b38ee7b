"""The kinematic prior (beyond the paper): what the robot cell knows of a part without the
cameras, and how the tracker fuses it.

- :mod:`.kinematic`: the prior's poses of one workpiece, where the gripper holds it or what it
  lies on (:class:`KinematicPrior`, :class:`RecordedGrasp`);
- :mod:`.fusion`: the tracker's filter kept with them: the held part with its holder, the
  lying part on its support at the support's speed, the part let go at rest; a fix off its
  support refused.
"""

from cellsight.tracking.prior.kinematic import KinematicPrior, RecordedGrasp

__all__ = ["KinematicPrior", "RecordedGrasp"]
