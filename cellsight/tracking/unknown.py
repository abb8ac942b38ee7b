"""Unknown occluders learned online (beyond the paper): where in each camera's image something
the cell file does not know hides the workpieces.

The visibility source predicts only what the cell file models. A box on the table or an
operator's forearm hides features it calls visible: their windows then hold nothing, or the
intruder's own corners. Per camera, an :class:`UnknownOccluders` map keeps evidence on a grid of
``cell_px`` square cells over the image:

- a selected, predicted-visible feature that its camera did not find, or whose corner the
  gate rejected in a frame where that camera had none of the part's corners accepted, adds
  one to the cells within ``radius_px`` of its predicted pixel (at most
  ``cap``); a failure counts only while the estimate is confirmed: within ``trust_s`` seconds
  of a frame whose update accepted at least ``min_accepted`` measurements of the part. The
  estimate then explains the rest of the views, so what it misses here is hidden, not
  mispredicted; a lost or long-drifting estimate teaches nothing, while a track coasting
  through a blind spell still learns;
- evidence halves every ``half_life_s`` seconds;
- a cell whose evidence reaches ``threshold`` is *unknown-occluded* until it has decayed below
  ``release``: the region is tried again about ``half_life_s * log2(cap / release)`` seconds
  after its last failure, and one failure there sets it again (with the cap, an intruder
  that stays costs one failed window per region and period).

A corner the gate rejects beside accepted ones of the same camera teaches nothing: such
rejections all over the image are noise beyond the model (the health monitor's NIS says so),
not an object in the way, while a camera that an intruder blinds offers only its corners. A
feature found
and accepted clears nothing: an intruder's own corner, accepted in its window, is not
evidence that the way is free. A predicted-visible feature within ``radius_px``
of an occluded cell is labelled ``unknown`` (:data:`UNKNOWN_LABEL`) and neither selected nor
used for acquisition. The map is shared by every part (an intruder hides them all). Pixels
``(u, v)`` as in the image, cells indexed ``[row, column]``, times in s.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from cellsight.camera import Camera

UNKNOWN_LABEL = "unknown"
"""The label of a predicted-visible feature that an unknown occluder covers (``occ_pred``)."""


class Grid(NamedTuple):
    """A boolean grid of square cells over an image, such as an unknown-occluder map:
    ``cells`` (rows, columns); cell ``[i, j]`` covers ``u + 0.5`` in ``[j, j + 1) * pitch_px``
    and ``v + 0.5`` in ``[i, i + 1) * pitch_px`` (pixel centres at integers, as the camera's)."""

    cells: np.ndarray
    pitch_px: int


@dataclass(frozen=True)
class UnknownOccluderRule:
    """The unknown-occluder maps' numbers (module docstring): ``cell_px`` (px) grid pitch,
    ``radius_px`` (px) reach of one feature's evidence and of a query, ``half_life_s`` (s),
    ``threshold``, ``release`` and ``cap`` (failures), ``min_accepted`` (accepted measurements
    of the part in one frame that confirm its estimate) and ``trust_s`` (s, how long such a
    frame lets failures count). ``enabled=False`` learns and masks nothing (the paper's
    tracker).

    Defaults: two failures in a row mask a region (one is a corner lost to noise or blur);
    a region that failed often is tried again 2 s after its last failure (52 frames at 26 Hz;
    the realistic world's forearm stays 1-4 s), one that failed twice after about 1 s. Two
    accepted measurements suffice to learn: while a robot also hides the part from another
    camera, the views left may hold no more.
    """

    cell_px: int = 16
    radius_px: float = 12.0
    half_life_s: float = 0.5
    threshold: float = 1.9
    release: float = 0.5
    cap: float = 8.0
    min_accepted: int = 2
    trust_s: float = 0.5
    enabled: bool = True

    def __post_init__(self) -> None:
        checks = {
            "cell_px": self.cell_px >= 1,
            "radius_px": self.radius_px >= 0 and np.isfinite(self.radius_px),
            "half_life_s": self.half_life_s > 0 and np.isfinite(self.half_life_s),
            "threshold": self.threshold > 0 and np.isfinite(self.threshold),
            "release": 0 < self.release <= self.threshold,
            "cap": self.cap >= self.threshold and np.isfinite(self.cap),
            "min_accepted": self.min_accepted >= 0,
            "trust_s": self.trust_s >= 0 and np.isfinite(self.trust_s),
        }
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"UnknownOccluderRule: {name} out of range, got "
                                 f"{getattr(self, name)}")

    def maps(self, cameras: Sequence[Camera]) -> UnknownOccluders:
        """Empty maps for ``cameras`` (the tracker's order)."""
        return UnknownOccluders(self, cameras)


