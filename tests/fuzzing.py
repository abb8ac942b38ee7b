"""Fuzz cases for hostile and random input (issue 14), shared by ``tests/test_fuzz.py`` (a few
thousand cases per ``make test``) and ``scripts/fuzz.py`` (``make fuzz``: 10^5 and more).

Each kind draws cases from a seeded generator and judges each one:

- ``soup``: a random polygon soup (random polygons, convex solids, non-convex prisms), a
  random viewpoint and 24 random points; :func:`cellsight.occlusion.visible_mask` must agree
  with the independent segment oracle (``tests/oracle.py``) on every point the oracle does not
  call ambiguous (a crossing within a hair of an edge or a plane);
- ``hostile_soup``: polygons with NaN, infinite, huge (1e12 m) or tiny (1e-12 m) coordinates,
  repeated or collinear vertices, too few vertices, bow ties, points and viewpoints with NaN:
  a :class:`~cellsight.errors.GeometryError` or an answer, never another exception;
- ``cell_file``: a small valid cell file, mutated (a value replaced by a hostile one, a key
  removed, a list emptied or repeated, a value moved elsewhere): loading it gives a cell or a
  :class:`~cellsight.errors.CellsightError`; a cell that loads is predicted at its nominal
  state, with the same rule;
- ``cell_text``: the same file's text, damaged (cut, bytes inserted or flipped, non-UTF-8,
  YAML tags and aliases): the same rule;
- ``cli``: ``cellsight visibility`` / ``compare`` / ``run`` with random, mostly hostile
  arguments (JSON values of every type, NaN, huge numbers, long strings, paths), run in
  process: an exit status of 0, 1 or 2 and no traceback;
- ``out_folder``, ``replay``, ``write_failure``: the run folder's families
  (``tests/fuzz_folders.py``): a writing command refuses bad arguments and a taken ``--out``
  before it changes anything, a replay refuses a changed cell, a failed write is never a
  finished run;
- ``run_folder``, ``recording``, ``sweep_resume``: what reads files back
  (``tests/fuzz_inputs.py``): a damaged run folder read by each of its readers, a damaged or
  hostile recording tracked, a damaged sweep resumed: an answer or a one-line refusal (the
  refusal where the input cannot be trusted, a run reused only with its identity), never a
  traceback, a hang or a write outside the output folder.

A failure is a disagreement or an unexpected exception; :func:`run_kind` returns them.
"""

from __future__ import annotations

import copy
import json
import math
import random
import tempfile
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from fuzz_folders import out_folder_case, replay_case, run_cli, write_failure_case
from fuzz_inputs import recording_case, run_folder_case, sweep_resume_case
from oracle import random_convex_solid, random_prism, random_soup, segment_oracle

from cellsight.errors import CellsightError, GeometryError

KINDS = ("soup", "hostile_soup", "cell_file", "cell_text", "cli", "out_folder", "replay",
         "write_failure", "run_folder", "recording", "sweep_resume")

