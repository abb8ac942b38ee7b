"""The sweep's grid of runs and one run of it, resumable.

A run is a :class:`RunSpec`: a cell (a built-in name or a cell file), an experiment (1-3), a
sensor (``rendered`` / ``ideal``), a variant (:data:`VARIANTS`: the tracker's options), a
realism profile (``exact``, ``lab``, ``harsh`` or a file), the predictor's structure and a
seed, written into its own folder ``<out>/<cell>/e<N>_<sensor>_<variant>[_<realism>]
[_<structure>]_s<seed>`` (the realism when not ``exact``, the structure when not the default).
:func:`run_spec` reuses a folder whose ``metrics.json`` is complete (read back, neither
interrupted nor failed) and of the very run asked for (its ``identity``: the cell's files, the
realism profile's knobs and the calibration by their SHA-256, the duration, the tracker's
options and the rest, :mod:`cellsight.experiments.identity`), and runs the others again (their
folder cleared first).

The ``calibrated`` variant's runs take the cell calibrated by ``cellsight calibrate`` in the
run's own world (its cell, realism and seed) as the model side: one calibration per cell,
realism and seed, shared by its experiments, made by the first run that needs it (the others
wait on a lock) into ``<out>/<cell>/calibration[_<realism>]_s<seed>``, and reused while it is
of the cell as it is now (:func:`~cellsight.calibration.command.finished_calibration`).
"""

from __future__ import annotations

import fcntl
import itertools
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from cellsight.errors import CellsightError
from cellsight.trackers import DEFAULT_TRACKER, TrackerChoice
from cellsight.visibility import OBJECT_BVH, STRUCTURES

if TYPE_CHECKING:
    from cellsight.experiments import RunConfig

CALIBRATED = "calibrated"
"""The variant whose runs take the cell calibrated on their own seed (module docstring)."""
VARIANTS: dict[str, TrackerChoice] = {
    "kinematic": DEFAULT_TRACKER,
    "plain": TrackerChoice("plain"),
    "nopred": TrackerChoice(occlusion_prediction=False),
    "offsets": TrackerChoice(experimental=frozenset({"camera-offsets"})),
    "unknown": TrackerChoice(experimental=frozenset({"unknown-occluders"})),
    CALIBRATED: DEFAULT_TRACKER,
}
"""Variant name -> the run's tracker (:class:`~cellsight.trackers.TrackerChoice`): ``kinematic``
the default, ``plain`` the paper's tracker from the images alone, and the default with one
change: ``nopred`` windows on every model point in the image, ``offsets`` and ``unknown`` the
experimental camera offsets and unknown-occluder map, ``calibrated`` the cell calibrated on the
run's own seed (module docstring)."""

SENSORS = ("rendered", "ideal")


def safe_name(text: str) -> str:
    """``text`` as one folder name that stays where it is put: every character but letters,
    digits, ``_``, ``-``, ``.`` and ``+`` made ``_``, and a leading ``.`` or ``-`` too (no
    ``..``, no hidden folder, no option-like name); ``_`` for an empty one."""
    name = re.sub(r"[^A-Za-z0-9_.+-]", "_", text)
    return re.sub(r"^[.-]", "_", name) or "_"


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep (module docstring); ``duration``: simulated seconds (None: until
    the task is done)."""

    cell: str
    experiment: int
    sensor: str
    variant: str
    seed: int
    duration: float | None = None
    realism: str = "exact"
    structure: str = OBJECT_BVH

    @property
    def _realism_tag(self) -> str:
        """``_<realism>`` in a folder's name (empty for ``exact``)."""
        if self.realism == "exact":
            return ""
        return "_" + safe_name(Path(self.realism.replace(":", "_").replace("/", "-")).stem)

    @property
    def folder(self) -> Path:
        """The run's folder under the sweep's output folder."""
        stem = Path(self.cell).stem if self.cell.endswith((".yaml", ".yml")) else self.cell
        stem = safe_name(stem)
        name = f"e{self.experiment}_{self.sensor}_{self.variant}{self._realism_tag}"
        if self.structure != OBJECT_BVH:
            name += "_" + self.structure
        return Path(stem) / f"{name}_s{self.seed}"

    @property
    def calibration_folder(self) -> Path | None:
        """The folder of the calibration the run takes (``calibrated`` variant; module
        docstring), under the sweep's output folder; None for the other variants."""
        if self.variant != CALIBRATED:
            return None
        return self.folder.parent / f"calibration{self._realism_tag}_s{self.seed}"

    def config(self, out: Path) -> RunConfig:
        """The run's :class:`~cellsight.experiments.RunConfig`, writing into ``out/folder``."""
        from cellsight.experiments import RunConfig

        calibration = self.calibration_folder
        return RunConfig(self.experiment, Path(out) / self.folder, cell=self.cell,
                         seed=self.seed, sensor=self.sensor, duration=self.duration,
                         progress=False, overwrite=True, realism=self.realism,
                         structure=self.structure, tracker=VARIANTS[self.variant],
                         calibration=None if calibration is None else Path(out) / calibration)


