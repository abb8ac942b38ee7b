"""Fuzz families of the files cellsight reads back (issue 59), run by :func:`fuzzing.run_kind`
like the other kinds:

- ``run_folder``: a finished run (experiment 2, ideal sensor, 1 s) copied and damaged one or
  two ways (``frames.csv`` bytes flipped, cut, rows dropped or repeated, columns renamed,
  values that are not numbers; ``metrics.json`` keys removed, values of the wrong type,
  invalid JSON, another experiment, another frames digest; ``run_cell.yaml`` edited or gone;
  files replaced by folders, empty files, FIFOs, links outside the folder), then read by one
  of ``diagnose``, ``check --path``, ``design-crossing --path``, ``export`` (into the case's
  output folder), ``compare`` (against the intact run) or the API's
  :func:`cellsight.runfolder.load_run`. A reader answers (exit 0) or refuses in one line (exit
  2); it must refuse what it cannot trust (a ``frames.csv`` that is not the run's, for every
  reader of the frames; ``metrics.json`` unusable, for all; another experiment, or an
  unfinished run, where the whole task is needed; a changed cell copy, where it is
  replayed) and answer where nothing it reads changed;
- ``recording``: a short recording (experiment 1, rendered, 0.3 s) damaged as bytes (flipped,
  cut, a stretch repeated or removed), as a file (a folder, a FIFO, a dangling link), or
  rewritten message by message (as a bare MCAP file, or a rosbag2 folder of MCAP or SQLite
  storage) with hostile fields (camera info with zero, NaN or infinite K and D, images of
  another size, step or encoding, compressed images that are no images, joint states with NaN,
  missing, unknown or repeated joints, stamps out of order or out of range, truth poses with
  NaN or a zero quaternion, topics dropped, repeated or of another type), then tracked
  (``cellsight track``): exit 0 with a finished run, or a one-line refusal that leaves no
  finished run; an undamaged rewrite must track;
- ``sweep_resume``: a tiny sweep (experiment 1, ideal sensor, 0.3 s, seeds 0 and 1, a realism
  profile file and a cell file) copied, damaged (a run's ``metrics.json`` removed, invalid,
  reformatted, its identity or its figures edited, interrupted; a run folder removed, emptied,
  replaced by a file or holding a stranger; ``sweep.json`` removed, garbled or a folder) and
  resumed, sometimes with another ``--duration``, ``--seeds`` or ``--realism``, an edited
  profile or cell file: a run is reused only when its identity is the one asked for, an
  intact run of the same inputs is reused, the printed count of reused runs is the count
  observed, and a failed run fails with cellsight's own error.

Every case runs under a watchdog (:func:`watchdog`: a case still running after ``HANG_S``
seconds is a failure, ``hang``), and the kind's temporary folder is compared before and after
the command (names, types, sizes, modification times, link targets): nothing may change
outside the case's output folder. Each kind makes its fixture once, in its temporary folder.
The report's figures (matplotlib, about 2 s a run) are drawn in one case in ten
(:data:`FIGURES`); the other cases leave them out.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import random
import re
import shutil
import signal
import stat
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from fuzz_folders import _refused_in_one_line

HANG_S = {"run_folder": 30.0, "recording": 20.0, "sweep_resume": 120.0}
"""Seconds a case of each kind may take before it counts as a hang."""
FIGURES = 0.1
"""The share of cases that draw the report's figures."""
JSON_VALUES = (None, True, False, 0, -1, 7, 2.5, 1e300, -1e300, "", "x", "é" * 3, "x" * 300,
               [], {}, [0], [1, 2, 3], {"a": 1}, [None], ["1"])


class Hang(BaseException):
    """A case still running when its watchdog fired (a BaseException, so that no ``except
    Exception`` of the code under test takes it for an error of its own)."""


@contextlib.contextmanager
def watchdog(seconds: float) -> Iterator[None]:
    """:class:`Hang` raised in the main thread after ``seconds`` (SIGALRM; a blocking
    ``open`` or ``read`` is interrupted too); nothing outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def fire(signum, frame):
        raise Hang(f"no answer after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@contextlib.contextmanager
def _figures(drawn: bool) -> Iterator[None]:
    """The report's figures drawn, or left out (:data:`FIGURES`)."""
    from cellsight.report import run_report

    real = run_report.write_figures
    if not drawn:
        run_report.write_figures = lambda run: []
    try:
        yield
    finally:
        run_report.write_figures = real


@dataclass
class Outcome:
    """A command run in process: its exit status (None: it did not end, ``crash`` says why),
    stdout and stderr."""

    status: int | None
    out: str = ""
    err: str = ""
    crash: str | None = None

    def verdict(self, answers: tuple[int, ...] = (0,)) -> str:
        """``accepted`` (an exit status of ``answers`` and no traceback), ``refused`` (exit 2,
        the error on stderr's last line) or the failure in words."""
        if self.crash is not None:
            return self.crash
        if "Traceback" in self.err:
            return f"a traceback: {self.err[-300:]!r}"
        if self.status in answers:
            return "accepted"
        if _refused_in_one_line(self.status, self.err):
            return "refused"
        return f"exit {self.status}, stderr {self.err[-300:]!r}"


def _exception_line(exc: BaseException) -> str:
    from fuzzing import _exception_line as line

    return line(exc)


def cli(argv: list[str], seconds: float, columns: int = 1000) -> Outcome:
    """``cellsight argv`` in process under the watchdog (rich's lines ``columns`` wide)."""
    from cellsight.cli import main

    out, err = io.StringIO(), io.StringIO()
    before = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(columns)
    try:
        with watchdog(seconds), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                status = main(argv)
            except SystemExit as exc:  # argparse
                status = exc.code if isinstance(exc.code, int) else 1
    except Hang as exc:
        return Outcome(None, out.getvalue(), err.getvalue(), f"hang: {exc}")
    except Exception as exc:  # noqa: BLE001 - the point of the fuzz
        return Outcome(None, out.getvalue(), err.getvalue(), _exception_line(exc))
    finally:
        if before is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = before
    return Outcome(status, out.getvalue(), err.getvalue())


def snapshot(root: Path, *skip: Path) -> dict[str, tuple]:
    """Every path under ``root`` but ``skip`` (and what is under them), not following links:
    its type and mode, and for all but folders its size, modification time and link target
    (a folder's own time changes with what is made in it, which the names show)."""
    entries: dict[str, tuple] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = [d for d in dirnames if here / d not in skip]
        for name in dirnames + filenames:
            path = here / name
            if path in skip:
                continue
            st = path.lstat()
            entries[str(path.relative_to(root))] = (
                (st.st_mode,) if stat.S_ISDIR(st.st_mode) else
                (st.st_mode, st.st_size, st.st_mtime_ns,
                 os.readlink(path) if stat.S_ISLNK(st.st_mode) else None))
    return entries


def changes(before: dict, after: dict) -> str:
    """The paths whose entries differ between two :func:`snapshot`s, in words ('' for none)."""
    changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
    more = f" and {len(changed) - 4} more" if len(changed) > 4 else ""
    return ", ".join(changed[:4]) + more