SMALL_CELL = {
    "name": "fuzz cell",
    "workpieces": [{
        "name": "part",
        "solid": {"prism": {"polygon": [[-0.05, -0.03], [0.05, -0.03], [0.05, 0.03],
                                        [0.02, 0.03], [0.02, 0.01], [-0.02, 0.01],
                                        [-0.02, 0.03], [-0.05, 0.03]], "height": 0.03}},
        "pose": {"xyz": [0.55, 0.0, 0.62], "rpy": [0.0, 0.0, 0.35]},
        "grasp": {"xyz": [0.0, -0.01, 0.015], "rpy": [0.0, 3.14159, 0.0]},
    }],
    "robots": [{
        "name": "arm",
        "base": {"xyz": [0.5, -0.6, 0.0]},
        "links": [
            {"a": 0.0, "alpha": -1.5708, "d": 0.6, "qlim": [-3.0, 3.0],
             "solids": [{"box": {"size": [0.2, 0.2, 0.2]}}]},
            {"a": 0.5, "qlim": [-2.0, 2.0],
             "solids": [{"segment": {"start": [-0.5, 0.0, 0.0], "end": [0.0, 0.0, 0.0],
                                     "width": 0.12}}]},
        ],
        "tool": {"mount": {"xyz": [0.0, 0.0, 0.0]},
                 "palm": [{"box": {"size": [0.08, 0.15, 0.07], "center": [0.0, 0.0, 0.035]}}],
                 "jaw": {"box": {"size": [0.035, 0.012, 0.09], "center": [0.0, 0.006, 0.115]}},
                 "max_opening": 0.09, "tcp": [0.0, 0.0, 0.145]},
        "home": [0.3, -0.4],
        "final": [0.5, -0.3],
    }],
    "static": [{"name": "table",
                "solids": [{"box": {"size": [1.8, 0.9, 0.05], "center": [0.8, 0.0, 0.575]}}]}],
    "cameras": [{"name": "cam1", "width": 320, "height": 240, "fx": 400.0,
                 "look_at": {"eye": [0.3, 1.2, 1.7], "target": [0.6, 0.0, 0.65]}},
                {"name": "cam2", "width": 320, "height": 240, "lens_mm": 8.0, "pixel_mm": 0.01,
                 "dist": [0.01, -0.02, 0.0, 0.0, 0.0],
                 "look_at": {"eye": [1.4, 1.1, 1.6], "target": [0.6, 0.0, 0.65]}}],
}

FOLDER_CASES = {"out_folder": out_folder_case, "replay": replay_case,
                "write_failure": write_failure_case,  # tests/fuzz_folders.py
                "run_folder": run_folder_case, "recording": recording_case,
                "sweep_resume": sweep_resume_case}  # tests/fuzz_inputs.py

HOSTILE_VALUES = (None, True, False, 0, -1, 1, 7, 1e300, -1e300, math.nan, math.inf, -math.inf,
                  "", "x", "nan", "a/b", "../../etc", "é" * 5, "x" * 300, [], {}, [0], [1, 2],
                  [1, 2, 3], [[1, 2, 3]], {"a": 1}, [None, None, None], ["1", "2", "3"],
                  [math.nan] * 3, [1e300] * 3, [-1.0, -1.0, -1.0], [0.0, 0.0, 0.0])


@dataclass
class Tally:
    """Outcome of some cases of one kind: counts and the failures found (one line each)."""

    kind: str
    cases: int = 0
    refused: int = 0  # cases answered by a clear error (a GeometryError / CellsightError)
    queries: int = 0  # point queries compared with the oracle (soup)
    hidden: int = 0  # of those, hidden by the oracle's answer
    ambiguous: int = 0
    failures: list[str] = field(default_factory=list)
    on_failure: Callable[[str], None] | None = None  # told each failure as it is found

    def fail(self, case: int, what: str) -> None:
        line = f"{self.kind} case {case}: {what}"
        self.failures.append(line)
        if self.on_failure is not None:
            self.on_failure(line)


def _exception_line(exc: BaseException) -> str:
    frame = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    where = f" at {Path(frame.filename).name}:{frame.lineno}" if frame else ""
    return f"{type(exc).__name__}: {str(exc)[:200]}{where}"


# ---- soups -----------------------------------------------------------------------------------

def _scene(rng: np.random.Generator) -> list[np.ndarray]:
    """Random polygons, or a few random solids (convex or non-convex) with some polygons."""
    if rng.random() < 0.5:
        return random_soup(rng, int(rng.integers(1, 30)))
    polygons = []
    for _ in range(int(rng.integers(1, 5))):
        make = random_convex_solid if rng.random() < 0.5 else random_prism
        polygons += make(rng, rng.uniform(-1.0, 1.0, 3), rng.uniform(0.2, 1.0))[0]
    return polygons + random_soup(rng, int(rng.integers(0, 6)))


