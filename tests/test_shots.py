"""Rendering only what the tracker reads (cellsight.world.render regions, cellsight.world.shots):
a region's pixels are the whole render's (judged against the whole render itself), the image
effects give a region what they give the whole image, and a run that renders only the windows
measures what a run rendering whole frames measures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight import load_cell
from cellsight.camera import Camera
from cellsight.experiments import RunConfig, run_experiment
from cellsight.model import Cell
from cellsight.tracking.grabbing import OnDemandImage, grabbed
from cellsight.world import World
from cellsight.world.images import ImageEffects, Imager
from cellsight.world.shots import RENDER_PX, Shot, merged_regions


def _distorted(cell: Cell) -> Cell:
    dist = [-0.3, 0.12, 0.002, -0.0015, 0.0]
    cameras = [Camera(c.K, c.width, c.height, c.T_base_cam, dist, c.name) for c in cell.cameras]
    return Cell(cell.name, cell.robots, cell.workpieces, cell.static, cameras)


def _boxes(rng: np.random.Generator, width: int, height: int, n: int) -> list[tuple]:
    """Random boxes inside the image, from a few pixels to more than the largest tile."""
    out = []
    for _ in range(n):
        u0, v0 = int(rng.integers(0, width - 4)), int(rng.integers(0, height - 4))
        out.append((u0, v0, int(rng.integers(u0 + 1, min(width, u0 + 450) + 1)),
                    int(rng.integers(v0 + 1, min(height, v0 + 450) + 1))))
    return out


@pytest.mark.parametrize("distorted", [False, True], ids=["pinhole", "distorted"])
def test_a_region_renders_the_whole_images_pixels(distorted: bool):
    cell = load_cell()
    world = World(_distorted(cell) if distorted else cell)
    for _ in range(400):  # 0.8 s: the crossing robot on its way
        world.step({}, {})
    whole = world.render()
    renderer = world._renderer
    width, height = renderer.size(0)
    rng = np.random.default_rng(7)
    differing = total = 0
    for k, box in enumerate(_boxes(rng, width, height, 60)):
        c = k % len(whole)
        u0, v0, u1, v1 = box
        region = renderer.render_region(world.scene.data, c, box).astype(int)
        ref = whole[c].astype(int)
        diff = region - ref[v0:v1, u0:u1]
        differing, total = differing + np.count_nonzero(diff), total + diff.size
        # where a pixel differs, it is an anti-aliased edge sample: by no more than the
        # contrast around it in the whole render
        for v, u in zip(*np.nonzero(diff), strict=True):
            around = ref[max(v + v0 - 1, 0):v + v0 + 2, max(u + u0 - 1, 0):u + u0 + 2]
            assert abs(diff[v, u]) <= around.max() - around.min()
    assert total > 10 ** 6 and differing <= 1e-4 * total
    world.close()


_RENDER_SCRIPT = """
import os, sys, numpy as np
from cellsight import load_cell
from cellsight.world import World
world = World(load_cell())
for _ in range(400):
    world.step({}, {})
whole = world.render()
boxes = [(0, 0, 768, 576), (100, 120, 260, 250), (300, 40, 330, 70)]
np.savez(sys.argv[1], *[world._renderer.render_region(world.scene.data, c, b)
                        for c in range(len(whole)) for b in boxes], *whole,
         threads=np.array(os.environ["LP_NUM_THREADS"]))