def _fresh(path: Path) -> Path:
    """``path`` emptied: removed whatever it is, made again as an empty folder."""
    if path.is_symlink() or path.is_file() or (path.exists() and not path.is_dir()):
        path.unlink()
    elif path.exists():
        shutil.rmtree(path)
    path.mkdir(parents=True)
    return path


def _content(path: Path) -> bytes | None:
    """A regular file's bytes (through links), None for anything else (never opens a FIFO)."""
    try:
        return path.read_bytes() if stat.S_ISREG(os.stat(path).st_mode) else None
    except OSError:
        return None


def _replace(path: Path, how: str, case_dir: Path, data: bytes, rng: random.Random) -> str:
    """Put something else at ``path`` (a file of ``data``): ``delete``, ``empty``,
    ``folder``, ``fifo``, ``link same`` (to a copy outside the run), ``link other`` (to an
    outside copy with a byte changed), ``link dangling``, ``link devnull``; returns ``how``."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
    outside = case_dir / "outside"
    outside.mkdir(exist_ok=True)
    if how == "empty":
        path.write_bytes(b"")
    elif how == "folder":
        path.mkdir()
    elif how == "fifo":
        os.mkfifo(path)
    elif how.startswith("link"):
        target = outside / path.name
        if how == "link same":
            target.write_bytes(data)
        elif how == "link other" and data:
            i = rng.randrange(len(data))
            target.write_bytes(data[:i] + bytes([data[i] ^ 0x04]) + data[i + 1:])
        elif how == "link other":
            target.write_bytes(b"x")
        elif how == "link devnull":
            target = Path(os.devnull)
        path.symlink_to(target)
    return how


FILE_SWAPS = ("delete", "empty", "folder", "fifo", "link same", "link other", "link dangling",
              "link devnull")


# ---- run folders read back ------------------------------------------------------------------

RUN_S = 1.0
BLOCK = ["--block", "cam1", "0.3-0.5"]
FRAME_READERS = ("load_run", "diagnose", "export", "check", "design-crossing")
CELL_READERS = ("load_run", "diagnose", "export")
WHOLE_READERS = ("check", "design-crossing")
READERS = {"load_run": 25, "diagnose": 25, "export": 15, "compare": 15, "check": 12,
           "design-crossing": 8}
NOT_NUMBERS = (b"abc", b"", b"nan", b"inf", b"-inf", b"1e999", b"--1", b"0x1F",
               "\u0661\u0662".encode(), b"1_000", b" 1", b'"1,5"', b"True", b"\xff")
WRONG_TYPES = (("experiment", "2"), ("experiment", 2.0), ("experiment", True),
               ("seed", "three"), ("frames", "many"), ("frames_sha256", 5),
               ("cell_files", [1]), ("phases", [1]), ("cameras", "cam1"), ("t_end_s", "end"),
               ("interrupted", "no"), ("metrics_version", "1"), ("identity", [1, 2]),
               ("workpiece", 3))


@dataclass
class Damage:
    """What a case did to a run folder (``what``) and what that asks of its readers."""

    what: list[str] = field(default_factory=list)
    broken: bool = False  # metrics.json unusable, or no run folder: every reader refuses
    frames: bool = False  # frames.csv is not the file the run wrote
    digest: bool = False  # metrics.json's frames_sha256 is another value
    unverified: bool = False  # frames_sha256 gone: frames.csv is not checked
    cell: bool = False  # the kept cell (run_cell.yaml, or a file it names) not the run's
    cell_unverified: bool = False  # cell_files gone: the kept cell is not checked
    cell_sha: bool = False  # cell_sha256 another value: another cell than the reader's
    unfinished: bool = False  # interrupted or failed
    experiment: bool = False  # not a run of experiment 2 or 3
    unknown: bool = False  # metrics edited in a way a reader may take or refuse

    def must_refuse(self, reader: str) -> str | None:
        """Why ``reader`` must refuse the folder (None: it need not)."""
        if self.broken:
            return "metrics.json unusable or no run folder"
        if reader in FRAME_READERS and self.digest:
            return "frames_sha256 changed"
        if reader in FRAME_READERS and self.frames and not self.unverified:
            return "frames.csv changed"
        if reader in CELL_READERS and self.cell and not self.cell_unverified:
            return "the kept cell changed"
        if reader in WHOLE_READERS and (self.unfinished or self.experiment or self.cell_sha):
            return "not a whole run of experiment 2 or 3 of this cell"
        return None

    def must_accept(self, reader: str) -> bool:
        """Nothing ``reader`` reads changed."""
        if reader == "compare":
            return not (self.broken or self.unknown)
        return not (self.must_refuse(reader) or self.unknown or self.unverified and self.frames
                    or self.cell_unverified and self.cell)


def _fixture_run(folder: Path) -> Path:
    """The kind's run (made once): experiment 2, ideal sensor, :data:`RUN_S` seconds."""
    from cellsight.experiments import RunConfig, run_experiment

    run = folder / "fixture" / "run"
    if not (run / "metrics.json").exists():
        with contextlib.redirect_stdout(io.StringIO()):
            run_experiment(RunConfig(2, run, sensor="ideal", duration=RUN_S, progress=False,
                                     video_every=0))
    return run


def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def _damage_frames(rng: random.Random, run: Path, case_dir: Path, d: Damage) -> None:
    path = run / "frames.csv"
    data = path.read_bytes()
    lines = _lines(data)  # the header, the rows, b"" after the last newline
    rows = range(1, len(lines) - 1)
    how = rng.choice(("flip", "cut", "drop row", "rename column", "value", "value", "nan",
                      "crlf", "swap rows", "repeat row", "header only", "not utf-8", "nul",
                      "long field", "touch", "swap"))
    if how == "flip":
        i = rng.randrange(len(data))
        data = data[:i] + bytes([data[i] ^ (1 << rng.randrange(8))]) + data[i + 1:]
    elif how == "cut":
        data = data[:rng.randrange(len(data))]
    elif how == "drop row":
        del lines[rng.choice(rows)]
        data = b"\n".join(lines)
    elif how in ("rename column", "value", "nan", "long field"):
        row = 0 if how == "rename column" else rng.choice(rows)
        cells = lines[row].split(b",")
        j = rng.randrange(len(cells))
        if how == "rename column":
            cells[j] = rng.choice((b"", b"x", cells[j].upper() + b"_", cells[j - 1],
                                   cells[j] + b" "))
        else:
            cells[j] = {"value": rng.choice(NOT_NUMBERS), "nan": b"nan",
                        "long field": b"9" * 200_000}[how]
        lines[row] = b",".join(cells)
        data = b"\n".join(lines)
    elif how == "crlf":
        data = data.replace(b"\n", b"\r\n")
    elif how == "swap rows":
        i, j = rng.sample(list(rows), 2)
        lines[i], lines[j] = lines[j], lines[i]
        data = b"\n".join(lines)
    elif how == "repeat row":
        i = rng.choice(rows)
        lines.insert(i, lines[i])
        data = b"\n".join(lines)
    elif how == "header only":
        data = lines[0] + b"\n"
    elif how in ("not utf-8", "nul"):
        i = rng.randrange(len(data))
        data = data[:i] + (b"\xff\xfe" if how == "not utf-8" else b"\x00") + data[i:]
    if how == "swap":
        how = _replace(path, rng.choice(FILE_SWAPS), case_dir, data, rng)
    else:
        path.write_bytes(data)
    d.what.append(f"frames.csv: {how}")


