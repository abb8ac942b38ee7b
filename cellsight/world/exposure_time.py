"""What a camera integrates over its exposure: motion blur and interlaced fields.

A camera with a shutter open for ``exposure_s`` sees a moving part and arm smeared over their
path: the image is the mean of ``BLUR_SAMPLES`` renders at the midpoints of equal slices of
``[t - exposure_s, t]``. An interlaced camera (the paper's CCIR cameras) exposes its two fields
``FIELD_S`` apart (50 fields a second): the even rows (0, 2, ...) are the earlier field, at
``t - FIELD_S``, the odd rows the frame's own, each field blurred over its own exposure.

:class:`ExposureHistory` keeps the kinematic state (joint positions and mocap poses, all that
moves in the rendered scene) of the last control steps, and gives each field's states as
MuJoCo data to render (:meth:`ExposureHistory.fields`); a past instant takes the state of the
last control step at or before it (2 ms resolution). Combining the renders is
:func:`combine`: the same for a whole image and for a region of it, row parity counted in the
whole image.
"""

from __future__ import annotations

import copy
import math
from collections import deque

import mujoco
import numpy as np

BLUR_SAMPLES = 4  # renders averaged over an exposure
FIELD_S = 0.02  # s between an interlaced camera's two fields (CCIR: 50 fields/s)


class ExposureHistory:
    """The scene's kinematic state over the last control steps (module docstring), for a
    camera exposed ``exposure_s`` seconds, its two fields ``FIELD_S`` apart when
    ``interlaced``; ``dt`` (s) is the control period."""

    def __init__(self, scene, exposure_s: float, interlaced: bool, dt: float) -> None:
        self.scene, self.exposure_s, self.interlaced = scene, float(exposure_s), interlaced
        reach = self.exposure_s + (FIELD_S if interlaced else 0.0)
        self._states: deque = deque(maxlen=int(math.ceil(reach / dt)) + 2)

    def record(self, t: float) -> None:
        """Keep the state of the control step that ends at ``t`` (s)."""
        d = self.scene.data
        self._states.append((t, d.qpos.copy(), d.mocap_pos.copy(), d.mocap_quat.copy()))

    def fields(self, t: float, now) -> list[list]:
        """Per field (one, or two when interlaced: the earlier first), the MuJoCo data of each
        instant its exposure samples; ``now`` is the data at ``t`` (s), used as it is for the
        instant ``t``."""
        starts = [t - FIELD_S, t] if self.interlaced else [t]
        if self.exposure_s <= 0:
            return [[self._at(s, t, now)] for s in starts]
        slice_s = self.exposure_s / BLUR_SAMPLES
        return [[self._at(end - self.exposure_s + (k + 0.5) * slice_s, t, now)
                 for k in range(BLUR_SAMPLES)] for end in starts]

    def _at(self, when: float, t: float, now):
        """MuJoCo data of the scene at ``when`` (s): ``now`` at ``t``, else the last recorded
        step at or before ``when`` (the oldest kept, before those)."""
        if when >= t - 1e-12:
            return now
        kept = [s for s in self._states if s[0] <= when + 1e-12] or list(self._states)[:1]
        if not kept:
            return now
        _, qpos, mocap_pos, mocap_quat = kept[-1]
        data = copy.copy(now)
        data.qpos[:], data.mocap_pos[:], data.mocap_quat[:] = qpos, mocap_pos, mocap_quat
        mujoco.mj_kinematics(self.scene.model, data)
        return data


def combine(fields: list[list[np.ndarray]], v0: int) -> np.ndarray:
    """One image (uint8) from each field's renders of the same pixels (uint8, all one shape):
    each field's mean, then, with two fields, the rows of the whole image's even rows from the
    first and odd rows from the second (``v0``: the whole image's row of the first row)."""
    means = [f[0] if len(f) == 1 else np.rint(np.mean(np.stack(f), axis=0,
                                                      dtype=np.float32)).astype(np.uint8)
             for f in fields]
    if len(means) == 1:
        return means[0]
    out = means[1].copy()
    first = v0 % 2  # the local row of the first even whole-image row
    out[first::2] = means[0][first::2]
    return out