@dataclass(frozen=True)
class SweepAxes:
    """The values a sweep goes over: built-in cells' names or cell files, experiments (1-3),
    sensors, tracker variants (:data:`VARIANTS`; the first is the one compared against),
    seeds, realism profiles and occlusion structures."""

    cells: Sequence[str]
    experiments: Sequence[int]
    sensors: Sequence[str]
    variants: Sequence[str]
    seeds: Sequence[int]
    realisms: Sequence[str] = ("exact",)
    structures: Sequence[str] = (OBJECT_BVH,)


def sweep_grid(axes: SweepAxes, variant_seeds: int | None = None,
               duration: float | None = None) -> list[RunSpec]:
    """Every combination of the ``axes``, in the order of their fields (cells first, seeds
    last); variants other than the first run on the first ``variant_seeds`` seeds only (None:
    on all), as comparisons; ``duration`` (s; None: until the task is done). Every value is
    checked, and every cell and realism profile loaded, before anything runs."""
    from cellsight.realism import load_profile

    cells, experiments, sensors, variants, seeds = (axes.cells, axes.experiments, axes.sensors,
                                                    axes.variants, axes.seeds)
    realisms, structures = axes.realisms, axes.structures

    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise CellsightError(f"--duration: expected a positive, finite number of seconds, got "
                             f"{duration!r}")
    for name, values, allowed in (("--structure", structures, STRUCTURES),
                                  ("--sensors", sensors, SENSORS),
                                  ("--variants", variants, tuple(VARIANTS)),
                                  ("--experiments", experiments, (1, 2, 3))):
        bad = [v for v in values if v not in allowed]
        if bad or not values:
            raise CellsightError(f"{name}: expected one or more of {list(allowed)}, got "
                                 f"{list(values)}")
    if not seeds or any(s < 0 for s in seeds):
        raise CellsightError(f"--seeds: expected one or more whole numbers >= 0, got "
                             f"{list(seeds)}")
    if variant_seeds is not None and variant_seeds < 1:
        raise CellsightError(f"--variant-seeds: expected a whole number >= 1, got "
                             f"{variant_seeds}")
    if not cells or not realisms:
        raise CellsightError(f"--cells, --realism: expected one or more of each, got "
                             f"{list(cells)}, {list(realisms)}")
    _check_cells(cells, sensors)
    for realism in realisms:
        try:
            load_profile(realism)
        except CellsightError as exc:
            raise CellsightError(f"--realism: {exc}") from exc
    compared = set(seeds[:variant_seeds]) if variant_seeds is not None else set(seeds)
    specs = [RunSpec(cell, e, sensor, variant, seed, duration, realism, structure)
            for cell, e, realism, structure, sensor, variant, seed in itertools.product(
                cells, experiments, realisms, structures, sensors, variants, seeds)
            if variant == variants[0] or seed in compared]
    _check_one_folder_each(specs)
    return specs


def _check_cells(cells: Sequence[str], sensors: Sequence[str]) -> None:
    """Load each cell once (a file or a built-in name): one that does not is refused here,
    before any run, rather than as every one of its runs failing; so is a line (several
    picks) with the ideal sensor, which sees one part."""
    from cellsight.experiments.config import Sensor
    from cellsight.model.loader import load_cell

    for cell in dict.fromkeys(cells):
        try:
            loaded = load_cell(cell)
        except CellsightError as exc:
            raise CellsightError(f"--cells: {exc}") from exc
        for sensor in dict.fromkeys(sensors):
            refused = Sensor(sensor).cannot_run(loaded, cell)
            if refused is not None:
                raise CellsightError(f"--sensors: {refused}; give --sensors rendered")