def _metric_path(data: dict, rng: random.Random) -> list:
    """A random path of keys and indices into the metrics, at least one deep."""
    path, node = [], data
    while True:
        keys = (list(node) if isinstance(node, dict) else
                list(range(len(node))) if isinstance(node, list) else [])
        if not keys or (path and rng.random() < 0.5):
            return path
        key = rng.choice(keys)
        path.append(key)
        node = node[key]


def _set_metric(d: Damage, key: str, value, original: dict) -> None:
    """The flags a top-level ``key`` set to ``value`` (or removed: ``...``) raises."""
    if key == "experiment" and not (type(value) is int and value in (2, 3)):
        d.experiment = True
    elif key == "frames_sha256" and value != original.get(key):
        if value is None or value is ...:
            d.unverified = True
        else:
            d.digest = True
    elif key in ("interrupted", "error") and value is not ... and value:
        d.unfinished = True
    elif key == "cell_files" and value != original.get(key):
        d.cell_unverified = True
    elif key == "cell_sha256" and value not in (None, ..., original.get(key)):
        d.cell_sha = True


def _damage_metrics(rng: random.Random, run: Path, case_dir: Path, d: Damage) -> None:
    path = run / "metrics.json"
    raw = path.read_bytes()
    original = json.loads(raw)
    data = json.loads(raw)
    how = rng.choice(("reformat", "drop key", "wrong type", "hostile value", "hostile value",
                      "experiment", "unfinished", "digest", "cell files", "cut", "flip",
                      "not utf-8", "not an object", "deep", "long number", "newer version",
                      "nan", "workpiece", "swap"))
    text: str | bytes | None = None
    if how == "reformat":
        text = json.dumps(data, indent=rng.choice((None, 2, 4)), sort_keys=True)
    elif how == "drop key":
        key = rng.choice(sorted(data))
        del data[key]
        how += f" {key}"
        _set_metric(d, key, ..., original)
        d.unknown = d.unknown or key in ("workpiece", "robot", "cell", "cameras")
    elif how == "wrong type":
        key, value = rng.choice(WRONG_TYPES)
        data[key] = value
        how += f" {key}"
        d.broken = True
    elif how == "hostile value":
        keys = _metric_path(data, rng)
        node = data
        for key in keys[:-1]:
            node = node[key]
        value = rng.choice(JSON_VALUES)
        node[keys[-1]] = value
        how += f" {'.'.join(map(str, keys))} = {json.dumps(value)[:20]}"
        if len(keys) == 1:
            _set_metric(d, keys[0], value, original)
        d.unknown = True
    elif how == "experiment":
        data["experiment"] = value = rng.choice((1, 3, 4, None))
        how += f" {value}"
        _set_metric(d, "experiment", value, original)
    elif how == "unfinished":
        key, value = rng.choice((("interrupted", True), ("error", "RuntimeError: x")))
        data[key] = value
        how += f" {key}"
        _set_metric(d, key, value, original)
    elif how == "digest":
        value = rng.choice(("0" * 64, data["frames_sha256"].upper(), "", None, ...))
        if value is ...:
            del data["frames_sha256"]
        else:
            data["frames_sha256"] = value
        _set_metric(d, "frames_sha256", value, original)
    elif how == "cell files":
        files = data["cell_files"]
        change = rng.choice(("copy digest", "missing file", "outside file", "none"))
        if change == "copy digest":
            files["run_cell.yaml"] = "0" * 64
            d.cell = True
        elif change == "missing file":
            files[str(case_dir / "gone.stl")] = "0" * 64
            d.cell = True
        elif change == "outside file":
            other = case_dir / "outside" / "mesh.stl"
            other.parent.mkdir(exist_ok=True)
            other.write_text("solid x\nendsolid x\n")
            files[str(other)] = "1" * 64
            d.cell = True
        else:
            data["cell_files"] = rng.choice(({}, None))
            d.cell_unverified = True
        how += f" {change}"
    elif how == "cut":
        text = raw[:rng.randrange(len(raw))]
        d.broken = True
    elif how == "flip":
        i = rng.randrange(len(raw))
        text = raw[:i] + bytes([raw[i] ^ (1 << rng.randrange(8))]) + raw[i + 1:]
        d.unknown = True
    elif how == "not utf-8":
        i = rng.randrange(len(raw))
        text = raw[:i] + b"\xff" + raw[i:]
        d.broken = True
    elif how == "not an object":
        text = rng.choice(("[]", "3", '"x"', "null", "[" + raw.decode() + "]"))
        d.broken = True
    elif how == "deep":
        text = '{"phases": ' + "[" * 100_000 + "]" * 100_000 + "}"
        d.broken = True
    elif how == "long number":
        text = '{"seed": 1' + "0" * 5000 + "}"
        d.broken = True
    elif how == "newer version":
        data["metrics_version"] = 2
        d.broken = True
    elif how == "nan":
        data[rng.choice(("position_rmse_mm", "t_end_s", "wall_s"))] = rng.choice(
            (math.nan, math.inf, -math.inf))
    elif how == "workpiece":
        data["workpiece"] = "nope"
        d.unknown = True
    if how == "swap":
        how = _replace(path, rng.choice(FILE_SWAPS), case_dir, raw, rng)
        if how == "link other":
            d.unknown = True
        elif how != "link same":
            d.broken = True
    elif text is not None:
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
    else:
        path.write_text(json.dumps(data, indent=1))
    d.what.append(f"metrics.json: {how}")


def _damage_cell(rng: random.Random, run: Path, case_dir: Path, d: Damage) -> None:
    path = run / "run_cell.yaml"
    data = path.read_bytes()
    how = rng.choice(("append", "flip", "touch", "swap", "swap"))
    if how == "append":
        path.write_bytes(data + b"\n# edited\n")
    elif how == "flip":
        i = rng.randrange(len(data))
        path.write_bytes(data[:i] + bytes([data[i] ^ (1 << rng.randrange(8))]) + data[i + 1:])
    elif how == "touch":
        path.write_bytes(data)
    else:
        how = _replace(path, rng.choice(FILE_SWAPS), case_dir, data, rng)
    d.what.append(f"run_cell.yaml: {how}")