def soup_case(rng: np.random.Generator, case: int, tally: Tally) -> None:
    """BSP against the oracle on one random scene, viewpoint and 24 points."""
    from cellsight.occlusion import visible_mask

    polygons = _scene(rng)
    points = rng.uniform(-2.0, 2.0, (24, 3))
    view = rng.normal(size=3)
    view *= rng.uniform(2.5, 6.0) / np.linalg.norm(view)
    visible = visible_mask(polygons, points, view)
    answer = segment_oracle(polygons, points, view)
    keep = ~answer.ambiguous
    tally.queries += len(points)
    tally.ambiguous += int((~keep).sum())
    tally.hidden += int((keep & ~answer.visible).sum())
    wrong = np.flatnonzero(keep & (visible != answer.visible))
    if len(wrong):
        tally.fail(case, f"{len(wrong)} of 24 points disagree with the oracle (first: point "
                         f"{wrong[0]}, bsp {visible[wrong[0]]})")


def _hostile_polygon(rng: np.random.Generator) -> np.ndarray:
    poly = rng.uniform(-1.0, 1.0, (int(rng.integers(3, 7)), 3))
    kind = int(rng.integers(0, 9))
    if kind == 0:
        poly[rng.integers(len(poly)), rng.integers(3)] = math.nan
    elif kind == 1:
        poly[rng.integers(len(poly)), rng.integers(3)] = math.inf
    elif kind == 2:
        poly *= 1e12
    elif kind == 3:
        poly *= 1e-12
    elif kind == 4:
        poly[1] = poly[0]
    elif kind == 5:
        poly = np.linspace(poly[0], poly[1], len(poly))  # collinear
    elif kind == 6:
        poly = poly[:2]
    elif kind == 7:
        poly = np.array([[0, 0, 0], [1, 1, 0], [1, 0, 0], [0, 1, 0]], float)  # bow tie
    return poly


def hostile_soup_case(rng: np.random.Generator, case: int, tally: Tally) -> None:
    """Degenerate and non-finite input: a clear GeometryError or an answer."""
    from cellsight.occlusion import visible_mask

    polygons = random_soup(rng, int(rng.integers(0, 4))) + [
        _hostile_polygon(rng) for _ in range(int(rng.integers(1, 3)))]
    points = rng.uniform(-2.0, 2.0, (int(rng.integers(0, 6)), 3))
    view = rng.uniform(-5.0, 5.0, 3)
    if rng.random() < 0.1 and len(points):
        points[0, 0] = math.nan
    if rng.random() < 0.05:
        view[1] = math.nan
    try:
        visible = visible_mask(polygons, points, view)
        if visible.shape != (len(points),):
            tally.fail(case, f"answer of shape {visible.shape} for {len(points)} points")
    except GeometryError:
        tally.refused += 1
    except Exception as exc:  # noqa: BLE001 - the point of the fuzz
        tally.fail(case, _exception_line(exc))


# ---- cell files ------------------------------------------------------------------------------

def _paths(node, prefix=()) -> Iterator[tuple]:
    """Every path (a tuple of keys and indices) into a nested dict/list, the root excluded."""
    items = node.items() if isinstance(node, dict) else (
        enumerate(node) if isinstance(node, list) else ())
    for key, value in items:
        yield (*prefix, key)
        yield from _paths(value, (*prefix, key))


def _mutate(data: dict, rng: random.Random) -> dict:
    """One to three random mutations of a copy of ``data``."""
    data = copy.deepcopy(data)
    for _ in range(rng.randint(1, 3)):
        paths = list(_paths(data))
        if not paths:
            break
        path = rng.choice(paths)
        parent = data
        for key in path[:-1]:
            parent = parent[key]
        key = path[-1]
        op = rng.random()
        if op < 0.55:
            parent[key] = copy.deepcopy(rng.choice(HOSTILE_VALUES))
        elif op < 0.7:
            del parent[key]
        elif op < 0.8:
            parent[key] = copy.deepcopy(_get(data, rng.choice(paths)))
        elif op < 0.9 and isinstance(parent[key], list):
            parent[key] = parent[key] * rng.choice((0, 2, 3))
        elif isinstance(parent, dict):
            parent[rng.choice(("extra", "name", "solid", "links", "fx", "kind"))] = copy.deepcopy(
                rng.choice(HOSTILE_VALUES))
    return data


