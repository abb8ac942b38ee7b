"""A camera's exposure, rendered when the tracker reads it: only its windows' region, or the
whole image where one is asked for.

:meth:`World.render(on_demand=True) <cellsight.world.World.render>` takes a :class:`Shot` per
camera: copies of the simulation's state over the exposure (one, or several for motion blur
and interlaced fields: :mod:`cellsight.world.exposure_time`), the camera, its time and its
noise offset. Reading it renders then (:meth:`GrayRenderer.render_region
<cellsight.world.render.GrayRenderer.render_region>`) and applies the camera's image effects
to that region (:class:`~cellsight.world.images.Imager`), so the pixels read are those of
the whole image, which :meth:`Shot.whole` renders, as a whole render of the same state would
show them (:mod:`cellsight.world.render` says to what precision). It is the
:class:`~cellsight.tracking.grabbing.OnDemandImage` of the tracker.

The tracker grabs every tracked part's windows of a camera at once, each part's a group. Each
group's region (the bounding box of its windows) is rendered, except that two regions are
rendered as one (their bounding box) where that costs less (:func:`merged_regions`): a render
costs about as much as ``RENDER_PX`` of its pixels (rendering regions of one size, 0.33 ms a
render and 0.017 us a pixel with the software rasteriser's threads, 0.20 ms and 0.024 us
without: 8,000-20,000 pixels). On the line (``line-cell``, lab, seed 3, its first 60 s,
each frame's windows grabbed both ways in turn), the grab takes 0.91x the time of grabbing
part by part with 20,000, 0.89x with 8,000.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cellsight.world.exposure_time import combine
from cellsight.world.images import Imager
from cellsight.world.render import GrayRenderer

RENDER_PX = 20_000  # a render costs about as much as this many of its pixels (module docstring)


def merged_regions(regions: Sequence[tuple[int, int, int, int]],
                   render_px: float = RENDER_PX) -> list[tuple[int, int, int, int]]:
    """Half-open ``(u0, v0, u1, v1)`` regions, two at a time replaced by their bounding box
    while that saves the most (a render costs ``render_px`` pixels; module docstring), until
    no pair's does: every region lies inside one of those returned."""
    out = [tuple(int(x) for x in r) for r in regions]
    while len(out) > 1:
        best, pair = 0.0, None
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                a, b = out[i], out[j]
                union = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
                saved = render_px + _area(a) + _area(b) - _area(union)
                if saved > best:
                    best, pair = saved, (i, j, union)
        if pair is None:
            break
        i, j, union = pair
        out = [r for k, r in enumerate(out) if k not in (i, j)] + [union]
    return out


def _area(box: tuple[int, int, int, int]) -> int:
    return (box[2] - box[0]) * (box[3] - box[1])


class Shot:
    """One camera's exposure (module docstring): ``fields`` the simulation's states then, per
    field the instants its exposure samples (not changed afterwards; one field of one state
    for a camera with neither blur nor interlacing), ``camera`` its index, ``t`` (s) its time,
    ``offset`` its noise offset (:meth:`Imager.exposure`)."""

    def __init__(self, renderer: GrayRenderer, imager: Imager | None, fields: list[list],
                 camera: int, t: float, offset: int) -> None:
        self._renderer, self._imager, self._fields = renderer, imager, fields
        self.camera, self.t, self.offset = camera, t, offset
        width, height = renderer.size(camera)
        self.shape = (height, width)
        self._whole: np.ndarray | None = None

    @property
    def renderer(self) -> GrayRenderer:
        """The renderer the shot renders with (its OpenGL contexts belong to the thread that
        made it)."""
        return self._renderer

    def whole(self) -> np.ndarray:
        """(H, W) uint8: the whole image (rendered once)."""
        if self._whole is None:
            image = combine([[self._renderer.render(d, [self.camera])[self.camera] for d in f]
                             for f in self._fields], 0)
            self._whole = image if self._imager is None else self._imager.whole(
                image, self.t, self.offset)
        return self._whole

    def preview(self, scale: float, renderer: GrayRenderer | None = None) -> np.ndarray:
        """(H, W) uint8: the whole image for a picture (a video frame), rendered at ``scale``
        of the resolution (:meth:`GrayRenderer.render_preview
        <cellsight.world.render.GrayRenderer.render_preview>`) with the exposure's effects;
        the whole image itself once it has been rendered. ``renderer``: another thread's twin
        of the shot's renderer (:meth:`GrayRenderer.twin
        <cellsight.world.render.GrayRenderer.twin>`), to render with there."""
        if self._whole is not None:
            return self._whole
        image = (renderer or self._renderer).render_preview(self._fields[-1][-1], self.camera,
                                                            scale)
        return image if self._imager is None else self._imager.whole(image, self.t, self.offset)

    def grab(self, boxes: Sequence[Sequence[int]],
             groups: Sequence[int] | None = None) -> np.ndarray:
        """(H, W) uint8: the image's pixels in the bounding box of ``boxes`` (half-open
        ``(u0, v0, u1, v1)``, clipped to the image), or with ``groups`` (per box, its group)
        in each group's bounding box, those rendered together where that costs less (module
        docstring), 0 elsewhere; the whole image once it has been rendered."""
        if self._whole is not None:
            return self._whole
        canvas = np.zeros(self.shape, np.uint8)
        b = np.asarray(boxes, dtype=np.int64).reshape(-1, 4)
        labels = np.zeros(len(b), np.int64) if groups is None else np.asarray(groups)
        regions = [r for g in np.unique(labels) if (r := self._region(b[labels == g]))]
        for region in merged_regions(regions):
            u0, v0, u1, v1 = region
            canvas[v0:v1, u0:u1] = self._read(region)
        return canvas

    def _region(self, b: np.ndarray) -> tuple[int, int, int, int] | None:
        """The bounding box of boxes ``b`` (n, 4) inside the image, widened to whole JPEG
        blocks when the camera compresses; None when empty."""
        if len(b) == 0:
            return None
        h, w = self.shape
        step = 1 if self._imager is None else self._imager.block()
        u0, v0 = (max(int(b[:, i].min()), 0) // step * step for i in (0, 1))
        u1, v1 = (min(-(-int(b[:, i].max()) // step) * step, n) for i, n in ((2, w), (3, h)))
        return (u0, v0, u1, v1) if u0 < u1 and v0 < v1 else None

    def _read(self, region: tuple[int, int, int, int]) -> np.ndarray:
        """The pixels of ``region``: rendered with the imager's blur context around it, then
        the image effects."""
        u0, v0, u1, v1 = region
        if self._imager is None:
            return self._render(region)
        h, w = self.shape
        m = self._imager.margin()
        p0, q0, p1, q1 = max(u0 - m, 0), max(v0 - m, 0), min(u1 + m, w), min(v1 + m, h)
        raw = self._render((p0, q0, p1, q1))
        developed = self._imager.develop(raw, (p0, q0), self.shape, self.t, self.offset)
        return self._imager.finish(developed[v0 - q0:v1 - q0, u0 - p0:u1 - p0])

    def _render(self, box: tuple[int, int, int, int]) -> np.ndarray:
        """The rendered pixels of ``box`` (before the image effects), over the exposure."""
        return combine([[self._renderer.render_region(d, self.camera, box) for d in f]
                        for f in self._fields], box[1])