def _damage_other(rng: random.Random, run: Path, case_dir: Path, d: Damage) -> None:
    """A file no reader reads: the report, the log, the key frames, a figure, a stranger."""
    name = rng.choice(("report.html", "run.log", "keyframes", "keyframes.json",
                       "fig_error.png", "notes.txt"))
    path = run / name
    if name == "notes.txt":
        path.write_text("the user's notes")
        how = "added"
    elif name == "keyframes":
        shutil.rmtree(path)
        path.write_text("not a folder")
        how = "a file"
    else:
        how = _replace(path, rng.choice(("delete", "empty", "folder", "fifo", "link dangling")),
                       case_dir, b"", rng)
    d.what.append(f"{name}: {how}")


def _damage_folder(rng: random.Random, run: Path, fixture: Path, d: Damage) -> None:
    how = rng.choice(("missing", "a file", "empty", "link to the run"))
    shutil.rmtree(run)
    if how == "a file":
        run.write_text("not a folder")
    elif how == "empty":
        run.mkdir()
    elif how == "link to the run":
        run.symlink_to(fixture)
    vars(d).update({**vars(Damage()), "what": [*d.what, f"run folder: {how}"]})  # the rest gone
    d.broken = how != "link to the run"


def _read(reader: str, run: Path, fixture: Path, out: Path, rng: random.Random,
          seconds: float) -> tuple[str, str]:
    """One reader over ``run``: its verdict (:meth:`Outcome.verdict`) and what ran."""
    from cellsight.errors import CellsightError
    from cellsight.runfolder import load_run

    if reader == "load_run":
        try:
            with watchdog(seconds):
                load_run(run)
        except Hang as exc:
            return f"hang: {exc}", reader
        except CellsightError as exc:
            text = str(exc)
            return ("refused" if text.strip() and "\n" not in text.strip() else
                    f"error of {len(text.splitlines())} lines: {text[:300]!r}"), reader
        except Exception as exc:  # noqa: BLE001 - the point of the fuzz
            return _exception_line(exc), reader
        return "accepted", reader
    argv = {"diagnose": ["diagnose", str(run)],
            "check": ["check", "--path", str(run), "--quiet"],
            "design-crossing": ["design-crossing", "--path", str(run), *BLOCK],
            "export": ["export", str(run), "--mcap", str(out / "run.mcap"), "--quiet",
                       *(["--no-images"] if rng.random() < 0.85 else ["--every", "1000"])],
            "compare": ["compare", *((str(run), str(fixture)) if rng.random() < 0.5 else
                                     (str(fixture), str(run)))]}[reader]
    if reader == "diagnose" and rng.random() < 0.3:
        argv.append("--json")
    # check and design-crossing answer 1 for a cell with errors, a clearance too small
    answers = (0, 1) if reader in WHOLE_READERS else (0,)
    outcome = cli(argv, seconds)
    verdict = outcome.verdict(answers)
    if verdict == "accepted" and outcome.status == 1 and "error" in outcome.err:
        verdict = f"exit 1, stderr {outcome.err[-300:]!r}"
    return verdict, " ".join(argv)


def run_folder_case(rng: random.Random, case: int, tally, folder: Path) -> None:
    """A copy of a finished run, damaged, read back: refused when what the reader reads
    changed, answered when nothing did, never a traceback, a hang or a write outside."""
    fixture = _fixture_run(folder)
    case_dir = _fresh(folder / "case")
    run = Path(shutil.copytree(fixture, case_dir / "run", symlinks=True))
    out = case_dir / "out"
    d = Damage()
    damages = {"frames": lambda: _damage_frames(rng, run, case_dir, d),
               "metrics": lambda: _damage_metrics(rng, run, case_dir, d),
               "cell": lambda: _damage_cell(rng, run, case_dir, d),
               "other": lambda: _damage_other(rng, run, case_dir, d),
               "folder": lambda: _damage_folder(rng, run, fixture, d)}
    chosen = rng.choices(list(damages), weights=(35, 35, 12, 12, 6), k=rng.choice((1, 1, 1, 2)))
    for name in sorted(set(chosen), key=list(damages).index):  # once each, the folder last
        damages[name]()
    if run.is_dir() and not run.is_symlink():  # what the damage left of the run's own files
        d.frames = _content(run / "frames.csv") != _content(fixture / "frames.csv")
        d.cell = d.cell or _content(run / "run_cell.yaml") != _content(fixture / "run_cell.yaml")
    reader = rng.choices(list(READERS), weights=list(READERS.values()))[0]
    before = snapshot(folder, out)
    with _figures(rng.random() < FIGURES):
        verdict, what = _read(reader, run, fixture, out, rng, HANG_S["run_folder"])
    changed = changes(before, snapshot(folder, out))
    damage = "; ".join(d.what) or "none"
    if verdict not in ("accepted", "refused"):
        tally.fail(case, f"{verdict} [{damage}; {what[:200]}]")
    elif changed:
        tally.fail(case, f"{verdict}, and changed {changed} outside {out} [{damage}; {what}]")
    elif verdict == "accepted" and d.must_refuse(reader):
        tally.fail(case, f"accepted, though {d.must_refuse(reader)} [{damage}; {what}]")
    elif verdict == "refused" and d.must_accept(reader):
        tally.fail(case, f"refused a run it can read [{damage}; {what}]")
    elif verdict == "refused":
        tally.refused += 1


# ---- recordings tracked ---------------------------------------------------------------------

_MESSAGES: dict[str, list] = {}


def _fixture_recording(folder: Path) -> tuple[Path, list]:
    """The kind's recording (made once: experiment 1, rendered, 0.3 s) and its messages."""
    from recordings import read_mcap

    from cellsight.experiments import RunConfig, run_experiment

    rec = folder / "fixture" / "rec.mcap"
    if not rec.exists():
        with contextlib.redirect_stdout(io.StringIO()):
            run_experiment(RunConfig(1, folder / "fixture" / "run", duration=0.3,
                                     progress=False, record=rec, video_every=0))
    if str(rec) not in _MESSAGES:
        _MESSAGES.clear()
        _MESSAGES[str(rec)] = read_mcap(rec)
    return rec, _MESSAGES[str(rec)]


Item = list  # [topic, type, log time ns, rosbags message]


def _of(items: list[Item], rng: random.Random, *endings: str) -> list[Item]:
    """The items of one random topic ending with one of ``endings``."""
    topics = sorted({it[0] for it in items if it[0].endswith(endings)})
    topic = rng.choice(topics)
    return [it for it in items if it[0] == topic]


def _some(items: list[Item], rng: random.Random) -> list[Item]:
    """All the items, or one of them (a change mid-recording)."""
    return items if rng.random() < 0.5 else [rng.choice(items)]


