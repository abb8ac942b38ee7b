"""The generated pages of the documentation, written by mkdocs-gen-files at build time: the
references (command line, cell file, realism profile, run folder, Python API), the results
(from the sweeps' summaries in ``docs/results/data``) and the changelog."""

from __future__ import annotations

import sys
from pathlib import Path

import mkdocs_gen_files

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parent))

import reference  # noqa: E402
import results  # noqa: E402

from cellsight.cli import build_parser  # noqa: E402
from cellsight.model.schema import CellSpec  # noqa: E402
from cellsight.realism.profile import Profile  # noqa: E402

API = {
    "cellsight": "load_cell and Camera: where to start",
    "cellsight.model": "the cell: robots, workpieces, static objects, cameras, snapshots",
    "cellsight.model.calibration": "cameras from and to OpenCV and ROS calibration files",
    "cellsight.occlusion": "visible_mask on any polygon soup, PolygonSoup, BSPTree",
    "cellsight.occlusion.predictor": "VisibilityPredictor: every feature, every camera, a frame",
    "cellsight.visibility": "what a prediction returns, per part and camera",
    "cellsight.tracking": "the tracker and its swappable parts",
    "cellsight.control": "trajectory planner, interpolation, servo loop, the grasping task",
    "cellsight.control.ik": "inverse kinematics over every configuration branch",
    "cellsight.world": "the simulated cell (MuJoCo): the plant and the truth",
    "cellsight.realism": "realism profiles and what a seed draws",
    "cellsight.session": "one run: a source of frames, the tracker, the sinks",
    "cellsight.session.driver": "your cell's camera and robot drivers as a source",
    "cellsight.experiments": "the paper's experiments from Python",
    "cellsight.runfolder": "a run's folder: its files, written and read back",
    "cellsight.recording": "tracking recordings: the topic map",
    "cellsight.sweep.command": "sweeps from Python",
}
"""The modules of the Python API reference, each with a line on what it holds."""


def write(path: str, text: str) -> None:
    with mkdocs_gen_files.open(path, "w") as page:
        page.write(text)


write("reference/cli.md", reference.cli_page(build_parser()))
write("reference/cell-file.md", reference.schema_page(
    "Cell file", "A cell file is YAML: robots, workpieces, static objects, cameras and the "
    "experiments' set-up. Lengths in metres, angles in radians unless a field says otherwise. "
    "The guide [Your own cell](../guides/own-cell.md) walks through one.", CellSpec))
write("reference/realism-profile.md", reference.schema_page(
    "Realism profile", "A realism profile is YAML: how the simulated world departs from the "
    "cell file. Each knob is a number or a distribution `{dist: fixed|normal|uniform, ...}`; "
    "its unit is in its name. The guide [Realism profiles](../guides/realism.md) shows how to "
    "write one.", Profile))
write("reference/run-folder.md", reference.run_folder_page())
write("reference/api/index.md", "# Python API\n\nGenerated from the docstrings.\n\n"
      "| module | what it holds |\n|---|---|\n" + "".join(
          f"| [`{name}`]({name}.md) | {text} |\n" for name, text in API.items()))
for name in API:
    write(f"reference/api/{name}.md", f"# `{name}`\n\n::: {name}\n")
for path, text in results.pages(ROOT).items():
    write(path, text)
write("changelog.md", (ROOT / "CHANGELOG.md").read_text())