def _get(data, path):
    for key in path:
        data = data[key]
    return data


def _load_and_predict(text: bytes, case: int, tally: Tally, folder: Path) -> None:
    """Load a cell file's bytes and predict at the nominal state: a result or a clear error."""
    from cellsight import load_cell
    from cellsight.occlusion.backends import visibility_predictor

    path = folder / f"cell{case % 8}.yaml"
    path.write_bytes(text)
    try:
        cell = load_cell(path)
        visibility_predictor(cell).predict()
    except CellsightError as exc:
        tally.refused += 1
        message = str(exc)
        if "\n" in message.strip() or len(message) > 2000:
            tally.fail(case, f"error message of {len(message)} characters / several lines")
    except Exception as exc:  # noqa: BLE001 - the point of the fuzz
        tally.fail(case, _exception_line(exc))


def _dump(data) -> str:
    return yaml.safe_dump(data, allow_unicode=True, sort_keys=False)


def cell_file_case(rng: random.Random, case: int, tally: Tally, folder: Path) -> None:
    """A mutated small cell file."""
    _load_and_predict(_dump(_mutate(SMALL_CELL, rng)).encode("utf-8"), case, tally, folder)


TEXT_INSERTS = (b"\xff\xfe", b"\x00", b"!!python/object/apply:os.system ['true']", b"&a [1, 2]",
                b"*a", b"{", b"]", b": :", b"- - -", b"\t", b"'", b'"', b"? ", b"!!binary AA==",
                b"<<: *a", b"%YAML 1.1\n---\n", b"...\n", b"\n" * 3, b"1e9999", b".nan")


def cell_text_case(rng: random.Random, case: int, tally: Tally, folder: Path) -> None:
    """The small cell file's text, damaged."""
    text = bytearray(_dump(SMALL_CELL).encode("utf-8"))
    for _ in range(rng.choice((1, 1, 1, 2, 3))):
        at = rng.randrange(len(text) + 1)
        op = rng.random()
        if op < 0.1:
            del text[at:]
        elif op < 0.45:
            text[at:at] = rng.choice(TEXT_INSERTS)
        elif op < 0.7 and at < len(text):
            text[at] = rng.randrange(256)
        elif op < 0.85 and at < len(text):
            text[at] = rng.choice(b"0123456789-.,: []{}")
        else:
            del text[at:at + rng.randint(1, 8)]
        if not text:
            break
    _load_and_predict(bytes(text), case, tally, folder)


# ---- command line ----------------------------------------------------------------------------

def _json_value(rng: random.Random, depth: int = 0):
    roll = rng.random()
    if depth > 2 or roll < 0.45:
        return rng.choice(HOSTILE_VALUES)
    if roll < 0.7:
        return [_json_value(rng, depth + 1) for _ in range(rng.randint(0, 7))]
    keys = ("R7AX", "R6AX", "part", "xyz", "rpy", "x", "", "cam1")
    return {rng.choice(keys): _json_value(rng, depth + 1) for _ in range(rng.randint(0, 3))}


def _joints_arg(rng: random.Random) -> str:
    if rng.random() < 0.3:
        return json.dumps({"R7AX": [rng.uniform(-1, 1) for _ in range(7)],
                           rng.choice(("R6AX", "R5AX")): _json_value(rng, 1)})
    return json.dumps(_json_value(rng))


def _pose_arg(rng: random.Random) -> str:
    if rng.random() < 0.4:
        pose = {"xyz": [rng.uniform(-1, 1) for _ in range(3)], "rpy": _json_value(rng, 2)}
        return json.dumps({rng.choice(("part", "nope")): pose})
    if rng.random() < 0.2:
        matrix = np.eye(4)
        matrix[:3, :3] *= rng.choice((1.0, 2.0, -1.0))
        matrix[3] = rng.choice(([0, 0, 0, 1], [1, 0, 0, 1]))
        return json.dumps({"part": matrix.tolist()})
    return json.dumps(_json_value(rng))


