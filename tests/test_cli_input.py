"""Bad command-line input: one clear line naming the argument and the value, exit status 2,
no traceback, no output folder (issue 14, first cases)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from oracle import cell_scene, segment_oracle

from cellsight import load_cell
from cellsight.cli import main
from cellsight.model.grasp import default_grasp_pose


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


@pytest.mark.parametrize(("option", "value"), [("--tracker", "fancy"), ("--experimental", "warp")])
def test_an_unknown_tracker_option_is_refused_with_the_choices(option, value, tmp_path: Path,
                                                                capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["run", "1", "--out", str(tmp_path / "run"), option, value])
    assert stop.value.code == 2 and not (tmp_path / "run").exists()
    assert f"argument {option}: invalid choice: '{value}'" in capsys.readouterr().err


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


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("cellsight: error: ") and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    return err


def test_a_non_empty_out_is_refused_untouched(tmp_path: Path, capsys) -> None:
    """An older run's views.mp4 would end up in a new ideal-sensor report: refused."""
    (tmp_path / "views.mp4").write_bytes(b"older run")
    assert main(["run", "1", "--out", str(tmp_path), "--quiet", "--sensor", "ideal"]) == 2
    err = _one_error_line(capsys)
    assert f"--out: '{tmp_path}' is not empty" in err and "pass --overwrite" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["views.mp4"]


def test_overwrite_refuses_a_folder_holding_more_than_a_run(tmp_path: Path, capsys) -> None:
    (tmp_path / "frames.csv").write_text("older run")
    (tmp_path / "keyframes").mkdir()
    (tmp_path / "keyframes" / "notes.txt").write_text("mine")
    (tmp_path / "thesis.tex").write_text("mine")
    assert main(["run", "1", "--out", str(tmp_path), "--quiet", "--overwrite"]) == 2
    err = _one_error_line(capsys)
    assert "holds 'keyframes', not a run's output" in err  # the first in name order
    assert {p.name for p in tmp_path.iterdir()} == {"frames.csv", "keyframes", "thesis.tex"}
    assert (tmp_path / "keyframes" / "notes.txt").is_file()


@pytest.mark.parametrize("where", ["at", "under"])
def test_out_at_or_under_a_file_is_one_line(where: str, tmp_path: Path, capsys) -> None:
    file = tmp_path / "file.txt"
    file.write_text("x")
    out = file if where == "at" else file / "run"
    assert main(["run", "1", "--out", str(out), "--quiet", "--overwrite"]) == 2
    err = _one_error_line(capsys)
    expected = "is not a folder" if where == "at" else "', a file"
    assert err.startswith("cellsight: error: --out: '") and "file.txt" in err  # a long path
    assert f"{expected}; expected a folder" in err  # is shortened in the middle
    assert file.read_text() == "x"


def test_argument_checks_come_before_the_folder_check(tmp_path: Path, capsys) -> None:
    (tmp_path / "frames.csv").write_text("older run")
    assert main(["run", "1", "--out", str(tmp_path), "--seed", "-1"]) == 2
    assert "--seed: expected a whole number >= 0, got -1" in _one_error_line(capsys)


@pytest.mark.parametrize(("content", "message"), [
    (b'{"seed": "\xff"}', "not UTF-8 text"),
    (b'{"seed": 1', "not valid JSON"),
    (b"[1, 2]", "expected a JSON object of metrics, got list [1, 2]"),
    (b"3.5", "expected a JSON object of metrics, got float 3.5"),
    (b'{"phases": [1]}', "field 'phases': expected an object, got [1]"),
    (b'{"phases": {"grasp": 2}}', "field 'phases.grasp': expected an object, got 2"),
    (b'{"timing_ms": "fast"}', "field 'timing_ms': expected an object"),
    (b"[" * 100_000, "not"),
    (b'{"seed": ' + b"9" * 5000 + b"}", "not usable JSON"),
])
def test_compare_names_a_bad_metrics_file(content: bytes, message: str, tmp_path: Path,
                                          capsys) -> None:
    good, bad = tmp_path / "good", tmp_path / "bad"
    good.mkdir()
    bad.mkdir()
    (good / "metrics.json").write_text('{"seed": 1}')
    (bad / "metrics.json").write_bytes(content)
    assert main(["compare", str(good), str(bad)]) == 2
    err = _one_error_line(capsys)
    assert f"{bad / 'metrics.json'}: " in err and message in err


def test_compare_names_a_missing_folder_or_file(tmp_path: Path, capsys) -> None:
    assert main(["compare", str(tmp_path / "nowhere"), str(tmp_path)]) == 2
    assert "no metrics.json here" in _one_error_line(capsys)
    (tmp_path / "metrics.json").mkdir()
    assert main(["compare", str(tmp_path), str(tmp_path)]) == 2
    assert "not a regular file (a folder" in _one_error_line(capsys)


def test_compare_shows_brackets_as_text(tmp_path: Path, capsys, monkeypatch) -> None:
    """Values and folder names are not read as rich markup ("[/red]" would raise)."""
    monkeypatch.chdir(tmp_path)
    Path("[red]").mkdir()
    Path("[red]/metrics.json").write_text('{"sensor": "[/red]", "seed": 3}')
    assert main(["compare", "[red]", "[red]"]) == 0
    out = capsys.readouterr().out
    assert "[/red]" in out and "[red]" in out.replace("[/red]", "")


def test_jaw_openings_reach_the_prediction(capsys) -> None:
    """``--openings`` in ``cellsight visibility``: the part held at R7AX's HOME, its jaws open
    and closed; each answer against the segment oracle on the cell at those openings, and the
    two differ (the jaws hide other features)."""
    cell = load_cell()
    robot, part = cell.robot("R7AX"), cell.workpiece("part")
    T_part = robot.tcp_pose(robot.home) @ np.linalg.inv(default_grasp_pose(part.solid,
                                                                          robot.tool))
    pose = json.dumps({"part": T_part.tolist()})
    answers = {}
    for opening in (0.0, robot.tool.max_opening):
        assert main(["visibility", "--part-pose", pose, "--openings",
                     json.dumps({"R7AX": opening}), "--json"]) == 0
        views = json.loads(capsys.readouterr().out)["part"]
        snapshot = cell.snapshot({}, {"part": T_part}, {"R7AX": opening})
        polygons, _, features = cell_scene(cell, snapshot)
        for c, cam in enumerate(cell.cameras):
            seen = cam.sees(features)
            oracle = segment_oracle(polygons, features[seen], cam.center, 2e-3, prune=True)
            got = np.array([f["visible"] for f in views[c]["features"]])[seen]
            sure = ~oracle.ambiguous
            np.testing.assert_array_equal(got[sure], oracle.visible[sure])
        answers[opening] = [[f["reason"] for f in v["features"]] for v in views]
    assert answers[0.0] != answers[robot.tool.max_opening]