"""


@pytest.mark.parametrize("threads", ["2", "1"])
def test_the_rasteriser_s_threads_do_not_change_a_pixel(tmp_path: Path, threads: str):
    """``cellsight.world`` renders in the calling thread (``LP_NUM_THREADS=0``, set unless the
    user set it: :mod:`cellsight.world.gl`): the same regions and whole images as the
    software rasteriser rendering in threads, judged pixel for pixel, each in its own
    process."""
    import os
    import subprocess
    import sys

    images, used = {}, {}
    for name, env in (("default", {}), ("threads", {"LP_NUM_THREADS": threads})):
        environ = {k: v for k, v in os.environ.items() if k != "LP_NUM_THREADS"}
        out = tmp_path / f"{name}.npz"
        subprocess.run([sys.executable, "-c", _RENDER_SCRIPT, str(out)], check=True,
                       env={**environ, **env})
        with np.load(out) as saved:
            used[name] = str(saved["threads"])
            images[name] = [saved[f"arr_{k}"] for k in range(len(saved.files) - 1)]
    assert used == {"default": "0", "threads": threads}
    assert len(images["default"]) == len(images["threads"]) > 3
    for a, b in zip(images["default"], images["threads"], strict=True):
        np.testing.assert_array_equal(a, b)


class _Picture:
    """A renderer of one fixed picture (for the image effects' region arithmetic alone; the
    renderer itself is judged above)."""

    def __init__(self, picture: np.ndarray) -> None:
        self.picture = picture

    def size(self, camera: int) -> tuple[int, int]:
        return self.picture.shape[1], self.picture.shape[0]

    def render(self, data, cameras):
        return [self.picture.copy()]

    def render_region(self, data, camera, box):
        u0, v0, u1, v1 = box
        return self.picture[v0:v1, u0:u1].copy()


def test_image_effects_give_a_region_the_whole_images_pixels():
    rng = np.random.default_rng(3)
    picture = (np.add.outer(np.arange(240) * 0.7, np.arange(320) * 0.4) % 200
               + rng.integers(0, 40, (240, 320))).astype(np.uint8)
    effects = ImageEffects(read_noise_dn=2.0, shot_dn_per_e=0.05, gain_drift=0.1,
                           defocus_px=1.2, vignetting=0.2, jpeg_quality=60)
    imager = Imager(effects, 5)
    shot = Shot(_Picture(picture), imager, [[None]], 0, 1.3, imager.exposure())
    for box in _boxes(rng, 320, 240, 25):
        u0, v0, u1, v1 = box
        read = shot.grab([box])
        assert np.array_equal(read[v0:v1, u0:u1], Shot(
            _Picture(picture), imager, [[None]], 0, 1.3, shot.offset).whole()[v0:v1, u0:u1])
    # a second exposure has noise of its own; the effects did act
    other = Shot(_Picture(picture), imager, [[None]], 0, 1.3, imager.exposure()).whole()
    whole = shot.whole()
    assert np.abs(other.astype(int) - whole).mean() > 1.0
    assert np.abs(whole.astype(int) - picture).mean() > 2.0


_BOX = st.tuples(st.integers(0, 700), st.integers(0, 500), st.integers(1, 300),
                 st.integers(1, 300)).map(lambda b: (b[0], b[1], b[0] + b[2], b[1] + b[3]))


def _cost(regions, render_px: float) -> float:
    return sum(render_px + (r[2] - r[0]) * (r[3] - r[1]) for r in regions)


def _union(a, b):
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


@settings(max_examples=200, deadline=None)
@given(st.lists(_BOX, max_size=7), st.sampled_from([0.0, 2_000.0, RENDER_PX, 200_000.0]))
def test_regions_are_merged_only_where_one_render_costs_less(regions, render_px):
    """``merged_regions`` against the cost computed apart (a render's ``render_px`` plus its
    pixels): every region lies inside one returned, the cost never rises, and no two returned
    would cost less as one."""
    out = merged_regions(regions, render_px)
    assert all(any(o[0] <= r[0] and o[1] <= r[1] and r[2] <= o[2] and r[3] <= o[3] for o in out)
               for r in regions)
    assert _cost(out, render_px) <= _cost(regions, render_px)
    for i, a in enumerate(out):
        for b in out[i + 1:]:
            assert _cost([_union(a, b)], render_px) >= _cost([a, b], render_px)


def test_every_part_s_windows_in_one_grab_are_the_whole_image_s_pixels():
    """A grab of several groups of windows (each part's windows, :meth:`Shot.grab` with
    ``groups``) gives, in every window, the whole render's pixels (to the anti-aliased edge
    samples of a shifted viewport, :mod:`cellsight.world.render`); with one group, exactly
    the grab of its boxes."""
    world = World(load_cell())
    for _ in range(400):
        world.step({}, {})
    whole = world.render()
    shot = world.render(on_demand=True)[0]
    rng = np.random.default_rng(3)
    width, height = world._renderer.size(0)
    boxes = _boxes(rng, width, height, 30)
    groups = [int(g) for g in rng.integers(0, 4, len(boxes))]
    together = shot.grab(boxes, groups)
    differing = total = 0
    for u0, v0, u1, v1 in boxes:
        diff = together[v0:v1, u0:u1].astype(int) - whole[0][v0:v1, u0:u1]
        differing, total = differing + np.count_nonzero(diff), total + diff.size
    assert total > 10 ** 5 and differing <= 1e-4 * total
    one = [b for b, g in zip(boxes, groups, strict=True) if g == 0]
    assert np.array_equal(world.render(on_demand=True)[0].grab(one, [0] * len(one)),
                          world.render(on_demand=True)[0].grab(one))
    world.close()


def test_a_shot_is_the_state_it_was_taken_in():
    world = World(load_cell())
    before = world.render()
    shots = world.render(on_demand=True)  # taken now, read later
    assert all(isinstance(s, OnDemandImage) for s in shots)
    robot = world.cell.robots[0].name
    q = world.measured_joints()[robot].copy()
    q[:3] += [0.4, -0.3, 0.3]
    for _ in range(500):  # 1 s: the arm moves
        world.step({robot: q}, {})
    assert all(np.array_equal(grabbed(s), b) for s, b in zip(shots, before, strict=True))
    assert any(not np.array_equal(a, b) for a, b in zip(world.render(), before, strict=True))
    assert grabbed(before[1]) is before[1]  # an array is passed on as it is
    world.close()


@pytest.mark.slow
def test_a_run_on_windows_measures_what_a_run_on_whole_frames_measures(tmp_path: Path):
    """The plain tracker: the kinematic one registers the cameras from whole images, which a
    run on windows renders only for the registration."""
    from cellsight.trackers import TrackerChoice

    runs = {}
    for full in (False, True):
        runs[full] = run_experiment(RunConfig(
            experiment=3, out=tmp_path / str(full), duration=1.5, full_frames=full,
            progress=False, video_every=0, tracker=TrackerChoice("plain")))
    windows, whole = runs[False], runs[True]
    assert windows["measurements"] == whole["measurements"] > 250
    assert windows["wrong_accepted"] == whole["wrong_accepted"]
    assert windows["position_rmse_mm"] == pytest.approx(whole["position_rmse_mm"], abs=0.01)
    assert windows["timing_ms"]["grab"] > 0.0 and whole["timing_ms"]["grab"] < 0.5
    assert windows["pixels_grabbed_fraction"] == whole["pixels_grabbed_fraction"] < 0.02
