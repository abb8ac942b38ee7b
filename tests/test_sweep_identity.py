"""A resumed sweep reuses a finished run only when it is the run asked for (its identity, every
input that shapes it), and writes only under its output folder whatever the cells and
profiles are named (issue 59, families 1 and 2)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellsight.experiments import RunConfig
from cellsight.experiments.identity import run_identity
from cellsight.model.loader import cell_path
from cellsight.sweep.command import run_sweep
from cellsight.sweep.grid import RunSpec, SweepAxes, sweep_grid

PROFILE = "timing: {latency_ms: 30.0}\n"


def _sweep(out: Path, **kwargs) -> dict:
    grid = {"cells": ["dual-arm"], "experiments": [1], "sensors": ["ideal"],
            "variants": ["kinematic"], "seeds": [0], "duration": 0.2, **kwargs}
    axes = SweepAxes(**{k: grid.pop(k) for k in list(grid) if k in SweepAxes.__dataclass_fields__})
    specs = sweep_grid(axes, **grid)
    (result,) = run_sweep(specs, out, jobs=1, progress=False)
    assert not result.get("error"), result.get("error")
    return result


def test_a_run_is_reused_only_with_every_input_the_same(tmp_path: Path):
    """The same grid again reuses; another duration, an edited profile file (the same name
    and folder) or the same file rewritten with other knobs run again; a file rewritten with
    the same knobs (another comment) is the same profile."""
    profile = tmp_path / "mine.yaml"
    profile.write_text(PROFILE)
    out = tmp_path / "out"
    first = _sweep(out, realisms=[str(profile)])
    assert not first.get("reused")
    assert _sweep(out, realisms=[str(profile)]).get("reused")
    assert not _sweep(out, realisms=[str(profile)], duration=0.3).get("reused")
    assert _sweep(out, realisms=[str(profile)], duration=0.3).get("reused")
    profile.write_text("# the same knobs, another comment\n" + PROFILE)
    assert _sweep(out, realisms=[str(profile)], duration=0.3).get("reused")
    profile.write_text(PROFILE.replace("30", "45"))
    again = _sweep(out, realisms=[str(profile)], duration=0.3)
    assert not again.get("reused")
    assert again["identity"] != first["identity"]


@pytest.mark.parametrize("change, differs", [
    (lambda c: c, False),
    (lambda c: RunConfig(**{**c.__dict__, "out": c.out / "elsewhere", "progress": False,
                            "video_every": 5}), False),
    (lambda c: RunConfig(**{**c.__dict__, "seed": 1}), True),
    (lambda c: RunConfig(**{**c.__dict__, "max_duration": 60.0}), True),
    (lambda c: RunConfig(**{**c.__dict__, "structure": "frame-bsp"}), True),
    (lambda c: RunConfig(**{**c.__dict__, "realism": "lab"}), True),
    (lambda c: RunConfig(**{**c.__dict__, "ideal_sigma_px": 0.3}), True),
])
def test_the_identity_holds_what_shapes_a_run_and_nothing_that_only_shows_it(
        tmp_path: Path, change, differs):
    config = RunConfig(1, tmp_path / "run", sensor="ideal")
    assert (run_identity(change(config)) != run_identity(config)) is differs


def test_a_calibration_rewritten_is_another_run(tmp_path: Path):
    folder = tmp_path / "cal"
    folder.mkdir()
    (folder / "calibration.json").write_text('{"schema": 1}')
    config = RunConfig(1, tmp_path / "run", calibration=folder)
    before = run_identity(config)
    (folder / "calibration.json").write_text('{"schema": 1, "cameras": {}}')
    assert run_identity(config)["calibration_sha256"] != before["calibration_sha256"]


@pytest.mark.parametrize("name", ["...yaml", "..yaml", ".hidden.yaml", "a b;c.yaml",
                                  "-rf.yaml"])
def test_run_folders_stay_under_the_output_folder_whatever_the_cell_is_named(
        tmp_path: Path, name: str):
    for kind in ("cells", "profiles"):
        (tmp_path / kind).mkdir()
    cell, profile = tmp_path / "cells" / name, tmp_path / "profiles" / name
    cell.write_text(cell_path("dual-arm").read_text())
    profile.write_text(PROFILE)
    spec = RunSpec(str(cell), 1, "ideal", "kinematic", 0, realism=f"{profile}:x/..")
    out = tmp_path / "out"
    where = (out / spec.folder).resolve()
    assert where.is_relative_to(out.resolve()) and where != out.resolve()
    assert all(part not in ("..", ".") and not part.startswith((".", "-"))
               for part in spec.folder.parts), spec.folder


def test_a_change_to_cellsights_code_is_another_run(tmp_path: Path):
    """The identity's code digest: a copy of the package is the same code; one module changed
    by one byte, or a data file, is another (so a resumed sweep runs again what the code
    changed); compiled caches do not count."""
    import shutil

    from cellsight.experiments.identity import PACKAGE, code_digest

    copy = tmp_path / "cellsight"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    same = code_digest(copy)
    assert same == code_digest(PACKAGE)
    (copy / "__pycache__").mkdir(exist_ok=True)
    (copy / "__pycache__" / "x.pyc").write_bytes(b"cache")
    assert code_digest.__wrapped__(copy) == same
    world = copy / "world" / "servo.py"
    world.write_text(world.read_text() + "\n")
    assert code_digest.__wrapped__(copy) != same
    world.write_text(world.read_text()[:-1])
    assert code_digest.__wrapped__(copy) == same
    data = copy / "data" / "realism.yaml"
    data.write_text(data.read_text() + "# edited\n")
    assert code_digest.__wrapped__(copy) != same