def _camera_info(items: list[Item], rng: random.Random) -> str:
    how = rng.choice(("K zero", "K nan", "K inf", "fx negative", "fy zero", "cx huge", "D nan",
                      "D long", "D empty", "model", "size", "P nan"))
    for it in _some(_of(items, rng, "/camera_info"), rng):
        m = it[3]
        k, d, p = m.k.copy(), m.d.copy(), m.p.copy()
        if how == "K zero":
            k[:] = 0.0
        elif how in ("K nan", "K inf"):
            k[rng.choice((0, 2, 4, 5))] = math.nan if how == "K nan" else math.inf
        elif how == "fx negative":
            k[0] = -k[0]
        elif how == "fy zero":
            k[4] = 0.0
        elif how == "cx huge":
            k[2] = 1e12
        elif how == "D nan":
            d = np.full(5, math.nan)
        elif how == "D long":
            d = np.zeros(14)
        elif how == "D empty":
            d = np.zeros(0)
        elif how == "model":
            m.distortion_model = rng.choice(("", "equidistant", "rational_polynomial", "x" * 300))
        elif how == "size":
            m.width, m.height = rng.choice(((0, 0), (1, 1), (65535, 576), (768, 0)))
        elif how == "P nan":
            p[0] = math.nan
        m.k, m.d, m.p = k, d, p
    return f"camera_info {how}"


def _image(items: list[Item], rng: random.Random) -> str:
    from recordings import T

    how = rng.choice(("encoding", "narrower", "step", "half data", "no data", "zero size",
                      "big endian", "huge", "compressed", "compressed"))
    for it in _some(_of(items, rng, "/image_raw"), rng):
        m = it[3]
        if how == "encoding":
            m.encoding = rng.choice(("rgb8", "bgr8", "mono16", "16UC1", "bayer_rggb8", "",
                                     "yuv422", "8UC3", "32FC1", "jpeg"))
        elif how == "narrower":
            m.width -= rng.choice((1, 8, 767))
        elif how == "step":
            m.step = rng.choice((0, 1, m.step * 2, 2**32 - 1))
        elif how == "half data":
            m.data = m.data[: len(m.data) // 2].copy()
        elif how == "no data":
            m.data = np.zeros(0, np.uint8)
        elif how == "zero size":
            m.width = m.height = m.step = 0
            m.data = np.zeros(0, np.uint8)
        elif how == "big endian":
            m.is_bigendian = 1
        elif how == "huge":
            m.width = m.height = 100_000
            m.step = 100_000
        else:
            data = rng.choice((b"", b"garbage", b"\xff\xd8\xff" + bytes(100),
                               _png_header(100_000, 100_000), _png_header(8, 8)))
            it[1] = "sensor_msgs/msg/CompressedImage"
            it[3] = T[it[1]](header=m.header, format=rng.choice(("jpeg", "png", "", "mono8")),
                             data=np.frombuffer(data, np.uint8))
            if rng.random() < 0.5:
                it[0] += "/compressed"
    return f"image {how}"


def _png_header(width: int, height: int) -> bytes:
    """A PNG file's start claiming ``width`` x ``height`` (no image data: a bomb's header)."""
    import struct
    import zlib

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    return (b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(ihdr)) + chunk
            + struct.pack(">I", zlib.crc32(chunk)))


def _joints(items: list[Item], rng: random.Random) -> str:
    how = rng.choice(("nan", "inf", "huge", "missing joint", "names short", "unknown joint",
                      "repeated name", "empty", "velocity"))
    chosen = _some(_of(items, rng, "/joint_states"), rng)
    j = rng.randrange(len(chosen[0][3].name))
    for it in chosen:
        m = it[3]
        if j >= len(m.name):  # a message with fewer joints (or one already cut by this case)
            continue
        position = np.asarray(m.position, float).copy()
        names = list(m.name)
        if how in ("nan", "inf", "huge"):
            position[j] = {"nan": math.nan, "inf": -math.inf, "huge": 1e300}[how]
        elif how == "missing joint":
            del names[j]
            position = np.delete(position, j)
        elif how == "names short":
            del names[j]
        elif how == "unknown joint":
            names.append("R7AX/elbow")
            position = np.append(position, 0.1)
        elif how == "repeated name":
            names[j] = names[j - 1]
        elif how == "empty":
            names, position = [], np.zeros(0)
        elif how == "velocity":
            m.velocity = np.zeros(3)
        m.name, m.position = names, position
    return f"joint_states {how}"


def _stamps(items: list[Item], rng: random.Random) -> str:
    how = rng.choice(("backwards", "nanosec", "negative", "far future", "same", "log shuffled",
                      "log zero"))
    chosen = _of(items, rng, "/image_raw", "/camera_info", "/joint_states", "/true_pose")
    it = rng.choice(chosen)
    stamp = it[3].header.stamp
    if how == "backwards":
        stamp.sec, stamp.nanosec = 0, 1000
    elif how == "nanosec":
        stamp.nanosec = 4_000_000_000
    elif how == "negative":
        stamp.sec = -5
    elif how == "far future":
        stamp.sec = 2**31 - 1
    elif how == "same":
        for other in chosen:
            other[3].header.stamp.sec = stamp.sec
            other[3].header.stamp.nanosec = stamp.nanosec
    elif how == "log shuffled":
        times = [other[2] for other in chosen]
        rng.shuffle(times)
        for other, ns in zip(chosen, times, strict=True):
            other[2] = ns
    else:
        it[2] = 0
    return f"{it[0]} stamps {how}"


def _truth(items: list[Item], rng: random.Random) -> str:
    how = rng.choice(("nan", "zero quaternion", "long quaternion", "huge"))
    for it in _some(_of(items, rng, "/true_pose"), rng):
        if not hasattr(it[3], "pose"):  # another mutation gave the topic another type
            continue
        pose = it[3].pose
        if how == "nan":
            pose.position.x = math.nan
        elif how == "zero quaternion":
            q = pose.orientation
            q.x = q.y = q.z = q.w = 0.0
        elif how == "long quaternion":
            pose.orientation.w = 5.0
        else:
            pose.position.z = 1e300
    return f"true_pose {how}"


def _topics(items: list[Item], rng: random.Random) -> str:
    how = rng.choice(("drop topic", "drop some", "repeat some", "another type", "frame id"))
    if how == "drop topic":
        gone = _of(items, rng, "")[0][0]
        items[:] = [it for it in items if it[0] != gone]
        return f"topic {gone} dropped"
    if how == "drop some":
        items[:] = [it for it in items if rng.random() < 0.7]
    elif how == "repeat some":
        items[:] = [copy for it in items for copy in ([it, list(it)] if rng.random() < 0.2
                                                      else [it])]
    elif how == "another type":
        joints = next(it for it in items if it[0] == "/joint_states")
        target = rng.choice(sorted({it[0] for it in items} - {"/joint_states"}))
        items.append([target, joints[1], joints[2], joints[3]])
    else:
        it = rng.choice(items)
        it[3].header.frame_id = rng.choice(("", "x" * 10_000, "é/ü", "\x00"))
    return f"topics {how}"


MESSAGE_EDITS: tuple[Callable[[list[Item], random.Random], str], ...] = (
    _camera_info, _image, _image, _joints, _joints, _stamps, _truth, _topics)


