"""The frame-by-frame example of docs/guides/your-cameras.md, run as it is written: rendered
frames of the built-in cell saved as image files, read back by OpenCV's ``VideoCapture`` and
fed to the tracker with the joints measured at each frame; the estimate against the
simulator's truth."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from cellsight import load_cell
from cellsight.rates import VISION_HZ
from cellsight.world import World

PAGE = Path(__file__).resolve().parent.parent / "docs/guides/your-cameras.md"
FRAMES = 30


def _example() -> str:
    """The ``python`` block right after the page's marker naming this test."""
    text = PAGE.read_text()
    start = text.index("<!-- test: tests/test_feed_your_cameras.py -->")
    return re.search(r"```python\n(.*?)```", text[start:], flags=re.DOTALL).group(1)


def test_the_readme_example_tracks_frames_read_from_files(tmp_path, monkeypatch, capsys):
    cell = load_cell()
    world = World(cell)
    joints, truth = [], None
    for k in range(FRAMES):
        while world.time < k / VISION_HZ - 1e-9:
            world.step({}, {})
        for cam, image in zip(cell.cameras, world.render(), strict=True):
            assert cv2.imwrite(str(tmp_path / f"{cam.name}_{k:03d}.png"), image)
        joints.append(world.measured_joints())
        truth = world.true_part_poses()["part"]
    world.close()
    monkeypatch.chdir(tmp_path)
    source = iter(joints)
    code = _example().replace('load_cell("my_cell.yaml")', "load_cell()")
    scope = {"read_joints": lambda: next(source)}
    exec(compile(code, str(PAGE), "exec"), scope)
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == FRAMES and lines[-1].split()[2] == "tracking:"
    part = scope["part"]
    assert np.linalg.norm(part.T_base_part[:3, 3] - truth[:3, 3]) < 1e-3
    assert np.all(np.sqrt(part.covariance[:3, :3].diagonal()) < 2e-3)
