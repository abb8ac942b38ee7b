"""Hostile input, third round (issue 59): refusals that come before the work, naming the option
and the value: an ``--mcap`` that cannot be written (under /proc), ``ik --seeds`` past its
bound; the refusal leaves nothing behind (the output folders are not created)."""

from __future__ import annotations

import time

import pytest

from cellsight.cli import main
from cellsight.commands.ik import MAX_SEEDS
from cellsight.errors import CellsightError
from cellsight.export.mcap_run import check_output

PART = '{"part": {"xyz": [0.6, -0.15, 0.79], "rpy": [0, 0, 0.15]}}'


@pytest.mark.parametrize("where", ["/proc/cellsight.mcap", "/proc/self/new/run.mcap"])
def test_an_mcap_that_cannot_be_written_is_refused_before_the_work(where, tmp_path):
    with pytest.raises(CellsightError, match=r"^--mcap: cannot write under '/proc"):
        check_output(where, False, tmp_path / "run")


def test_a_writable_mcap_folder_is_left_as_it_was(tmp_path):
    before = sorted(tmp_path.iterdir())
    assert check_output(tmp_path / "new" / "run.mcap", False, tmp_path / "run") == (
        tmp_path / "new" / "run.mcap")
    assert sorted(tmp_path.iterdir()) == before  # no probe file, no folder made


def test_track_refuses_an_unwritable_mcap_before_tracking(tmp_path, capsys):
    out = tmp_path / "tracked"
    start = time.monotonic()
    code = main(["track", str(tmp_path / "absent.mcap"), "--out", str(out),
                 "--mcap", "/proc/cellsight.mcap"])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists() and time.monotonic() - start < 30
    assert "--mcap: cannot write under '/proc'" in err  # before the recording is even opened


@pytest.mark.parametrize("seeds", [MAX_SEEDS + 1, 10**9])
def test_ik_seeds_past_the_bound_are_refused_at_once(seeds, capsys):
    start = time.monotonic()
    assert main(["ik", "--part-pose", PART, "--seeds", str(seeds)]) == 2
    assert time.monotonic() - start < 10
    assert (f"--seeds: expected a whole number from 0 to {MAX_SEEDS} (about 30 ms each), "
            f"got {seeds}") in capsys.readouterr().err



def test_ik_names_a_redundant_arms_solutions_by_their_start(capsys):
    """A 7-axis arm has no branch flags: each row is named by the start that found it (HOME,
    middle, FINAL, random k), not "seed HOME" or "seed seed 17"."""
    part = '{"part": {"xyz": [0.6, -0.15, 0.79], "rpy": [0, 0, 0.35]}}'
    assert main(["ik", "--cell", "iiwa-cell", "--part-pose", part, "--seeds", "4"]) == 0
    starts = [line.split("│")[1].strip() for line in capsys.readouterr().out.splitlines()
              if line.startswith("│")]
    starts = [s for s in starts if s]  # not a wrapped row's continuation
    assert starts and "HOME" in starts and not any(s.startswith("seed") for s in starts)
    assert all(s in ("HOME", "middle", "FINAL") or s.startswith("random ") for s in starts)


def test_a_run_says_what_ended_it(tmp_path, capsys):
    """The time limit is named when it ends a run with the task not done, and the run's
    printed result says it (with the phase the task stopped in)."""
    from cellsight.experiments import RunConfig, run_experiment

    metrics = run_experiment(RunConfig(2, tmp_path / "limit", sensor="ideal", max_duration=3.0,
                                       progress=False, video_every=0))
    assert metrics["ended_by"] == "the time limit (3 s) with the task not done"
    assert metrics["final_phase"] == "waiting" and metrics["last_setback"] is None
    assert main(["run", "2", "--sensor", "ideal", "--duration", "2", "--quiet", "--out",
                 str(tmp_path / "short")]) == 0
    assert "ended by --duration 2 s; the task waiting" in " ".join(
        capsys.readouterr().out.split())
