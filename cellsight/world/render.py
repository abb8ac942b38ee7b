"""Offscreen grayscale rendering of the cell's cameras (B/W cameras, like the paper's).

Images are rendered with the camera's pinhole model (see
:func:`~cellsight.world.mjcf.mjcf_camera`); a camera with lens distortion gets the rendered
image warped by the camera's distortion maps (:meth:`Camera.distortion_maps
<cellsight.camera.Camera.distortion_maps>`), so that ``Camera.project`` matches the pixels.

A region of an image (a half-open box ``(u0, v0, u1, v1)`` of pixels, ``image[v0:v1, u0:u1]``)
can be rendered alone, as a camera that grabs only its windows reads only them
(:meth:`GrayRenderer.render_region`). It is rendered into an offscreen framebuffer resized to
the region (``mjr_resizeOffscreen``: a software render costs about 0.65 ms plus its
framebuffer's area, 0.03 us a pixel with 4x multisampling on this kind of machine; resizing
costs about 0.05 ms), with the whole image's projection and the viewport moved by the region's
origin, so its pixels are the whole render's: the same to the grey level except at a few
anti-aliased edge samples (about 1 pixel in 100,000), where the shifted viewport rounds a
vertex differently; such a pixel may differ by tens of grey levels (up to 33 measured on
experiment 3). A distorted camera renders the region of the pinhole
image its distortion maps read.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence

import cv2
import mujoco
import numpy as np

from cellsight.camera import Camera

# Held while a thread makes, uses or frees an OpenGL context (each thread renders with contexts
# of its own), and while the model's framebuffer settings are changed to make one. A harsh sweep
# run died of a segmentation fault with the run's thread and the video's thread both in
# mjr_render; with the lock one more did (of about 150), in the run's thread's mjr_readPixels
# while the video's thread waited here: the lock rules out the first, the cause is not found.
_GL = threading.RLock()


class GrayRenderer:
    """Renders every cell camera of a MuJoCo model as (H, W) uint8 grayscale images, whole
    or by region. ``samples``: multisampling of its framebuffers (default: the model's
    ``offsamples``, 4 for a cell: anti-aliased edges)."""

    def __init__(self, model, cameras: list[Camera], size: tuple[int, int] | None = None,
                 samples: int | None = None) -> None:
        self._model, self._cameras, self._size = model, list(cameras), size
        self._samples = model.vis.quality.offsamples if samples is None else int(samples)
        self._names = [c.name for c in cameras]
        self._sizes = [size or (c.width, c.height) for c in cameras]
        self._maps = [c.distortion_maps(s) for c, s in zip(cameras, self._sizes, strict=True)]
        try:
            self._renderers = {s: self._context(*s) for s in set(self._sizes)}
        except Exception as exc:
            raise RuntimeError(
                f"offscreen rendering failed with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}: "
                f"{exc}. Set MUJOCO_GL=egl (or osmesa) before MuJoCo is first imported "
                f"(import cellsight.world first, or export it in the shell)."
            ) from exc
        self._rgb = {s: np.empty((s[1], s[0], 3), np.uint8) for s in self._renderers}
        self._offscreen: mujoco.Renderer | None = None  # regions and previews (resized)
        self._framebuffer = (0, 0)  # its framebuffer's (width, height) px now

    def twin(self, samples: int | None = None) -> GrayRenderer:
        """A renderer of the same model, cameras and sizes (and multisampling, unless
        ``samples`` is given), with OpenGL contexts of its own, current in the thread that
        makes it: for another thread, which must also close it."""
        return GrayRenderer(self._model, self._cameras, self._size,
                            self._samples if samples is None else samples)

    def size(self, camera: int) -> tuple[int, int]:
        """(width, height) px of camera ``camera``'s rendered images."""
        return self._sizes[camera]

    def render(self, data, cameras: Sequence[int] | None = None) -> list[np.ndarray | None]:
        """Every camera's image, in camera order; with ``cameras`` (indices), only theirs (None
        for the others)."""
        images: list[np.ndarray | None] = []
        for c, (name, size, maps) in enumerate(zip(self._names, self._sizes, self._maps,
                                                   strict=True)):
            if cameras is not None and c not in cameras:
                images.append(None)
                continue
            renderer = self._renderers[size]
            with _GL:
                renderer.update_scene(data, camera=name)
                rgb = renderer.render(out=self._rgb[size])
            gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
            if maps is not None:
                gray = cv2.remap(gray, maps[0], maps[1], cv2.INTER_LINEAR, borderValue=0)
            images.append(gray)
        return images

    def render_preview(self, data, camera: int, scale: float) -> np.ndarray:
        """(H, W) uint8: camera ``camera``'s whole image rendered at ``scale`` (0-1] of its
        resolution (the same field of view, the viewport shrunk, in a framebuffer of that size)
        and resized back to it, then distorted as :meth:`render` does: a picture for a
        video, at a fraction of the cost, blurrier than the image the tracker reads."""
        width, height = self._sizes[camera]
        w, h = max(1, round(width * scale)), max(1, round(height * scale))
        gray = cv2.resize(self._offscreen_gray(data, camera, w, h, mujoco.MjrRect(0, 0, w, h)),
                          (width, height), interpolation=cv2.INTER_LINEAR)
        maps = self._maps[camera]
        if maps is None:
            return gray
        return cv2.remap(gray, maps[0], maps[1], cv2.INTER_LINEAR, borderValue=0)

    def render_region(self, data, camera: int, box: Sequence[int]) -> np.ndarray:
        """(v1 - v0, u1 - u0) uint8: the pixels ``box`` = (u0, v0, u1, v1) of camera
        ``camera``'s image (inside the image; module docstring), as :meth:`render` gives
        them."""
        u0, v0, u1, v1 = (int(x) for x in box)
        width, height = self._sizes[camera]
        if not (0 <= u0 < u1 <= width and 0 <= v0 < v1 <= height):
            raise ValueError(f"render_region: box {tuple(box)} is not inside the "
                             f"{width}x{height} image of camera {self._names[camera]!r}")
        maps = self._maps[camera]
        if maps is None:
            return self._pinhole_region(data, camera, (u0, v0, u1, v1))
        mu, mv = maps[0][v0:v1, u0:u1], maps[1][v0:v1, u0:u1]
        inside = (mu > -1) & (mu < width) & (mv > -1) & (mv < height)
        if not inside.any():
            return np.zeros((v1 - v0, u1 - u0), np.uint8)
        s0 = max(int(np.floor(mu[inside].min())), 0), max(int(np.floor(mv[inside].min())), 0)
        s1 = (min(int(np.floor(mu[inside].max())) + 2, width),
              min(int(np.floor(mv[inside].max())) + 2, height))
        source = self._pinhole_region(data, camera, (*s0, *s1))
        # the maps moved by the source's integer origin sample the same pixels; samples outside
        # the whole image read the border value there as here
        padded = np.zeros((s1[1] - s0[1] + 2, s1[0] - s0[0] + 2), np.uint8)
        padded[1:-1, 1:-1] = source
        return cv2.remap(padded, mu - np.float32(s0[0] - 1), mv - np.float32(s0[1] - 1),
                         cv2.INTER_LINEAR, borderValue=0)

    def _pinhole_region(self, data, camera: int, box: tuple[int, int, int, int]) -> np.ndarray:
        """The pixels ``box`` of camera ``camera``'s pinhole (undistorted) render."""
        u0, v0, u1, v1 = box
        width, height = self._sizes[camera]
        # OpenGL's rows count from the bottom: the framebuffer's bottom row is image row v1
        return self._offscreen_gray(data, camera, u1 - u0, v1 - v0,
                                    mujoco.MjrRect(-u0, -(height - v1), width, height))

    def _offscreen_gray(self, data, camera: int, w: int, h: int,
                        viewport: mujoco.MjrRect) -> np.ndarray:
        """(h, w) uint8: camera ``camera`` rendered through ``viewport`` into the offscreen
        framebuffer sized ``w`` x ``h`` px, read back top row first, in grey."""
        rgb = np.empty((h, w, 3), np.uint8)
        with _GL:
            renderer = self._sized(w, h)
            renderer.update_scene(data, camera=self._names[camera])
            mujoco.mjr_render(viewport, renderer.scene, renderer._mjr_context)
            mujoco.mjr_readPixels(rgb, None, mujoco.MjrRect(0, 0, w, h), renderer._mjr_context)
        return cv2.cvtColor(np.flipud(rgb), cv2.COLOR_RGB2GRAY)

    def _sized(self, width: int, height: int) -> mujoco.Renderer:
        """The offscreen renderer (made on first use), its context current and its
        framebuffer resized to ``width`` x ``height`` px where it is not that size."""
        if self._offscreen is None:
            self._offscreen = self._context(width, height, framebuffer=(width, height))
            self._framebuffer = (width, height)
        self._offscreen._gl_context.make_current()
        if self._framebuffer != (width, height):
            mujoco.mjr_resizeOffscreen(width, height, self._offscreen._mjr_context)
            self._framebuffer = (width, height)
        return self._offscreen

    def _context(self, width: int, height: int,
                 framebuffer: tuple[int, int] | None = None) -> mujoco.Renderer:
        """A renderer of ``width`` x ``height`` px images with this renderer's multisampling,
        its framebuffer ``framebuffer`` (width, height) px (default: the model's): a
        framebuffer's size and samples are the model's ``offwidth``, ``offheight`` and
        ``offsamples`` when it is made, set for the moment (under a lock: another thread may be
        making one of its own)."""
        glob, quality = self._model.vis.global_, self._model.vis.quality
        with _GL:
            kept = glob.offwidth, glob.offheight, quality.offsamples
            if framebuffer is not None:
                glob.offwidth, glob.offheight = framebuffer
            quality.offsamples = self._samples
            try:
                return mujoco.Renderer(self._model, height, width)
            finally:
                glob.offwidth, glob.offheight, quality.offsamples = kept

    def close(self) -> None:
        kept = [] if self._offscreen is None else [self._offscreen]
        with _GL:
            for renderer in [*self._renderers.values(), *kept]:
                renderer.close()
        self._renderers.clear()
        self._offscreen = None