def _write_bag(items: list[Item], out: Path, storage) -> None:
    from recordings import STORE
    from rosbags.rosbag2 import Writer

    with Writer(out, version=8, storage_plugin=storage) as writer:
        connections: dict[tuple[str, str], object] = {}
        for topic, kind, ns, msg in items:
            if (topic, kind) not in connections:
                connections[topic, kind] = writer.add_connection(topic, kind, typestore=STORE)
            writer.write(connections[topic, kind], ns, STORE.serialize_cdr(msg, kind))


def _rewritten(rng: random.Random, messages: list, case_dir: Path) -> tuple[Path, list[str]]:
    """The recording rewritten with 0-2 hostile edits: a bare MCAP file, or a rosbag2 folder
    (MCAP or SQLite storage)."""
    from recordings import to_rosbags
    from rosbags.rosbag2 import StoragePlugin

    items = [[topic, kind, ns, msg] for topic, kind, ns, decoded in messages
             if (msg := to_rosbags(kind, decoded)) is not None]
    what = [rng.choice(MESSAGE_EDITS)(items, rng) for _ in range(rng.choice((0, 1, 1, 1, 2)))]
    form = rng.choice(("mcap file", "rosbag2 mcap", "rosbag2 sqlite"))
    bag = case_dir / "bag"
    _write_bag(items, bag, StoragePlugin.SQLITE3 if form == "rosbag2 sqlite" else
               StoragePlugin.MCAP)
    if form == "mcap file":
        target = case_dir / "rewritten.mcap"
        next(bag.glob("*.mcap")).rename(target)
        shutil.rmtree(bag)
        bag = target
    elif rng.random() < 0.2:
        bag = bag / "metadata.yaml"  # a rosbag2 folder named by its metadata file
    return bag, [form, *what]


def _damaged_bytes(rng: random.Random, rec: Path, case_dir: Path) -> tuple[Path, str, bool]:
    """The recording's bytes damaged; whether it must be refused."""
    data = rec.read_bytes()
    how = rng.choice(("flip", "flip", "cut", "repeat", "remove", "zero", "garbage"))
    if how == "flip":
        out = bytearray(data)
        for _ in range(rng.choice((1, 1, 4, 16))):
            out[rng.randrange(len(out))] ^= 1 << rng.randrange(8)
        data = bytes(out)
    elif how == "cut":
        data = data[:rng.randrange(len(data))]
    elif how in ("repeat", "remove"):
        a = rng.randrange(len(data))
        b = min(len(data), a + rng.choice((1, 8, 100, 5000, 50_000)))
        data = (data[:b] + data[a:]) if how == "repeat" else data[:a] + data[b:]
    elif how == "zero":
        data = b""
    else:
        data = data + os.urandom(rng.choice((1, 100, 10_000)))
    path = case_dir / "rec.mcap"
    path.write_bytes(data)
    return path, f"bytes {how}", how in ("cut", "zero")


def _damaged_file(rng: random.Random, rec: Path, case_dir: Path) -> tuple[Path, str, bool]:
    """Something other than an MCAP file where the recording is; whether it must be refused."""
    how = rng.choice(("empty folder", "folder with bad metadata", "fifo", "link dangling",
                      "link devnull", "link to the recording"))
    path = case_dir / "rec.mcap"
    if how == "empty folder":
        path.mkdir()
    elif how == "folder with bad metadata":
        path.mkdir()
        (path / "metadata.yaml").write_bytes(rng.choice((b"", b"rosbag2_bagfile_information: 1",
                                                         b"{", b"\xff\xfe")))
    elif how == "fifo":
        os.mkfifo(path)
    elif how == "link dangling":
        path.symlink_to(case_dir / "gone.mcap")
    elif how == "link devnull":
        path.symlink_to(os.devnull)
    else:
        path.symlink_to(rec)
    return path, f"file {how}", how != "link to the recording"


def recording_case(rng: random.Random, case: int, tally, folder: Path) -> None:
    """A damaged or hostile recording, tracked: a finished run or a one-line refusal."""
    from cellsight.runfolder import finished_metrics

    rec, messages = _fixture_recording(folder)
    case_dir = _fresh(folder / "case")
    roll = rng.random()
    if roll < 0.3:
        path, what, refuse = _damaged_bytes(rng, rec, case_dir)
        accept = False
    elif roll < 0.4:
        path, what, refuse = _damaged_file(rng, rec, case_dir)
        accept = not refuse
    else:
        path, edits = _rewritten(rng, messages, case_dir)
        what, refuse, accept = ", ".join(edits), False, len(edits) == 1
    out = case_dir / "out"
    argv = ["track", str(path), "--out", str(out), "--quiet"]
    if rng.random() < 0.2:
        argv.append("--calibration-from-bag")
    if rng.random() < 0.15:
        argv += ["--tracker", "plain"]
    if rng.random() < 0.2:
        argv += ["--cell", "dual-arm"]
    if rng.random() < 0.08:
        argv += ["--mcap", str(out / "tracked.mcap")]
    before = snapshot(folder, out)
    with _figures(rng.random() < FIGURES):
        outcome = cli(argv, HANG_S["recording"])
    verdict = outcome.verdict()
    changed = changes(before, snapshot(folder, out))
    finished = out.is_dir() and finished_metrics(out) is not None
    if verdict not in ("accepted", "refused"):
        tally.fail(case, f"{verdict} [{what}]")
    elif changed:
        tally.fail(case, f"{verdict}, and changed {changed} outside {out} [{what}]")
    elif verdict == "accepted" and refuse:
        tally.fail(case, f"tracked a recording it must refuse [{what}]")
    elif verdict == "refused" and accept:
        tally.fail(case, f"refused an intact recording: {outcome.err[-300:]!r} [{what}]")
    elif verdict == "accepted" and not finished:
        tally.fail(case, f"exit 0, yet no finished run in {out} [{what}]")
    elif verdict == "refused" and finished:
        tally.fail(case, f"refused, yet {out} holds a finished run [{what}]")
    elif verdict == "refused":
        tally.refused += 1


# ---- sweeps resumed -------------------------------------------------------------------------

SWEEP_S = "0.3"
PROFILE_TEXT = "timing: {latency_ms: 30.0}\n"
REUSED = re.compile(r"(\d+) runs \((\d+) reused, (\d+) failed\)")
FAILED = re.compile(r"^failed (\S+): ([A-Za-z_][A-Za-z0-9_]*)", re.MULTILINE)
INVALIDATING = {"metrics removed", "metrics cut", "metrics identity seed",
                "metrics identity duration", "metrics identity removed", "metrics interrupted",
                "metrics error", "metrics wrong type", "metrics newer version",
                "metrics folder", "metrics fifo", "metrics of the other seed", "folder removed",
                "folder emptied", "folder a file"}
"""Damage to a run that makes it no longer the finished run its identity asks for."""
HARMLESS = {"metrics reformatted", "metrics figure", "metrics nan figure", "frames removed",
            "frames edited", "stranger", "link to a copy"}
