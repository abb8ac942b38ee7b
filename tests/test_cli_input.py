"""Bad command-line input: one clear line naming the argument and the value, exit status 2,
no traceback, no output folder (issue 14, first cases)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cellsight.cli import main


@pytest.mark.parametrize(("args", "message"), [
    (["--joints", '{"R7AX": "abc"}'], "--joints: robot 'R7AX': expected finite numbers, got 'abc'"),
    (["--joints", '{"R7AX": [0, NaN, 0, 0, 0, 0, 0]}'], "--joints: robot 'R7AX': expected finite"),
    (["--joints", "[1, 2]"], "--joints: expected an object robot -> list of numbers, got [1, 2]"),
    (["--part-pose", '{"part": {"xzy": [0.6, 0, 0.62]}}'], "unknown keys ['xzy']; expected xyz"),
    (["--part-pose", '{"part": {"xyz": [0.6, 0]}}'], "'part'.xyz: expected finite numbers of "
                                                      "shape (3,)"),
    (["--part-pose", json.dumps({"part": (2 * np.eye(4)).tolist()})], "expected a rigid"),
    (["--part-pose", json.dumps({"part": np.diag([1.0, 1.0, -1.0, 1.0]).tolist()})],
     "expected a rigid"),
    (["--part-pose", json.dumps({"part": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                          [1, 1, 1, 1]]})], "last row 0 0 0 1"),
])
def test_bad_joints_and_poses_give_one_clear_line(args, message, capsys) -> None:
    assert main(["visibility", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cellsight: error: ") and message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_long_values_are_json_not_file_names(capsys) -> None:
    """A value longer than a file name may be was tried as a path first (OSError)."""
    joints = '{' + " " * 300 + '"R7AX": [0.3, 0.0, -0.5, 0.9, 0.0, 1.2, 0.0]}'
    assert main(["visibility", "--joints", joints, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)
    assert main(["visibility", "--joints", "x" * 300]) == 2
    assert "--joints: not valid JSON" in capsys.readouterr().err


def test_a_json_file_that_is_not_utf8_is_named(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "joints.json"
    bad.write_bytes(b'{"R7AX": "\\xff\xff"}')
    assert main(["visibility", "--joints", str(bad)]) == 2
    assert f"--joints: {bad}: not UTF-8 text" in capsys.readouterr().err


@pytest.mark.parametrize(("option", "value", "message"), [
    ("--duration", "inf", "--duration: expected a positive, finite number of seconds, got inf"),
    ("--duration", "nan", "--duration: expected a positive, finite number of seconds, got nan"),
    ("--seed", "-1", "--seed: expected a whole number >= 0, got -1"),
])
def test_bad_run_options_are_refused_before_any_output(option, value, message, tmp_path: Path,
                                                       capsys) -> None:
    out = tmp_path / "run"
    assert main(["run", "1", "--out", str(out), "--quiet", option, value]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()
