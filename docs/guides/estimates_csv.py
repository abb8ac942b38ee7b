"""A sink of your own: each frame's estimate of the part into ``estimates.csv`` in the run
folder (t in s; x, y, z in m, in the cell's base frame; the tracker's status)."""

import csv

from cellsight.session import FrameRecord, RunContext


class EstimatesCsv:
    """One row a frame; empty x, y, z while the tracker has no estimate."""

    def start(self, run: RunContext) -> None:
        self.path = run.out / "estimates.csv"
        self.file = self.path.open("w", newline="")
        self.rows = csv.writer(self.file)
        self.rows.writerow(["t", "x", "y", "z", "status"])

    def frame(self, record: FrameRecord) -> None:
        part = record.part
        xyz = part.T_base_part[:3, 3] if part.status.has_estimate else ["", "", ""]
        self.rows.writerow([f"{record.t:.5f}", *xyz, part.status_text])

    def close(self, completed: bool) -> None:
        self.file.close()


if __name__ == "__main__":
    from pathlib import Path

    from cellsight.experiments import ExperimentRun, RunConfig

    config = RunConfig(1, Path("out/own-sink"), sensor="ideal", duration=2.0, overwrite=True)
    ExperimentRun(config, sinks=[EstimatesCsv()]).run()
    print((config.out / "estimates.csv").read_text()[:300])