"""Damage to a run that leaves it a finished run of its identity: it is reused."""
MAY_FAIL = {"folder a file", "metrics folder", "metrics fifo", "stranger", "link to a copy"}
"""Damage after which a run that is run again may fail (cellsight's own error, one line)."""


def _sweep_argv(inputs: Path, out: Path, duration: str = SWEEP_S,
                seeds: tuple[str, ...] = ("0", "1"), realism: tuple[str, ...] | None = None,
                cells: tuple[str, ...] | None = None) -> list[str]:
    return ["sweep", "--cells", *(cells or (str(inputs / "my_cell.yaml"),)),
            "--experiments", "1", "--sensors", "ideal", "--duration", duration,
            "--seeds", *seeds, "--realism", *(realism or (str(inputs / "mine.yaml"),)),
            "--quiet", "--jobs", "1", "--out", str(out)]


def _fixture_sweep(folder: Path) -> tuple[Path, Path]:
    """The kind's sweep (made once) and the folder of its cell and profile files."""
    from cellsight.model.loader import cell_path

    inputs, sweep = folder / "inputs", folder / "fixture" / "sweep"
    if not (sweep / "summary.md").exists():
        inputs.mkdir(parents=True, exist_ok=True)
        (inputs / "mine.yaml").write_text(PROFILE_TEXT)
        (inputs / "my_cell.yaml").write_text(cell_path("dual-arm").read_text())
        with _figures(False):
            made = cli(_sweep_argv(inputs, sweep), 600.0)
        assert made.status == 0, (made.crash, made.err[-500:])
    return sweep, inputs


def _signature(path: Path) -> tuple | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns) if stat.S_ISREG(st.st_mode) else None


