"""Fuzz families of the run folders and the commands that write files (issue 23), run by
:func:`fuzzing.run_kind` like the other kinds:

- ``out_folder``: every command that writes (``run``, ``show``, ``cameras --write``,
  ``place-cameras``, ``sweep``, ``export``) with at least one bad argument, or with an
  ``--out`` that already holds the user's files of the names it writes (no ``--overwrite``), a
  file, or a folder under a file: it must refuse (exit 2, no traceback, the error on the last
  line of stderr) and leave every file and folder as it was;
- ``replay``: a kept run whose cell's files (its ``run_cell.yaml``, the calibration files it
  names) are damaged, deleted, rewritten unchanged or only touched, then replayed (the API's
  :func:`cellsight.runfolder.load_run`, or ``cellsight export``): a changed or missing file is
  refused in one line and nothing is written; an unchanged one replays;
- ``write_failure``: a short run in which the ``k``-th write through
  :mod:`cellsight.runfolder.writes` fails with a full disk: the command ends with exit 1 or 2
  in one line, never a traceback, and the folder is never taken for a finished run
  (:func:`cellsight.runfolder.finished_metrics`).

Each kind makes its run folder once, in its temporary folder (a 0.3 s ideal run).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import random
import shutil
from pathlib import Path

NO_SPACE = OSError(errno.ENOSPC, "No space left on device")
CAMERA_FILE_FORMAT = "opencv-yaml"

# Per command: its valid arguments (OUT and RUN stand for the case's folders) and bad values
# for some of them; a case replaces one or two by a bad value.
COMMANDS: dict[str, tuple[list[str], dict[str, list[str]]]] = {
    "run": (["run", "1", "--sensor", "ideal", "--duration", "0.3", "--quiet", "--out", "OUT"], {
        "1": ["0", "4", "x"], "--duration": ["nan", "-1", "0", "inf", "x"],
        "--sensor": ["camera"],
        "--seed": ["-1", "x", "1.5"], "--realism": ["nope", "missing.yaml"],
        "--structure": ["octree"], "--cell": ["missing.yaml", "RUN"]}),
    "show": (["show", "--out", "OUT"], {
        "--joints": ['{"R7AX": [1, 2]}', "[1, 2]", '{"R9": []}', "nan"],
        "--part-pose": ['{"part": {"xyz": [0, 0]}}', '{"nope": {"xyz": [0, 0, 0]}}'],
        "--cell": ["missing.yaml", "RUN"]}),
    "cameras": (["cameras", "--write", "OUT"], {
        "--format": ["opencv", "json"], "--cell": ["missing.yaml", "RUN"]}),
    "place-cameras": (["place-cameras", "--task", "RUN", "--quiet", "--out", "OUT"], {
        "--cameras": ["0", "-1", "100000"], "--every": ["0", "-3"],
        "--radii": ["-1", "nan", "0"], "--elevations": ["0", "95", "nan"],
        "--azimuth-step": ["0", "400"], "--task": ["5", "missing", "OUT"],
        "--jobs": ["0"], "--verify-seeds": ["-1"], "--verify-duration": ["nan", "-2"]}),
    "sweep": (["sweep", "--experiments", "1", "--sensors", "ideal", "--duration", "0.3",
               "--quiet", "--out", "OUT"], {
        "--duration": ["nan", "-1", "0"], "--jobs": ["0", "-2"], "--seeds": ["-1"],
        "--experiments": ["4", "0"], "--realism": ["nope"], "--cells": ["missing.yaml"],
        "--sensors": ["camera"], "--variants": ["nope"], "--structure": ["octree"]}),
    "export": (["export", "RUN", "--quiet", "--mcap", "OUT/run.mcap"], {
        "RUN": ["missing", "OUT"], "--mcap": ["RUN/frames.csv", "RUN/metrics.json"],
        "--every": ["0", "-1", "x"], "--cell": ["missing.yaml"]}),
}
OWN_FILES = {"run": ["frames.csv", "metrics.json", "run.log"], "show": ["cell_3d.png"],
             "cameras": ["cameras.yaml", "cell.yaml"], "place-cameras": ["cell.yaml", "report.md"],
             "sweep": ["summary.md", "summary.csv"], "export": ["run.mcap"]}


def _made_run(folder: Path) -> Path:
    """The kind's run folder (made once): a 0.3 s ideal run on a cell whose cameras come from
    calibration files in ``folder/cal``; the cell file itself is removed after the run."""
    from cellsight.cli import main
    from cellsight.experiments import RunConfig, run_experiment

    run = folder / "run"
    if not (run / "metrics.json").exists():
        with contextlib.redirect_stdout(io.StringIO()):
            assert main(["cameras", "--write", str(folder / "cal"), "--format",
                         CAMERA_FILE_FORMAT]) == 0
        run_experiment(RunConfig(1, run, cell=folder / "cal" / "cell.yaml", sensor="ideal",
                                 duration=0.3, progress=False, video_every=0))
        (folder / "cal" / "cell.yaml").unlink()
    return run


def _tree(root: Path) -> dict[str, str]:
    """Every path under ``root`` with its content's digest ('dir' for a folder)."""
    return {str(p.relative_to(root)): "dir" if p.is_dir() else
            hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*"))}


def run_cli(argv: list[str]) -> tuple[int, str]:
    """``cellsight`` in process: its exit status and stderr."""
    from cellsight.cli import main

    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            status = main(argv)
        except SystemExit as exc:  # argparse
            status = exc.code if isinstance(exc.code, int) else 1
    return status, err.getvalue()


def _refused_in_one_line(status: int, err: str) -> bool:
    """Exit 2, no traceback, and the error on stderr's last line (argparse's usage may come
    before it)."""
    lines = err.strip().splitlines()
    return (status == 2 and "Traceback" not in err and bool(lines)
            and "error" in lines[-1] and all(line.startswith(("usage:", " ", "cellsight"))
                                             for line in lines))


# ---- every command checks its arguments and its folder before it creates anything -----------

def _out_state(rng: random.Random, command: str, case_dir: Path) -> tuple[Path, bool]:
    """An ``--out`` for the case and whether it alone must make the command refuse."""
    state = rng.choice(("missing", "empty", "own files", "stranger", "file", "under a file"))
    out = case_dir / "out"
    if state == "missing":
        return case_dir / "new" / "deeper", False
    if state in ("file", "under a file"):
        out.write_text("a user's file")
        return (out if state == "file" else out / "inside"), command != "export"
    out.mkdir()
    if state == "own files":
        for name in OWN_FILES[command]:
            (out / name).write_text(f"the user's own {name}")
        return out, True
    if state == "stranger":
        (out / "notes.txt").write_text("the user's notes")
        return out, command == "run"
    return out, False


def out_folder_case(rng: random.Random, case: int, tally, folder: Path) -> None:
    """A writing command with bad arguments or a taken ``--out``: refused, nothing changed."""
    run = _made_run(folder)
    case_dir = folder / "case"
    shutil.rmtree(case_dir, ignore_errors=True)
    case_dir.mkdir()
    command = rng.choice(sorted(COMMANDS))
    base, bad_values = COMMANDS[command]
    out, taken = _out_state(rng, command, case_dir)
    argv = list(base)
    bad = rng.sample(sorted(bad_values), k=rng.choice((0, 1, 1, 2)) if taken else
                     rng.choice((1, 1, 2)))
    for arg in bad:
        value = rng.choice(bad_values[arg])
        if arg in argv and arg.startswith("--"):
            argv[argv.index(arg) + 1] = value
        elif arg in argv:
            argv[argv.index(arg)] = value
        else:
            argv += [arg, value]
    if bad and rng.random() < 0.3:
        argv.append("--overwrite")  # a bad argument is refused all the same
    argv = [a.replace("OUT", str(out)).replace("RUN", str(run)) for a in argv]
    before_case, before_run = _tree(case_dir), _tree(run)
    status, err = run_cli(argv)
    changed = _tree(case_dir) != before_case or _tree(run) != before_run
    if not _refused_in_one_line(status, err) or changed:
        tally.fail(case, f"exit {status}, {'changed files, ' if changed else ''}stderr "
                         f"{err[-300:]!r} for {json.dumps(argv)[:400]}")
    else:
        tally.refused += 1


# ---- every replay verifies the cell ----------------------------------------------------------

def _damage(rng: random.Random, path: Path) -> bool:
    """Change ``path`` one of several ways, or not at all; True when its content changed."""
    data = path.read_bytes()
    how = rng.choice(("flip", "append", "cut", "delete", "same", "touch"))
    if how == "flip" and data:
        i = rng.randrange(len(data))
        path.write_bytes(data[:i] + bytes([data[i] ^ (1 << rng.randrange(8))]) + data[i + 1:])
    elif how == "append":
        path.write_bytes(data + b"\n# edited\n")
    elif how == "cut" and data:
        path.write_bytes(data[: rng.randrange(len(data))])
    elif how == "delete":
        path.unlink()
        return True
    elif how in ("same", "touch"):
        path.write_bytes(data)
    return path.read_bytes() != data


def replay_case(rng: random.Random, case: int, tally, folder: Path) -> None:
    """Damage one of a kept run's cell files and replay the run: refused when it changed."""
    from cellsight.errors import CellsightError
    from cellsight.runfolder import load_run

    run = _made_run(folder)
    kept = json.loads((run / "metrics.json").read_text())["cell_files"]
    files = [run / name if name == "run_cell.yaml" else Path(name) for name in sorted(kept)]
    target = rng.choice(files)
    pristine = target.read_bytes()
    mcap = folder / "replay.mcap"
    try:
        changed = _damage(rng, target)
        if rng.random() < 0.8:
            try:
                ok, what = load_run(run).n > 0, "load_run"
            except CellsightError as exc:
                ok, what = False, f"load_run: {exc}"
            refused_well = not ok and "\n" not in what
        else:
            status, err = run_cli(["export", str(run), "--mcap", str(mcap), "--quiet"])
            ok, what = status == 0, f"export: exit {status}, {err[-300:]!r}"
            refused_well = _refused_in_one_line(status, err) and not mcap.exists()
        if changed and not refused_well:
            tally.fail(case, f"{target.name} changed, replayed anyway or badly refused: {what}")
        elif not changed and not ok:
            tally.fail(case, f"{target.name} unchanged, refused: {what}")
        elif changed:
            tally.refused += 1
    finally:
        target.write_bytes(pristine)
        mcap.unlink(missing_ok=True)


# ---- every write records its failure in the run ----------------------------------------------

def write_failure_case(rng: random.Random, case: int, tally, folder: Path) -> None:
    """A short run whose ``k``-th write fails (full disk): one line, never a finished run."""
    from cellsight.runfolder import finished_metrics, writes
    from cellsight.runfolder.framelog import FrameWriter

    out = folder / "write_failure"
    shutil.rmtree(out, ignore_errors=True)
    k = rng.randrange(1, 40)
    calls = {"n": 0}

    def hit() -> bool:
        calls["n"] += 1
        return calls["n"] == k

    def raise_no_space() -> None:
        raise NO_SPACE

    def file_write(self, data):  # a whole file's bytes, as AtomicFile fails on an OSError
        if hit():
            raise self._failing(NO_SPACE)
        return real["file"](self, data)

    def row_write(self, write):  # a frames.csv row, failing inside the writer's own guard
        return real["row"](self, raise_no_space if hit() else write)

    def log_flush(self):  # run.log, failing inside logging's emit
        if hit():
            raise_no_space()
        return real["log"](self)

    targets = {"file": (writes.AtomicFile, "write", file_write),
               "row": (FrameWriter, "_written", row_write),
               "log": (writes._LogFile, "flush", log_flush)}
    real = {key: getattr(cls, name) for key, (cls, name, _) in targets.items()}
    for cls, name, wrapper in targets.values():
        setattr(cls, name, wrapper)
    try:
        status, err = run_cli(["run", rng.choice(("1", "2", "3")), "--sensor", "ideal",
                            "--duration", "0.3", "--quiet", "--out", str(out)])
    finally:
        for key, (cls, name, _) in targets.items():
            setattr(cls, name, real[key])
    failed = calls["n"] >= k
    if "Traceback" in err:
        tally.fail(case, f"write {k} failed: a traceback: {err[-300:]!r}")
    elif failed and (status == 0 or finished_metrics(out) is not None):
        tally.fail(case, f"write {k} of {calls['n']} failed, yet exit {status} and "
                         f"finished metrics")
    elif failed and len(err.strip().splitlines()) != 1:
        tally.fail(case, f"write {k} failed: stderr not one line: {err[-300:]!r}")
    elif not failed and status != 0:
        tally.fail(case, f"no write failed ({calls['n']} writes), yet exit {status}: "
                         f"{err[-300:]!r}")
    elif failed:
        tally.refused += 1