class UnknownOccluders:
    """Per camera, the evidence grid of unknown occluders and its occluded cells (module
    docstring)."""

    def __init__(self, rule: UnknownOccluderRule, cameras: Sequence[Camera]) -> None:
        self.rule = rule
        pitch = rule.cell_px
        self.shapes = [(-(-cam.height // pitch), -(-cam.width // pitch)) for cam in cameras]
        self._evidence = [np.zeros(shape) for shape in self.shapes]
        self._occluded = [np.zeros(shape, dtype=bool) for shape in self.shapes]
        self._t = [-np.inf] * len(self.shapes)

    def decay(self, c: int, t: float) -> None:
        """Let camera ``c``'s evidence decay to time ``t`` (s); cells below ``release`` are
        free again."""
        dt = t - self._t[c]
        if dt > 0 and np.isfinite(dt):
            self._evidence[c] *= 0.5 ** (dt / self.rule.half_life_s)
            self._occluded[c] &= self._evidence[c] >= self.rule.release
        self._t[c] = max(self._t[c], t)

    def covered(self, c: int, pixels: np.ndarray, t: float) -> np.ndarray:
        """(n,) bool: which ``pixels`` (n, 2) px of camera ``c`` lie within ``radius_px`` of an
        unknown-occluded cell at time ``t`` (s); NaN pixels are not covered."""
        if not self.rule.enabled:
            return np.zeros(len(pixels), dtype=bool)
        self.decay(c, t)
        occluded = self._occluded[c]
        return np.array([bool(occluded[cells].any()) for cells in self._cells(c, pixels)],
                        dtype=bool)

    def learn(self, c: int, t: float, failed: np.ndarray) -> None:
        """Camera ``c`` at time ``t`` (s): features looked for at the predicted pixels
        ``failed`` (n, 2) px failed (module docstring; the caller checks that the estimate is
        confirmed: ``min_accepted``, ``trust_s``)."""
        if not self.rule.enabled:
            return
        self.decay(c, t)
        evidence = self._evidence[c]
        for cells in self._cells(c, failed):
            evidence[cells] = np.minimum(evidence[cells] + 1.0, self.rule.cap)
        self._occluded[c] |= evidence >= self.rule.threshold

    def mask(self, c: int, t: float) -> Grid:
        """Camera ``c``'s unknown-occluded cells at time ``t`` (s)."""
        self.decay(c, t)
        return Grid(self._occluded[c].copy(), self.rule.cell_px)

    def _cells(self, c: int, pixels: np.ndarray) -> list[tuple[slice, slice]]:
        """Per pixel of ``pixels`` (n, 2): the block of camera ``c``'s cells within
        ``radius_px`` of it (the cells its square of half-side ``radius_px`` touches); an empty
        block for a NaN or off-image pixel."""
        pitch, r = self.rule.cell_px, self.rule.radius_px
        rows, cols = self.shapes[c]
        out = []
        for u, v in np.asarray(pixels, dtype=float).reshape(-1, 2):
            if not (np.isfinite(u) and np.isfinite(v)):
                out.append((slice(0, 0), slice(0, 0)))
                continue
            c0, c1 = int(np.floor((u + 0.5 - r) / pitch)), int(np.floor((u + 0.5 + r) / pitch))
            r0, r1 = int(np.floor((v + 0.5 - r) / pitch)), int(np.floor((v + 0.5 + r) / pitch))
            out.append((slice(max(r0, 0), max(min(r1 + 1, rows), 0)),
                        slice(max(c0, 0), max(min(c1 + 1, cols), 0))))
        return out