def _damage_input(rng: random.Random, inputs: Path) -> tuple[str, str]:
    """The profile or the cell file edited in place: (what, effect); effect ``same``,
    ``changed`` (another identity) or ``refused`` (the sweep must refuse it)."""
    name = rng.choice(("mine.yaml", "my_cell.yaml"))
    path = inputs / name
    data = path.read_bytes()
    how = rng.choice(("comment", "value", "invalid", "unknown key", "delete", "folder"))
    if how == "comment":
        path.write_bytes(b"# an edit\n" + data)
    elif how == "value":
        path.write_bytes(data.replace(b"30.0", b"45.0") if name == "mine.yaml" else
                         data.replace(b"name:", b"name: x", 1) if b"name: " in data else
                         data + b"\n# edited\n")
    elif how == "invalid":
        path.write_bytes(data[: len(data) // 2] + b"\n  - ][")
    elif how == "unknown key":
        path.write_bytes(data + b"\nnot_a_key: 1\n")
    elif how == "delete":
        path.unlink()
    else:
        path.unlink()
        path.mkdir()
    if how in ("invalid", "unknown key", "delete", "folder"):
        effect = "refused"
    elif name == "mine.yaml":
        effect = "same" if how == "comment" else "profile"
    else:
        effect = "cell"  # the cell's digest is over its bytes: a comment is another cell
    return f"{name} {how}", effect


def _restore(inputs: Path, pristine: dict[str, bytes]) -> None:
    for name, data in pristine.items():
        path = inputs / name
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        path.unlink(missing_ok=True)
        path.write_bytes(data)


def _damage_run(rng: random.Random, run: Path, other: Path, case_dir: Path) -> str:
    """One damage to a run folder of the sweep, named as in :data:`INVALIDATING` and
    :data:`HARMLESS`."""
    metrics = run / "metrics.json"
    how = rng.choice(("metrics removed", "metrics cut", "metrics reformatted",
                      "metrics identity seed", "metrics identity duration",
                      "metrics identity removed", "metrics interrupted", "metrics error",
                      "metrics figure", "metrics nan figure", "metrics wrong type",
                      "metrics newer version", "metrics folder", "metrics fifo",
                      "metrics of the other seed", "frames removed", "frames edited",
                      "folder removed", "folder emptied", "folder a file", "stranger",
                      "link to a copy"))
    if how == "metrics of the other seed" and not (other / "metrics.json").is_file():
        how = "metrics removed"  # the other run's own damage took its metrics away
    raw = metrics.read_bytes()
    data = json.loads(raw)
    edits = {"metrics identity seed": ("identity", {**data["identity"], "seed": 7}),
             "metrics identity duration": ("identity", {**data["identity"], "duration_s": 9.0}),
             "metrics interrupted": ("interrupted", True),
             "metrics error": ("error", "RuntimeError: x"),
             "metrics figure": ("position_rmse_mm", 123.0),
             "metrics nan figure": ("position_rmse_mm", rng.choice((math.nan, math.inf))),
             "metrics wrong type": ("seed", "zero"), "metrics newer version":
             ("metrics_version", 2)}
    if how in edits:
        key, value = edits[how]
        metrics.write_text(json.dumps({**data, key: value}, indent=1))
    elif how == "metrics identity removed":
        del data["identity"]
        metrics.write_text(json.dumps(data))
    elif how == "metrics reformatted":
        metrics.write_text(json.dumps(data, indent=4, sort_keys=True))
    elif how in ("metrics removed", "metrics cut", "metrics folder", "metrics fifo"):
        metrics.unlink()
        if how == "metrics cut":
            metrics.write_bytes(raw[:rng.randrange(len(raw))])
        elif how == "metrics folder":
            metrics.mkdir()
        elif how == "metrics fifo":
            os.mkfifo(metrics)
    elif how == "metrics of the other seed":
        shutil.copy(other / "metrics.json", metrics)
    elif how == "frames removed":
        (run / "frames.csv").unlink()
    elif how == "frames edited":
        frames = run / "frames.csv"
        frames.write_bytes(frames.read_bytes().replace(b"0", b"1", 3))
    elif how == "stranger":
        (run / "notes.txt").write_text("the user's notes")
    else:
        copy = case_dir / "elsewhere" / run.name
        if how == "link to a copy":
            shutil.copytree(run, copy, symlinks=True)
        shutil.rmtree(run)
        if how == "folder emptied":
            run.mkdir()
        elif how == "folder a file":
            run.write_text("not a folder")
        elif how == "link to a copy":
            run.symlink_to(copy)
    return how


def _damage_sweep_files(rng: random.Random, out: Path) -> str:
    how = rng.choice(("sweep.json removed", "sweep.json garbled", "sweep.json a folder",
                      "summary.md removed", "summary.csv garbled"))
    name, _, change = how.partition(" ")
    path = out / name
    if path.is_dir():
        path.rmdir()
    path.unlink(missing_ok=True)
    if change == "garbled":
        path.write_bytes(b"\xff{[")
    elif change == "a folder":
        path.mkdir()
    return how


def sweep_resume_case(rng: random.Random, case: int, tally, folder: Path) -> None:
    """A copy of a finished sweep, damaged, resumed: a run reused only with its identity,
    an intact one reused, the count printed right, no traceback, hang or write outside."""
    from cellsight.sweep.grid import RunSpec

    fixture, inputs = _fixture_sweep(folder)
    case_dir = _fresh(folder / "case")
    out = Path(shutil.copytree(fixture, case_dir / "out", symlinks=True))
    pristine = {p.name: p.read_bytes() for p in inputs.iterdir()}
    cell_file, profile = str(inputs / "my_cell.yaml"), str(inputs / "mine.yaml")
    what: list[str] = []
    duration, seeds, realism, overwrite = SWEEP_S, ("0", "1"), (profile,), False
    roll = rng.random()
    if roll < 0.1:
        duration = rng.choice(("0.25", "0.30", "0.2999999"))
        what.append(f"--duration {duration}")
    elif roll < 0.2:
        seeds = rng.choice((("1",), ("1", "0"), ("0", "2")))
        what.append(f"--seeds {' '.join(seeds)}")
    elif roll < 0.25:
        realism = rng.choice((("exact", profile), ("exact",)))
        what.append(f"--realism {' '.join(Path(r).name for r in realism)}")
    elif roll < 0.3:
        overwrite = True
        what.append("--overwrite")
    effect = "same"
    try:
        if rng.random() < 0.25:
            change, effect = _damage_input(rng, inputs)
            what.append(change)
            if change.startswith("mine.yaml") and profile not in realism:
                effect = "same"  # a profile the sweep does not use
        runs = {seed: RunSpec(cell_file, 1, "ideal", "kinematic", int(seed), None, profile)
                .folder for seed in ("0", "1")}
        damaged: dict[Path, set[str]] = {}
        for _ in range(rng.choice((0, 1, 1, 1, 2))):
            if rng.random() < 0.85:
                seed = rng.choice(("0", "1"))
                run = out / runs[seed]
                if runs[seed] in damaged:  # each run damaged once at most
                    continue
                how = _damage_run(rng, run, out / runs["1" if seed == "0" else "0"], case_dir)
                damaged.setdefault(runs[seed], set()).add(how)
                what.append(f"s{seed}: {how}")
            else:
                what.append(_damage_sweep_files(rng, out))
        _resume(rng, case, tally, folder, out, inputs, what, effect, damaged,
                (duration, seeds, realism, overwrite))
    finally:
        _restore(inputs, pristine)


def _resume(rng: random.Random, case: int, tally, folder: Path, out: Path, inputs: Path,
            what: list[str], effect: str, damaged: dict[Path, set[str]], asked: tuple) -> None:
    """Resume the damaged copy ``out`` and judge it (:func:`sweep_resume_case`)."""
    from cellsight.errors import CellsightError
    from cellsight.sweep.grid import RunSpec

    duration, seeds, realism, overwrite = asked
    cell_file, profile = str(inputs / "my_cell.yaml"), str(inputs / "mine.yaml")
    grid = [RunSpec(cell_file, 1, "ideal", "kinematic", int(s), None, r).folder
            for r in realism for s in seeds]
    existed = {RunSpec(cell_file, 1, "ideal", "kinematic", s, None, profile).folder
               for s in (0, 1)}
    sweep_json = out / "sweep.json"  # none: a folder holding summary.* is no sweep to resume
    refusal = effect == "refused" or sweep_json.is_dir() or (
        not sweep_json.exists() and not overwrite)
    inputs_changed = {r: float(duration) != float(SWEEP_S) or effect == "cell" or (
        effect == "profile" and "mine" in str(r)) for r in grid}
    must_not = {r for r in grid if r not in existed or inputs_changed[r]
                or damaged.get(r, set()) & INVALIDATING}
    must_reuse = {r for r in grid if r not in must_not and damaged.get(r, set()) <= HARMLESS}
    may_fail = any(d & MAY_FAIL for d in damaged.values())
    signatures = {r: _signature(out / r / "metrics.json") for r in grid}
    argv = _sweep_argv(inputs, out, duration, seeds, realism)
    if overwrite:
        argv.append("--overwrite")
    before, before_out = snapshot(folder, out), snapshot(out)
    with _figures(rng.random() < FIGURES):
        outcome = cli(argv, HANG_S["sweep_resume"])
    verdict = outcome.verdict((0, 1))
    changed = changes(before, snapshot(folder, out))
    shown = "; ".join(what) or "nothing changed"

    def fail(text: str) -> None:
        tally.fail(case, f"{text} [{shown}]")

    counted = REUSED.search(outcome.out)
    failed = dict(FAILED.findall(outcome.out))
    clean = {c.__name__ for c in _subclasses(CellsightError)}
    reused = {r for r in grid if signatures[r] is not None and str(r) not in failed
              and _signature(out / r / "metrics.json") == signatures[r]}
    if verdict not in ("accepted", "refused"):
        fail(verdict)
    elif changed:
        fail(f"{verdict}, and changed {changed} outside {out}")
    elif refusal and (verdict != "refused" or changes(before_out, snapshot(out))):
        fail(f"exit {outcome.status}, expected a refusal before anything is written: "
             f"{outcome.err[-300:]!r}")
    elif verdict == "refused" and not refusal and not may_fail:
        fail(f"refused: {outcome.err[-300:]!r}")
    elif verdict == "refused":
        tally.refused += 1
    elif outcome.status == 1 and (not failed or not may_fail):
        fail(f"exit 1: {sorted(failed.items())[:3]}, {outcome.err[-200:]!r}")
    elif bad := sorted((f, kind) for f, kind in failed.items() if kind not in clean):
        fail(f"runs failed with an error not cellsight's own: {bad[:3]}")
    elif counted is None or int(counted[1]) != len(grid) or int(counted[3]) != len(failed):
        fail(f"printed {counted[0] if counted else 'no count'} for {len(grid)} runs, "
             f"{len(failed)} failed")
    elif not set(failed) <= {str(r) for r in grid}:
        fail(f"failed runs {sorted(failed)} are not runs of the grid")
    elif int(counted[2]) != len(reused):
        fail(f"printed {counted[0]}, yet {len(reused)} runs were left as they were")
    elif wrongly := sorted(str(r) for r in reused & must_not):
        fail(f"reused {wrongly}, whose identity is not the one asked for")
    elif missed := sorted(str(r) for r in must_reuse - reused):
        fail(f"ran {missed} again, though intact and of the same inputs")
    elif stale := [str(r) for r in grid if r not in reused and str(r) not in failed
                   and not _rerun_of(out / r, duration, int(r.name.rpartition("_s")[2]))]:
        fail(f"{stale}: run again, yet its metrics.json is not of the run asked for")
    elif failed or len(reused) < len(grid):
        tally.refused += 1


def _rerun_of(run: Path, duration: str, seed: int) -> bool:
    """The folder holds a finished run of ``duration`` and ``seed``."""
    from cellsight.runfolder import finished_metrics

    metrics = finished_metrics(run)
    identity = (metrics or {}).get("identity") or {}
    return identity.get("duration_s") == float(duration) and identity.get("seed") == seed


def _subclasses(cls: type) -> Iterator[type]:
    for sub in cls.__subclasses__():
        yield sub
        yield from _subclasses(sub)
