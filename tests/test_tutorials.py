"""The documentation's tutorials (``examples/plot_*.py``, run by mkdocs-gallery at build time):
each runs as a script, in a temporary working folder with matplotlib's Agg backend, prints
something and draws at least one figure; and what each one claims is checked here against a
computation of the test's own, which the script cannot fake (another occlusion back-end,
a segment sampling of the boxes' solids, the tracker's record against the world's truth,
OpenCV's projection of the drawn cameras)."""

from __future__ import annotations

import ast
import contextlib
import io
import os
import re
import runpy
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import cv2  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from cellsight.geometry.transforms import transform_points  # noqa: E402
from cellsight.occlusion.backends import visibility_predictor
from cellsight.realism import draw_world  # noqa: E402

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
TUTORIALS = sorted(p.name for p in EXAMPLES.glob("plot_*.py"))
FINAL_POSITION_BOUND_MM = 1.0  # measured: 0.31 mm at the last frame, 0.43 mm at most
RUN_POSITION_BOUND_MM = 2.0


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Each tutorial run once (on first use): name -> (globals, stdout, figures drawn)."""
    done: dict[str, tuple[dict, str, int]] = {}

    def run(name: str) -> tuple[dict, str, int]:
        if name not in done:
            folder = tmp_path_factory.mktemp(name[:-3])
            out = io.StringIO()
            plt.close("all")
            here = os.getcwd()
            os.chdir(folder)  # contextlib.chdir is Python >= 3.11
            try:
                with contextlib.redirect_stdout(out):
                    scope = runpy.run_path(str(EXAMPLES / name), run_name="__main__")
            finally:
                os.chdir(here)
            figures = len(plt.get_fignums())
            plt.close("all")
            done[name] = (scope, out.getvalue(), figures)
        return done[name]

    return run


def test_there_are_the_four_tutorials_and_a_gallery_header() -> None:
    assert TUTORIALS == ["plot_1_visibility.py", "plot_2_visible_mask.py", "plot_3_tracking.py",
                         "plot_4_realism.py"]
    assert (EXAMPLES / "README.md").read_text().startswith("# Tutorials\n")
    for name in TUTORIALS:
        doc = ast.get_docstring(ast.parse((EXAMPLES / name).read_text()))
        assert doc is not None and doc.startswith("# "), name  # the gallery page's title


@pytest.mark.parametrize("name", TUTORIALS)
def test_a_tutorial_runs_prints_and_draws(runs, name) -> None:
    _, out, figures = runs(name)
    assert out.strip(), f"{name} printed nothing"
    assert figures >= 1, f"{name} drew no figure"


def _printed_views(out: str) -> list[dict[str, tuple[int, dict]]]:
    """The visibility tutorial's per-camera lines, one dict per state: camera -> (visible
    count, hidden feature -> reason)."""
    states: list[dict] = []
    for match in re.finditer(r"^(cam\d): (\d+) of \d+ visible; hidden: (\{.*?\});", out, re.M):
        cam, count, hidden = match.group(1), int(match.group(2)), ast.literal_eval(match.group(3))
        if not states or cam in states[-1]:
            states.append({})
        states[-1][cam] = (count, hidden)
    return states


def test_visibility_matches_the_other_back_end_and_the_ray_casts(runs) -> None:
    scope, out, _ = runs("plot_1_visibility.py")
    cell, part, T = scope["cell"], scope["part"], scope["T_base_part"]
    grasper = scope["grasper"]
    # The IK solution puts the TCP at the grasp.
    assert np.allclose(grasper.tcp_pose(scope["q_grasp"]), scope["T_base_tcp"], atol=1e-5)
    other = visibility_predictor(cell, structure="frame-bsp")  # the script uses object-bvh
    printed = _printed_views(out)
    assert len(printed) == 2
    for joints, lines in zip((scope["joints"], scope["joints_cross"]), printed, strict=True):
        for view in other.predict(joints, {part.name: T})[part.name]:
            hidden = {part.feature_names[j]: r for j, r in enumerate(view.reason) if r}
            assert lines[view.camera] == (view.count, hidden)
    reasons = [set(r for _, h in state.values() for r in h.values()) for state in printed]
    assert {"self", "R7AX.gripper"} <= reasons[0]
    assert any(r.startswith("R6AX.link") for r in reasons[1])
    checks = re.findall(r"matches the ray casts for (\d+) of (\d+)", out)
    assert len(checks) == 2 and all(a == b for a, b in checks)


def _inside_any(boxes, points: np.ndarray, margin: float) -> np.ndarray:
    """Points strictly inside a box's solid (at least ``margin`` inside every face's plane)."""
    inside = np.zeros(len(points), dtype=bool)
    for b in boxes:
        here = np.ones(len(points), dtype=bool)
        for k, normal in enumerate(b.normals):
            here &= (points - b.face_points(k)[0]) @ normal < -margin
        inside |= here
    return inside


def test_visible_mask_agrees_with_a_sampling_of_the_solids(runs) -> None:
    scope, out, _ = runs("plot_2_visible_mask.py")
    assert re.search(r"disagreements with visible_mask: 0$", out, re.M)
    assert re.search(r"orbit of \d+ viewpoints: disagreements with the brute force: 0$", out,
                     re.M)
    assert "same flags as visible_mask: True" in out and "same answers: True" in out
    # Independently: a floor point is hidden iff its sight line passes through a box's solid;
    # sample each segment densely (a segment grazing a box within the step may differ).
    points, viewpoint, visible = scope["points"], scope["viewpoint"], scope["visible"]
    s = np.linspace(0.0, 1.0, 4001)[1:-1]
    hidden = np.array([_inside_any(scope["boxes"], viewpoint + s[:, None] * (p - viewpoint),
                                   1e-9).any() for p in points])
    assert np.sum(hidden != ~visible) <= 2  # 0 when measured
    assert 0 < hidden.sum() < len(points)
    for k, name in enumerate(b.name for b in scope["boxes"]):
        assert int(re.search(rf"hidden by {name}: (\d+) points", out).group(1)) == np.sum(
            scope["hider"] == k) > 0


def test_tracking_stays_within_a_millimetre_of_the_truth(runs) -> None:
    scope, out, _ = runs("plot_3_tracking.py")
    final = re.search(r"^final \(([\d.]+) s\): (\S+); position error ([\d.]+) mm", out, re.M)
    assert final is not None and final.group(2) == "tracking"
    # The last record's estimate against the world's truth at that frame, recomputed here.
    error_mm = 1e3 * np.linalg.norm(scope["rec"].T_base_part[:3, 3] - scope["truth"][:3, 3])
    assert float(final.group(3)) == pytest.approx(error_mm, abs=1e-3)
    assert error_mm < FINAL_POSITION_BOUND_MM
    log = scope["log"]
    assert len(log) == round(scope["duration"] * scope["VISION_HZ"])
    assert log[0]["status"] == "acquired"
    assert all(r["status"].split(":")[0] in ("tracking", "degraded") for r in log[1:])
    assert max(r["position_mm"] for r in log) < RUN_POSITION_BOUND_MM
    # The forearm hides features of the first camera during the run.
    assert min(r["visible"][0] for r in log) < max(r["visible"][0] for r in log)
    assert any(r.startswith("R6AX.") for r in scope["rec"].reasons[0])


def _opencv_shift(nominal, built, points: np.ndarray) -> float:
    """Mean pixel distance between the two cameras' projections, by OpenCV."""
    def project(cam):
        T = cam.T_cam_base
        uv, _ = cv2.projectPoints(points, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], cam.K,
                                  cam.dist5)
        return uv.reshape(-1, 2)
    return float(np.linalg.norm(project(built) - project(nominal), axis=1).mean())


def test_realism_shifts_match_opencv_projections_of_the_drawn_cameras(runs) -> None:
    scope, out, _ = runs("plot_4_realism.py")
    cell, part = scope["cell"], scope["part"]
    assert "lab/cameras alone vs whole lab: identical -> True" in out
    means = {}
    for profile in ("lab", "harsh"):
        points = transform_points(part.T_base_part, part.feature_points)
        shifts = [_opencv_shift(n, b, points) for seed in range(20)
                  for n, b in zip(cell.cameras, draw_world(profile, cell, seed).cell.cameras,
                                  strict=True)]
        means[profile] = np.mean(shifts)
        printed = re.search(rf"^{profile}\s+at start: mean shift ([\d.]+) px", out, re.M)
        assert float(printed.group(1)) == pytest.approx(means[profile], abs=0.01)
    assert 2.0 < means["harsh"] / means["lab"] < 4.0
    assert means["lab"] > 0.1
