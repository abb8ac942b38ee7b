"""What a camera gives the tracker: a whole image, or an image read on demand.

The paper's system grabs only the image windows of the selected features. A camera that can do
the same gives the tracker an :class:`OnDemandImage` instead of an array: the tracker asks it
for the region of a camera's windows once they are planned (:func:`grabbed` with the boxes;
with every tracked part's windows at once, each part's a group), and for the whole image only
where it needs one (the whole-image search and the camera check).
Anything else (an image array, the ideal sensor's view, None for a camera that gave nothing)
is passed on as it is. The time a grab takes is the tracker's ``grab`` stage
(:mod:`.timing`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class OnDemandImage(Protocol):
    """One camera's exposure, read when asked: pixels as in the image (u = column, v = row),
    boxes half-open ``(u0, v0, u1, v1)``."""

    def grab(self, boxes: Sequence[Sequence[int]],
             groups: Sequence[int] | None = None) -> np.ndarray:
        """(H, W) uint8: the exposure's pixels in at least the region that holds every box
        (with ``groups``, per box the group it belongs to: in at least each group's region);
        what lies outside is unspecified (read as 0)."""
        ...

    def whole(self) -> np.ndarray:
        """(H, W) uint8: the whole image."""
        ...


def grabbed(observed: Any, boxes: Sequence[Sequence[int]] | None = None, *,
            groups: Sequence[np.ndarray] | None = None) -> Any:
    """What a camera took, read for the windows ``boxes``, or for ``groups`` of windows
    (each an (n, 4) array: every tracked part's windows in one grab), or (neither) the whole
    image, when it is an :class:`OnDemandImage`; anything else as it is."""
    if observed is None or isinstance(observed, np.ndarray):  # before the protocol's slow check
        return observed
    if not isinstance(observed, OnDemandImage):
        return observed
    if groups is not None and len(groups) > 1:
        labels = np.repeat(np.arange(len(groups)), [len(g) for g in groups])
        return observed.grab(np.concatenate(groups).tolist(), labels.tolist())
    if groups is not None:
        boxes = groups[0]
    return observed.whole() if boxes is None else observed.grab(boxes)
