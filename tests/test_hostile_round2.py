"""Hostile input, second round (issue 23): the answers that were silently wrong. A part pose
that is not rigid, two sweep runs sharing one folder, and a replay that used a cell file
edited after the run."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from cellsight.cli import main
from cellsight.errors import CellsightError
from cellsight.experiments import RunConfig, run_experiment
from cellsight.model.loader import load_cell
from cellsight.occlusion.backends import visibility_predictor
from cellsight.runfolder import RunDataError, load_run

CELL = load_cell()
T_PART = CELL.workpiece("part").T_base_part


@pytest.mark.parametrize(("name", "pose"), [
    ("scaled x2", np.diag([2.0, 2.0, 2.0, 1.0]) @ T_PART),
    ("mirrored", np.diag([1.0, 1.0, -1.0, 1.0]) @ T_PART),
    ("last row 0 0 0 2", np.vstack([T_PART[:3], [0.0, 0.0, 0.0, 2.0]])),
    ("sheared", T_PART @ np.array([[1, 0.1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])),
])
def test_the_api_refuses_a_part_pose_that_is_not_rigid(name: str, pose: np.ndarray) -> None:
    predictor = visibility_predictor(CELL)
    with pytest.raises(CellsightError, match="workpiece part: pose must be a rigid transform"):
        predictor.predict(None, {"part": pose})
    with pytest.raises(CellsightError, match="rigid transform"):
        CELL.snapshot(None, {"part": pose})


def test_a_rigid_pose_within_rounding_is_taken() -> None:
    rounded = T_PART.round(9)
    assert visibility_predictor(CELL).predict(None, {"part": rounded})["part"][0].count > 0


@pytest.mark.parametrize("args", [
    ["--seeds", "0", "0"],
    ["--sensors", "ideal", "ideal", "--seeds", "3"],
])
def test_sweep_refuses_two_runs_in_one_folder(args: list[str], tmp_path: Path, capsys) -> None:
    out = tmp_path / "sweep"
    assert main(["sweep", "--out", str(out), "--experiments", "1", "--sensors", "ideal",
                 "--duration", "0.1", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "two runs would share the folder" in err
    assert not out.exists()


def test_sweep_refuses_two_cell_files_of_the_same_name(tmp_path: Path, capsys) -> None:
    for sub in ("a", "b"):
        (tmp_path / sub).mkdir()
        shutil.copy(CELL.source, tmp_path / sub / "cell.yaml")
    out = tmp_path / "sweep"
    assert main(["sweep", "--out", str(out), "--cells", str(tmp_path / "a" / "cell.yaml"),
                 str(tmp_path / "b" / "cell.yaml"), "--experiments", "1", "--sensors", "ideal",
                 "--seeds", "0", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "files of the same name" in err and str(tmp_path / "a" / "cell.yaml") in err
    assert not out.exists()


@pytest.fixture(scope="module")
def calibrated_run(tmp_path_factory) -> tuple[Path, Path]:
    """A short ideal run on a cell whose cameras come from calibration files, run from a
    cell file that is then removed: (run folder, calibration folder)."""
    root = tmp_path_factory.mktemp("kept")
    assert main(["cameras", "--write", str(root / "cal")]) == 0
    run = root / "run"
    run_experiment(RunConfig(1, run, cell=root / "cal" / "cell.yaml", sensor="ideal",
                             duration=0.3, progress=False, video_every=0))
    (root / "cal" / "cell.yaml").unlink()
    return run, root / "cal"


def test_a_run_replays_from_its_own_cell_without_the_original_file(calibrated_run) -> None:
    run, _ = calibrated_run
    data = load_run(run)
    assert data.cell.source == str(run / "run_cell.yaml")
    assert [c.name for c in data.cell.cameras] == [c.name for c in CELL.cameras]
    np.testing.assert_allclose(data.cell.cameras[0].K, CELL.cameras[0].K, atol=1e-9)
    assert data.n > 0


def test_a_run_whose_calibration_file_changed_is_refused(calibrated_run, tmp_path) -> None:
    run, cal = calibrated_run
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    intrinsics = sorted(cal.glob("*_intrinsics.yaml"))[0]
    before = intrinsics.read_text()
    intrinsics.write_text(before + "\n# re-calibrated\n")
    try:
        with pytest.raises(RunDataError, match=rf"{intrinsics.name}.*has changed since the run"):
            load_run(copy)
        assert load_run(copy, "dual-arm").n > 0  # --cell replays it with another cell
    finally:
        intrinsics.write_text(before)
    assert load_run(copy).n > 0


@pytest.mark.parametrize("edit", ["camera moved", "deleted"])
def test_a_run_whose_kept_cell_was_edited_is_refused(calibrated_run, tmp_path, edit) -> None:
    run, _ = calibrated_run
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    kept = copy / "run_cell.yaml"
    if edit == "deleted":
        kept.unlink()
    else:
        kept.write_text(kept.read_text() + "\n# moved by hand\n")
    now = "is gone" if edit == "deleted" else "has changed"
    with pytest.raises(RunDataError, match=f"run_cell.yaml: it {now} since the run"):
        load_run(copy)
    assert main(["export", str(copy), "--mcap", str(tmp_path / "x.mcap"), "--quiet"]) == 2
    assert not (tmp_path / "x.mcap").exists()


def test_an_older_run_is_refused_when_its_cell_file_changed(calibrated_run, tmp_path) -> None:
    """A run folder without ``run_cell.yaml`` (written before cells were kept) replays from the
    file its metrics.json names, only while that file is the one the run used."""
    run, _ = calibrated_run
    old = tmp_path / "old"
    shutil.copytree(run, old)
    (old / "run_cell.yaml").unlink()
    cell_file = tmp_path / "cell.yaml"
    shutil.copy(CELL.source, cell_file)
    metrics = json.loads((old / "metrics.json").read_text())
    metrics["cell"], metrics["cell_files"] = str(cell_file), {}
    metrics["cell_sha256"] = hashlib.sha256(cell_file.read_bytes()).hexdigest()
    (old / "metrics.json").write_text(json.dumps(metrics))
    assert load_run(old).cell.source == str(cell_file)
    cell_file.write_text(cell_file.read_text() + "\n# a camera moved by hand\n")
    with pytest.raises(RunDataError, match="has changed since the run"):
        load_run(old)


def _edited_cell(tmp_path: Path, old: str, new: str) -> Path:
    """The built-in cell file with ``old`` replaced by ``new`` (once), in ``tmp_path``."""
    text = Path(CELL.source).read_text()
    assert old in text
    path = tmp_path / "cell.yaml"
    path.write_text(text.replace(old, new, 1))
    return path


def test_the_loader_refuses_a_crossing_robot_that_grasps(tmp_path: Path) -> None:
    path = _edited_cell(tmp_path, "  crossing:\n    robot: R6AX", "  crossing:\n    robot: R7AX")
    with pytest.raises(CellsightError, match=r"experiments\.crossing\.robot.*R7AX.*grasping"):
        load_cell(path)


def test_the_loader_refuses_an_image_the_renderer_cannot_take(tmp_path: Path) -> None:
    path = _edited_cell(tmp_path, "width: 768", "width: 100000")
    with pytest.raises(CellsightError, match="image size must be 1 to 8192 px"):
        load_cell(path)


@pytest.mark.parametrize(("text", "message"), [
    ('{"R7AX": [true, 0, 0, 0, 0, 0, 0]}', "expected finite numbers, got [True"),
    ('{"R7AX": [0, 0, 0, 0, 0, 0, 0], "R7AX": [0, 0, 0, 0, 0, 0, 0]}', "'R7AX' given twice"),
])
def test_joints_on_the_command_line_refuse_booleans_and_repeated_robots(
        text: str, message: str, capsys) -> None:
    assert main(["visibility", "--joints", text]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(("joints", "message"), [
    ({"R7AX": ["a"] * 7}, "R7AX: expected 7 joint values"),
    ({"R7AX": [1j] + [0.0] * 6}, "R7AX: joint values must be real numbers"),
    ([0.1] * 7, "joints must map names to values"),
])
def test_the_api_names_the_robot_of_bad_joint_values(joints, message: str) -> None:
    with pytest.raises(CellsightError, match=message):
        visibility_predictor(CELL).predict(joints)


def test_export_refuses_a_link_to_the_runs_own_file(calibrated_run, tmp_path) -> None:
    from cellsight.export.rosbag import check_output

    run, _ = calibrated_run
    link = tmp_path / "lnk.mcap"
    link.symlink_to(run / "frames.csv")
    before = (run / "frames.csv").read_bytes()
    with pytest.raises(CellsightError, match="is the run's own frames.csv"):
        check_output(link, True, run)
    assert main(["export", str(run), "--mcap", str(link), "--overwrite"]) == 2
    assert (run / "frames.csv").read_bytes() == before


def test_compare_says_when_runs_are_not_like_for_like(tmp_path: Path, capsys) -> None:
    from cellsight.runfolder import write_metrics

    for name, t_end, cell in (("a", 12.5, "/x/dual_arm_cell.yaml"), ("b", 48.0, "/y/ur_cell.yaml"),
                              ("c", 12.5, "/x/dual_arm_cell.yaml")):
        (tmp_path / name).mkdir()
        write_metrics(tmp_path / name, {"experiment": 3, "t_end_s": t_end, "cell_sha256": name,
                                        "cell": cell})
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "b")]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "not like for like" in out and "cell dual_arm_cell.yaml vs ur_cell.yaml" in out
    assert "duration (s) 12.5 vs 48.0" in out
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "c")]) == 0
    assert "cell dual_arm_cell.yaml, changed between the runs" in " ".join(
        capsys.readouterr().out.split())
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "a")]) == 0
    assert "not like for like" not in capsys.readouterr().out


def test_show_keeps_the_users_files_without_overwrite(tmp_path: Path, capsys) -> None:
    out = tmp_path / "pictures"
    out.mkdir()
    (out / "cell_3d.png").write_text("the user's own picture")
    assert main(["show", "--out", str(out)]) == 2
    assert "already holds cell_3d.png; pass --overwrite" in capsys.readouterr().err
    assert (out / "cell_3d.png").read_text() == "the user's own picture"
    assert sorted(p.name for p in out.iterdir()) == ["cell_3d.png"]
    assert main(["show", "--out", str(out), "--overwrite"]) == 0
    assert (out / "cell_3d.png").read_bytes()[:4] == b"\x89PNG"
    assert {p.name for p in out.iterdir()} == {"cell_3d.png", "view_cam1.png", "view_cam2.png"}
    assert main(["show", "--out", str(out / "cell_3d.png" / "x")]) == 2
    assert "a file; expected a folder" in capsys.readouterr().err



@pytest.mark.parametrize(("old", "new", "message"), [
    ("points: [[0.55, 0.0], [0.85, 0.04]]", "points: [[0.55, 0.0], [0.55, 0.0]]",
     r"experiments\.conveyor\.points': .*points 0 and 1 coincide"),
    ("lens_mm: 16.0", "lens_mm: 1.0e-300",
     r"cameras\[0\]'.*fx = 1.2\d*e-298 px gives a 180 deg field of view"),
    ("lens_mm: 16.0", "lens_mm: 1.0e+9",
     r"cameras\[0\]'.*field of view over 768 px; expected 0.01 to 179 deg"),
])
def test_the_loader_refuses_a_still_conveyor_and_an_absurd_lens(
        old: str, new: str, message: str, tmp_path: Path, capsys) -> None:
    path = _edited_cell(tmp_path, old, new)
    with pytest.raises(CellsightError, match=message):
        load_cell(path)
    assert main(["visibility", "--cell", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err  # one line: no numpy warning leaks


def test_a_home_on_its_joint_limits_loads_and_runs(tmp_path: Path) -> None:
    """The loader and the run agree on the limits: HOME exactly on them (every joint of the
    grasping robot at a limit) loads and runs in a world with encoder offsets and noise; a
    millionth beyond is refused by the loader, before anything runs."""
    robot = CELL.robot("R7AX")
    on_limits = np.where(np.arange(robot.n_joints) % 2 == 0, robot.chain.qlim[:, 0],
                         robot.chain.qlim[:, 1])
    home = "home: [0.499, -0.051, 0.259, 0.65, 0.0, 0.664, -0.051]"
    path = _edited_cell(tmp_path, home, f"home: {on_limits.tolist()}")
    np.testing.assert_array_equal(load_cell(path).robot("R7AX").home, on_limits)
    metrics = run_experiment(RunConfig(experiment=1, sensor="ideal", duration=2.0, cell=path,
                                       realism="lab", out=tmp_path / "run", progress=False))
    assert "error" not in metrics and metrics["frames"] > 0
    beyond = on_limits.copy()
    beyond[1] += 1e-6
    path = _edited_cell(tmp_path, home, f"home: {beyond.tolist()}")
    with pytest.raises(CellsightError, match="joint 2 = .* outside its limits"):
        load_cell(path)
