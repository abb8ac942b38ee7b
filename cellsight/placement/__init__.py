"""Camera placement (issue 15, beyond the paper): score candidate camera poses on a shell
around the work area by how well the features they would see over a whole task serve the
tracker, and pick the best few.

- :mod:`.task`: the task's frames (joints, part poses, phases) from a run or a fresh run;
- :mod:`.candidates`: the shell of candidate cameras looking at the work area;
- :mod:`.scoring`: per frame and candidate, the exact visibility of every feature (the
  predictor's object hierarchies, all candidates at once) and the pose information it gives;
- :mod:`.choose`: the objective (predicted position error, frames with fewer than 4 points)
  and the greedy choice with exchanges;
- :mod:`.report` and :mod:`.command`: ``cellsight place-cameras``.
"""

from cellsight.placement.candidates import shell_candidates
from cellsight.placement.choose import Placement, choose_cameras, placement_loss
from cellsight.placement.scoring import CandidateScores, score_candidates
from cellsight.placement.task import TaskFrames

__all__ = ["CandidateScores", "Placement", "TaskFrames", "choose_cameras", "placement_loss",
           "score_candidates", "shell_candidates"]
