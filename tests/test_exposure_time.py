"""Motion blur and interlaced fields (cellsight.world.exposure_time), judged against a second
world stepped alike with neither: each field is the mean of that world's sharp renders at the
instants its exposure samples, the even rows the earlier field, and a region reads what the
whole image shows."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cellsight import load_cell
from cellsight.world import World
from cellsight.world.exposure_time import BLUR_SAMPLES, FIELD_S
from cellsight.world.images import ImageEffects
from cellsight.world.imperfections import IDEAL

EXPOSURE_S = 0.008


def _slide(world: World, step: int, part: str, start: np.ndarray) -> None:
    """One control step with the part slid 0.5 m/s along x (so the images move)."""
    T = start.copy()
    T[0, 3] += 0.5 * step * world.dt_control
    world.place_part(part, T)
    world.step({}, {})


def test_blurred_interlaced_fields_are_the_means_of_the_sharp_renders_they_sample():
    cell = load_cell()
    part = cell.workpieces[0]
    effects = ImageEffects(exposure_s=EXPOSURE_S, interlaced=True)
    blurred, sharp = World(cell, errors=replace(IDEAL, images=effects)), World(cell)
    n = 120
    seen = {}
    for k in range(1, n + 1):
        for world in (blurred, sharp):
            _slide(world, k, part.name, part.T_base_part)
        if k >= n - 20:
            seen[k] = sharp.render([0])[0].astype(np.float32)
    dt = sharp.dt_control

    def field(end_step: int) -> np.ndarray:
        """The mean of the sharp renders at the steps the exposure ending there samples."""
        slice_s = EXPOSURE_S / BLUR_SAMPLES
        steps = [int(np.floor((end_step * dt - EXPOSURE_S + (i + 0.5) * slice_s) / dt + 1e-9))
                 for i in range(BLUR_SAMPLES)]
        return np.rint(np.mean([seen[s] for s in steps], axis=0))

    expected = field(n)
    expected[0::2] = field(n - round(FIELD_S / dt))[0::2]
    image = blurred.render([0])[0].astype(np.float32)
    assert image.shape == expected.shape
    assert np.abs(image - seen[n]).max() > 50  # the part moved: blur and fields show
    np.testing.assert_array_equal(image, expected)
    # a region read on demand is the whole image's pixels there (rendering regions differs
    # from whole renders at anti-aliased edge samples only; test_shots.py)
    shot = blurred.render([0], on_demand=True)[0]
    box = (200, 151, 420, 331)  # an odd first row: the fields' rows counted in the image
    u0, v0, u1, v1 = box
    region = shot.grab([box])[v0:v1, u0:u1].astype(int)
    differing = np.count_nonzero(region - shot.whole()[v0:v1, u0:u1])
    assert differing <= 1e-3 * region.size
    blurred.close()
    sharp.close()
