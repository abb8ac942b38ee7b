"""Camera placement (issue 15, beyond the paper): score candidate camera poses on a shell
around the work area by how well the features they would see over a whole task serve the
tracker, and pick the best few.

- :mod:`.task`: the task's frames (joints, part poses, phases) from a run or a fresh run;
- :mod:`.candidates`: the shell of candidate cameras looking at the work area;
- :mod:`.scoring`: per frame and candidate, the exact visibility of every feature (the
  predictor's object hierarchies, all candidates at once) and the pose information it gives;
- :mod:`.choose`: the objective (predicted position error, frames with fewer than 4 points)
  and the greedy choice with exchanges;
- :mod:`.report` and :mod:`.command`: ``cellsight place-cameras`` (the package imports nothing
  itself, so that the command line registers the command without loading the rest).
"""
