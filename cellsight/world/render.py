"""Offscreen grayscale rendering of the cell's cameras (B/W cameras, like the paper's).

Images are rendered with the camera's pinhole model (see
:func:`~cellsight.world.mjcf.mjcf_camera`); a camera with lens distortion gets the rendered
image warped by its distortion model, so that ``Camera.project`` matches the pixels.
"""

from __future__ import annotations

import os

import cv2
import mujoco
import numpy as np

from cellsight.world.mjcf import scaled_K


def distortion_maps(camera, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """``cv2.remap`` maps that turn an ideal pinhole image (intrinsics scaled to ``size``)
    into the camera's distorted image, or None for a camera without distortion.

    Each output pixel is undistorted by fixed-point iteration of OpenCV's model (the inverse
    of ``Camera.project_camera``) to 1e-6 px, then mapped through the ideal camera matrix."""
    if camera.dist is None:
        return None
    w, h = size
    K = scaled_K(camera, size)
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    yd = (v - K[1, 2]) / K[1, 1]
    xd = (u - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    k1, k2, p1, p2, k3 = camera.dist
    x, y = xd.copy(), yd.copy()
    for _ in range(200):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        x_new = (xd - 2 * p1 * x * y - p2 * (r2 + 2 * x * x)) / radial
        y_new = (yd - p1 * (r2 + 2 * y * y) - 2 * p2 * x * y) / radial
        step = max(np.abs(x_new - x).max(), np.abs(y_new - y).max())
        x, y = x_new, y_new
        if step * K[0, 0] < 1e-6:
            break
    map_u = K[0, 0] * x + K[0, 1] * y + K[0, 2]
    map_v = K[1, 1] * y + K[1, 2]
    return map_u.astype(np.float32), map_v.astype(np.float32)


class GrayRenderer:
    """Renders every cell camera of a MuJoCo model as (H, W) uint8 grayscale images."""

    def __init__(self, model, cameras, size: tuple[int, int] | None = None) -> None:
        self._names = [c.name for c in cameras]
        self._sizes = [size or (c.width, c.height) for c in cameras]
        self._maps = [distortion_maps(c, s) for c, s in zip(cameras, self._sizes, strict=True)]
        try:
            self._renderers = {s: mujoco.Renderer(model, s[1], s[0]) for s in set(self._sizes)}
        except Exception as exc:
            raise RuntimeError(
                f"offscreen rendering failed with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}: "
                f"{exc}. Set MUJOCO_GL=egl (or osmesa) before MuJoCo is first imported "
                f"(import cellsight.world first, or export it in the shell)."
            ) from exc
        self._rgb = {s: np.empty((s[1], s[0], 3), np.uint8) for s in self._renderers}

    def render(self, data) -> list[np.ndarray]:
        images = []
        for name, size, maps in zip(self._names, self._sizes, self._maps, strict=True):
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