def _check_one_folder_each(specs: list[RunSpec]) -> None:
    """Refuse a grid where two runs would write into one folder: a value given twice
    (``--seeds 0 0``) or two cell files of the same name in different folders."""
    by_folder: dict[Path, RunSpec] = {}
    for spec in specs:
        other = by_folder.setdefault(spec.folder, spec)
        if other is spec:
            continue
        if other == spec:
            what = ("the same run twice (a value repeated in --cells, --experiments, --sensors, "
                    "--variants, --realism, --structure or --seeds)")
        elif other.cell != spec.cell:
            what = f"cells {other.cell!r} and {spec.cell!r} (files of the same name: rename one)"
        else:
            what = f"realism {other.realism!r} and {spec.realism!r} (rename one)"
        raise CellsightError(f"sweep: two runs would share the folder {str(spec.folder)!r}: "
                             f"{what}")


def reusable_metrics(folder: Path, identity: dict | None = None) -> dict | None:
    """The metrics of a finished run in ``folder`` (neither interrupted nor failed; with
    ``identity``, that run's: every input that shapes it the same,
    :func:`~cellsight.experiments.identity.run_identity`), else None."""
    from cellsight.runfolder import finished_metrics

    metrics = finished_metrics(folder)
    if metrics is None or identity is None:
        return metrics
    return metrics if metrics.get("identity") == identity else None


_STOPPED_BY: list[str] = []
"""In a pool's worker process: the signal that stopped a run there (the sweep is ending)."""


def run_spec(job: tuple[RunSpec, Path]) -> dict:
    """Run one ``(spec, out)`` job (or reuse its finished folder); returns its metrics, with
    ``"error"`` set when it failed (the sweep goes on) and ``"reused"`` when it was done. In a
    worker process whose run a signal stopped, the jobs already queued to it are not run."""
    import multiprocessing

    from cellsight.calibration.command import finished_calibration
    from cellsight.experiments import run_experiment
    from cellsight.experiments.identity import run_identity

    if _STOPPED_BY:
        return {"error": f"not run: the worker was stopped by {_STOPPED_BY[0]}"}
    spec, out = job
    try:
        identity = run_identity(spec.config(out))
    except CellsightError:  # the cell, the profile or the calibration no longer loads
        identity = {"unreadable": True}
    done = reusable_metrics(Path(out) / spec.folder, identity)
    if done is not None and spec.calibration_folder is not None and not finished_calibration(
            Path(out) / spec.calibration_folder, spec.cell, spec.realism, spec.seed):
        done = None  # its calibration is gone or stale: calibrate and run again
    if done is not None:
        return {**done, "reused": True}
    try:
        _check_under_out(spec, Path(out))
        if spec.calibration_folder is not None:
            _calibrate(spec, Path(out))
        metrics = run_experiment(spec.config(out))
    except Exception as exc:  # recorded; the other runs go on
        return {"error": f"{type(exc).__name__}: {exc}"[:1000]}
    if metrics.get("signal") and multiprocessing.parent_process() is not None:
        _STOPPED_BY.append(str(metrics["signal"]))
    return metrics


def _check_under_out(spec: RunSpec, out: Path) -> None:
    """A :class:`~cellsight.runfolder.RunFolderError` when the run's folder (or its
    calibration's) leads, through a link in ``out``, to a folder outside ``out``: a run that is
    not reused is cleared and written again, and the sweep writes only under its ``--out``
    (a run reused through such a link is only read)."""
    from cellsight.runfolder import RunFolderError

    inside = out.resolve()
    for folder in (spec.folder, spec.calibration_folder):
        if folder is None:
            continue
        target = (out / folder).resolve()
        if not target.is_relative_to(inside):
            raise RunFolderError(f"--out: {str(out / folder)!r} leads to {str(target)!r}, "
                                 f"outside {str(out)!r} (a link): the sweep writes only under "
                                 f"its --out; remove the link, or copy the run there")


def _calibrate(spec: RunSpec, out: Path) -> None:
    """Make the run's calibration unless it is made (module docstring): one process at a time
    per folder (the lock file beside it)."""
    from cellsight.calibration.board import Board
    from cellsight.calibration.command import finished_calibration, write_world_calibration
    from cellsight.calibration.output import is_calibration_output
    from cellsight.runfolder import check_out_folder

    folder = out / spec.calibration_folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    with open(folder.with_name(folder.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if finished_calibration(folder, spec.cell, spec.realism, spec.seed):
            return
        stale = check_out_folder(folder, True, "calibration", "", is_calibration_output)
        write_world_calibration(folder, spec.cell, spec.realism, spec.seed, Board(), stale)
