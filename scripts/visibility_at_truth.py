"""How much of a run's visibility error is the model's and how much the pose estimate's.

For each run folder given: the in-view visibility accuracy of the predictor with the cell
file's model at the world's *true* part pose and joints (what remains is the model's error:
the world's cameras, robots and part differ from the cell file's), next to the run's own
accuracy (at the tracker's predicted pose). Every third frame.

    python scripts/visibility_at_truth.py out/lab/dual-arm/e1_rendered_pred_lab_s1 ...
"""

from __future__ import annotations

import argparse

from cellsight.occlusion.backends import visibility_predictor
from cellsight.runfolder import load_run
from cellsight.runfolder.figures import _per_camera, in_image


def accuracies(folder: str, every: int = 3) -> tuple[float, float]:
    """(accuracy at the true pose, the run's accuracy) over in-view labels."""
    run = load_run(folder)
    predictor = visibility_predictor(run.cell)
    inside = in_image(run.frames)
    true = _per_camera(run.frames, "vis_true", "bits")
    logged = _per_camera(run.frames, "vis_pred", "bits")
    agree = total = 0
    for k in range(0, run.n, every):
        joints = {r: q[k] for r, q in run.joints.items()}
        openings = {run.robot: run.opening[k]} if run.robot else {}
        views = predictor.predict(joints, {run.part.name: run.T_true[k]}, openings)
        for c, view in enumerate(views[run.part.name]):
            m = inside[k, c]
            agree += int((view.visible[m] == true[k, c][m]).sum())
            total += int(m.sum())
    return agree / max(total, 1), float((logged == true)[inside].mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="run folders")
    for folder in parser.parse_args().runs:
        at_truth, in_run = accuracies(folder)
        print(f"{folder}: at the true pose {at_truth:.4f}, in the run {in_run:.4f}")


if __name__ == "__main__":
    main()