def _cli_argv(rng: random.Random, folder: Path) -> list[str]:
    command = rng.choices(("visibility", "compare", "run"), weights=(6, 2, 2))[0]
    if command == "visibility":
        argv = ["visibility", "--json"]
        if rng.random() < 0.8:
            argv += ["--joints", _joints_arg(rng)]
        if rng.random() < 0.8:
            argv += ["--part-pose", _pose_arg(rng)]
        if rng.random() < 0.1:
            argv += ["--cell", rng.choice((str(folder), str(folder / "missing.yaml"), "x" * 300))]
        return argv
    if command == "compare":
        runs = []
        for name in ("a", "b"):
            run = folder / f"run_{name}"
            run.mkdir(exist_ok=True)
            content = rng.choice((json.dumps(_json_value(rng)).encode(), b"\xff\xfe{",
                                  b"{\"position_rmse_mm\": 1.0}", b"[1, 2]", b"{"))
            (run / "metrics.json").write_bytes(content)
            runs.append(str(run) if rng.random() < 0.9 else str(folder / "missing"))
        return ["compare", *runs]
    seed = rng.choice(("-1", "x", "1.5", "nan", "99999999999999999999"))
    duration = rng.choice(("nan", "inf", "-1", "0", "abc", "-inf", "1e999"))
    argv = ["run", rng.choice(("3", "0", "4", "x")), "--seed", seed, "--duration", duration,
            "--out", str(folder / "runs" / "r"), "--quiet", "--sensor", "ideal"]
    return argv if rng.random() < 0.7 else [*argv[:2], "--out", str(folder / "file.txt")]


def cli_case(rng: random.Random, case: int, tally: Tally, folder: Path) -> None:
    """``cellsight`` in process with random arguments: exit 0, 1 or 2, never a traceback."""

    (folder / "file.txt").write_text("not a folder")
    argv = _cli_argv(rng, folder)
    try:
        status, err = run_cli(argv)
    except Exception as exc:  # noqa: BLE001 - the point of the fuzz
        tally.fail(case, f"{_exception_line(exc)} for {json.dumps(argv)[:300]}")
        return
    if status not in (0, 1, 2) or "Traceback" in err:
        tally.fail(case, f"exit {status}, stderr {err[-300:]!r} for {json.dumps(argv)[:300]}")
    elif status:
        tally.refused += 1


# ---- driver ----------------------------------------------------------------------------------

def run_kind(kind: str, cases: int, seed: int = 0,
             progress: Callable[[int], None] | None = None,
             on_failure: Callable[[str], None] | None = None) -> Tally:
    """Run ``cases`` cases of ``kind`` (one of :data:`KINDS`) from ``seed``; ``progress`` is
    called with the number of cases done after each one, ``on_failure`` with each failure."""
    tally = Tally(kind, on_failure=on_failure)
    np_rng = np.random.default_rng([seed, KINDS.index(kind)])
    py_rng = random.Random(seed * 1000 + KINDS.index(kind))
    with tempfile.TemporaryDirectory(prefix=f"fuzz-{kind}-") as tmp:
        folder = Path(tmp)
        for case in range(cases):
            if kind == "soup":
                soup_case(np_rng, case, tally)
            elif kind == "hostile_soup":
                hostile_soup_case(np_rng, case, tally)
            elif kind == "cell_file":
                cell_file_case(py_rng, case, tally, folder)
            elif kind == "cell_text":
                cell_text_case(py_rng, case, tally, folder)
            elif kind == "cli":
                cli_case(py_rng, case, tally, folder)
            else:
                try:
                    FOLDER_CASES[kind](py_rng, case, tally, folder)
                except Exception as exc:  # noqa: BLE001 - the point of the fuzz
                    tally.fail(case, _exception_line(exc))
            tally.cases += 1
            if progress is not None:
                progress(case + 1)
    return tally
