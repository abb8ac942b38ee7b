"""A run against the same run tracked back from its recordings (``cellsight run --record``,
then ``cellsight track``): per tracked folder, the largest difference of the estimates from the
run's and the whole-task position RMSE of each; and a figure of the position error over time.

    python scripts/recording_roundtrip.py RUN_DIR TRACK_DIR [TRACK_DIR ...] --out FIG.png

``make recordings`` runs it on experiment 3 in the lab world, recorded lossless and as JPEG."""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from cellsight.runfolder import FrameLog, read_metrics  # noqa: E402


def _error_mm(log: FrameLog) -> np.ndarray:
    return 1e3 * np.linalg.norm(log.poses("est")[:, :3] - log.poses("true")[:, :3], axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("tracks", nargs="+")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    run = FrameLog.read(Path(args.run) / "frames.csv")
    fig, ax = plt.subplots(figsize=(9, 3.2))
    t = run.floats("t")
    ax.plot(t, _error_mm(run), lw=2.5, color="0.75", label="the run itself")
    print(f"{args.run}: position RMSE {read_metrics(Path(args.run))['position_rmse_mm']:.4f} mm")
    for folder in args.tracks:
        log = FrameLog.read(Path(folder) / "frames.csv")
        metrics = read_metrics(Path(folder))
        same = len(log.floats("t")) == len(t)
        diff = (np.nanmax(np.abs(log.poses("est")[:, :3] - run.poses("est")[:, :3]))
                if same else float("nan"))
        label = f"{Path(folder).name}: tracked from {Path(metrics['recording']).name}"
        print(f"{folder}: {log.n} frames ({metrics['frames_dropped']} missing, predicted), "
              f"position RMSE {metrics['position_rmse_mm']:.4f} mm, largest difference from "
              f"the run's estimate {1e3 * diff:.3g} mm")
        ax.plot(log.floats("t"), _error_mm(log), lw=0.9, label=label)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("position error (mm)")
    ax.set_title("experiment 3, lab world: the run and the run tracked from its recordings")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
