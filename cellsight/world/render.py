"""Offscreen grayscale rendering of the cell's cameras (B/W cameras, like the paper's).

Images are rendered with the camera's pinhole model (see
:func:`~cellsight.world.mjcf.mjcf_camera`); a camera with lens distortion gets the rendered
image warped by the camera's distortion maps (:meth:`Camera.distortion_maps
<cellsight.camera.Camera.distortion_maps>`), so that ``Camera.project`` matches the pixels.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import cv2
import mujoco
import numpy as np

from cellsight.camera import Camera


class GrayRenderer:
    """Renders every cell camera of a MuJoCo model as (H, W) uint8 grayscale images."""

    def __init__(self, model, cameras: list[Camera], size: tuple[int, int] | None = None) -> None:
        self._names = [c.name for c in cameras]
        self._sizes = [size or (c.width, c.height) for c in cameras]
        self._maps = [c.distortion_maps(s) for c, s in zip(cameras, self._sizes, strict=True)]
        try:
            self._renderers = {s: mujoco.Renderer(model, s[1], s[0]) for s in set(self._sizes)}
        except Exception as exc:
            raise RuntimeError(
                f"offscreen rendering failed with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}: "
                f"{exc}. Set MUJOCO_GL=egl (or osmesa) before MuJoCo is first imported "
                f"(import cellsight.world first, or export it in the shell)."
            ) from exc
        self._rgb = {s: np.empty((s[1], s[0], 3), np.uint8) for s in self._renderers}

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
            renderer.update_scene(data, camera=name)
            rgb = renderer.render(out=self._rgb[size])
            gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
            if maps is not None:
                gray = cv2.remap(gray, maps[0], maps[1], cv2.INTER_LINEAR, borderValue=0)
            images.append(gray)
        return images

    def close(self) -> None:
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers.clear()
