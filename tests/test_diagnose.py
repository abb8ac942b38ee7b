"""``cellsight diagnose`` (cellsight.runfolder.wrong_corners): a rendered run's wrong corners
grouped into spans, counted against the run's own metrics and against ``frames.csv`` read with
the csv module."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import pytest

from cellsight.cli import main
from cellsight.runfolder.wrong_corners import wrong_corner_spans


@pytest.fixture(scope="module")
def wrong_run(tmp_path_factory) -> Path:
    """One second of experiment 3 in the `harsh` world, seed 1, which measures wrong corners
    (JPEG, noise: 32, 26 of them accepted; seed 0 measured one until the filter stopped
    learning a velocity from the cameras' skew, and none since); a second of `lab` measured
    three, in the acquisition's wide first look, until the log came to show the narrow
    windows that verify a fix instead."""
    out = tmp_path_factory.mktemp("diagnose") / "run"
    assert main(["run", "3", "--realism", "harsh", "--seed", "1", "--duration", "1", "--out",
                 str(out), "--quiet"]) == 0
    return out


def test_spans_count_every_wrong_corner_and_what_the_gate_did(wrong_run):
    metrics = json.loads((wrong_run / "metrics.json").read_text())
    spans = wrong_corner_spans(wrong_run)
    assert metrics["wrong_measurements"] > 0
    assert sum(s.frames for s in spans) == metrics["wrong_measurements"]
    assert sum(s.accepted for s in spans) == metrics["wrong_accepted"]
    # the same wrong corners, counted straight from the log
    with (wrong_run / "frames.csv").open() as f:
        rows = list(csv.DictReader(f))
    for c in (1, 2):
        wrong = sum(r[f"wrong_c{c}"].count("1") for r in rows)
        accepted = sum(w == "1" and j == "0" and r["status"] not in ("waiting", "lost")
                       for r in rows
                       for w, j in zip(r[f"wrong_c{c}"], r[f"rej_c{c}"], strict=False))
        mine = [s for s in spans if s.camera == f"cam{c}"]
        assert sum(s.frames for s in mine) == wrong
        assert sum(s.accepted for s in mine) == accepted
        assert sum(s.accepted + s.rejected + s.unused for s in mine) == wrong
    assert [s.accepted for s in spans] == sorted((s.accepted for s in spans), reverse=True)
    assert all(s.truth and s.predicted and s.phase for s in spans)


def test_the_command_names_cameras_and_features(wrong_run, capsys):
    assert main(["diagnose", str(wrong_run), "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert listed and {s["camera"] for s in listed} <= {"cam1", "cam2"}
    assert all(s["feature"].startswith("f") and s["feature"] != "f0" for s in listed)
    assert main(["diagnose", str(wrong_run)]) == 0
    assert "accepted by the gate" in capsys.readouterr().out
    assert main(["diagnose", str(wrong_run / "nothing")]) == 2


def test_the_report_shows_the_worst_accepted_wrong_corners(wrong_run):
    accepted = [s for s in wrong_corner_spans(wrong_run) if s.accepted]
    report = (wrong_run / "report.html").read_text()
    assert "<h2>Wrong corners</h2>" in report
    for i in range(1, min(len(accepted), 4) + 1):
        picture = cv2.imread(str(wrong_run / f"fig_wrong_corner_{i}.png"))
        assert picture is not None and picture.shape == (192, 192, 3)
        assert f'src="fig_wrong_corner_{i}.png"' in report
        # the green cross at the crop's true projection
        assert (picture[..., 1] > 150).sum() > 20 and (picture[..., 0] < 50).sum() > 20


def test_top_lists_the_spans_with_the_most_accepted_first(wrong_run, capsys):
    spans = wrong_corner_spans(wrong_run)
    assert len(spans) > 2
    assert main(["diagnose", str(wrong_run), "--top", "2", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [s["accepted"] for s in listed] == [s.accepted for s in spans[:2]]
    assert main(["diagnose", str(wrong_run), "--top", "2"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert f"in {len(spans)} spans; the first 2:" in out
    assert main(["diagnose", str(wrong_run), "--top", "0"]) == 2
    assert "--top: expected a whole number >= 1, got 0" in capsys.readouterr().err
