"""The camera check's sliding window of innovations (:mod:`cellsight.tracking.camera_check`):
its running count, mean and standard deviation against NumPy's over the rows the window
holds, gathered anew at every frame."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight.tracking.camera_check import _WindowMoments

SPAN_S = 0.5
HZ = 26.0


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(min_value=0, max_value=12), min_size=1, max_size=80),
       st.integers(min_value=0, max_value=2**31 - 1), st.floats(min_value=0.1, max_value=40.0))
def test_the_window_s_moments_are_numpy_s_over_its_rows(sizes, seed, scale):
    """Frames of 0-12 rows at 26 Hz, innovations of up to tens of pixels about an offset:
    the count exactly, the mean and the standard deviation to 1e-9 px of NumPy's over the
    frames less than ``SPAN_S`` old; cleared, nothing."""
    rng = np.random.default_rng(seed)
    window, kept = _WindowMoments(), []
    offset = rng.normal(scale=scale, size=2)
    for k, size in enumerate(sizes):
        t = k / HZ
        rows = offset + rng.normal(scale=scale, size=(size, 2))
        window.slide(t, rows, SPAN_S)
        kept = [(s, r) for s, r in kept + [(t, rows)] if s >= t - SPAN_S - 1e-9]
        gathered = np.concatenate([r for _, r in kept])
        assert window.n == len(gathered)
        if len(gathered) >= 1:
            np.testing.assert_allclose(window.mean(), gathered.mean(axis=0), rtol=0, atol=1e-9)
        if len(gathered) >= 2:
            np.testing.assert_allclose(window.std(), gathered.std(axis=0, ddof=1), rtol=0,
                                       atol=1e-9)
    window.clear()
    assert window.n == 0
