"""A run's identity: every input that shapes what a run computes, recorded in its
``metrics.json`` (``identity``), so that a sweep reuses a finished run only when it is the
run asked for (:func:`cellsight.sweep.grid.reusable_metrics`).

The identity holds the experiment, the seed, the sensor (and the ideal sensor's noise), the
tracker's options, the predictor's structure, the duration and its limits, the cell (the
SHA-256 of its file and every file it points to), the realism profile (the SHA-256 of its
knobs as loaded, so that an edited profile file is another profile), the calibration folder
(the SHA-256 of its ``calibration.json``, None without one), cellsight's version and the
SHA-256 of cellsight's own code (every module and data file of the package: a change to the
world, the tracker or the task is another run, even under the same version). What only shows a
run (the output folder, progress, video, recording, live stream) is not in it.
"""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING

import cellsight
from cellsight.calibration.folder import CALIBRATION_FILE
from cellsight.errors import CellsightError
from cellsight.model.loader import load_cell
from cellsight.realism import Profile, load_profile
from cellsight.runfolder import cell_digest
from cellsight.tracking.setup import tracker_facts

if TYPE_CHECKING:
    from cellsight.experiments.config import RunConfig


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def profile_digest(realism: str | Path | Profile) -> str:
    """The SHA-256 of a realism profile's knobs as loaded (its name and file left out)."""
    profile = load_profile(realism)
    knobs = profile.model_dump(mode="json", exclude={"name", "file"})
    return _sha256(json.dumps(knobs, sort_keys=True).encode())


def calibration_digest(folder: Path | None) -> str | None:
    """The SHA-256 of a calibration folder's ``calibration.json`` (None: no calibration)."""
    if folder is None:
        return None
    try:
        return _sha256((folder / CALIBRATION_FILE).read_bytes())
    except OSError as exc:
        raise CellsightError(f"--calibration: {folder}: {exc.strerror or exc}") from None


PACKAGE = Path(cellsight.__file__).resolve().parent


@functools.cache
def code_digest(package: Path = PACKAGE) -> str:
    """The SHA-256 of the code in ``package``: every ``.py`` module and every file of its
    ``data`` folder, by path and content (compiled caches aside)."""
    digest = hashlib.sha256()
    files = [*package.rglob("*.py"), *(package / "data").rglob("*")]
    for path in sorted(f for f in files if f.is_file() and "__pycache__" not in f.parts):
        digest.update(str(path.relative_to(package)).encode() + b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def run_identity(config: RunConfig) -> dict:
    """The identity of the run ``config`` describes (module docstring)."""
    calibration = None if config.calibration is None else Path(config.calibration)
    return {"experiment": config.experiment, "seed": config.seed, "sensor": config.sensor,
            "ideal_sigma_px": None if config.sensor.takes_images else config.ideal_sigma_px,
            **tracker_facts(config.tracker), "structure": config.structure,
            "duration_s": config.duration, "max_duration_s": config.max_duration,
            "tail_s": config.tail_s, "cell_sha256": cell_digest(load_cell(config.cell)),
            "realism_sha256": profile_digest(config.realism),
            "calibration_sha256": calibration_digest(calibration),
            "cellsight": cellsight.__version__, "code_sha256": code_digest()}
