"""What a real camera and frame grabber do to the rendered image, in the order light meets them.

1. optics: vignetting (brightness falls as ``1 - vignetting (r / r_corner)^2`` with the
   distance ``r`` from the image centre) and defocus (a Gaussian blur of ``defocus_px``);
2. the scene's lighting and the camera's gain drift slowly: every grey level is multiplied by
   ``1 + gain_drift sin(2 pi t / gain_period_s + gain_phase)``;
3. the sensor: shot noise (Poisson in electrons, as a Gaussian of variance ``I * shot_dn_per_e``
   grey levels^2 for a level ``I``) and read noise (Gaussian, ``read_noise_dn``), then 8 bits;
4. the link: optional JPEG compression at ``jpeg_quality`` (1-100; 0: none).

Grey levels (DN) are 0-255. The noise is seeded (:class:`Imager`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class ImageEffects:
    """The effects' strengths (module docstring); all zero is a clean render."""

    read_noise_dn: float = 0.0
    shot_dn_per_e: float = 0.0
    gain_drift: float = 0.0
    gain_period_s: float = 20.0
    gain_phase: float = 0.0
    defocus_px: float = 0.0
    vignetting: float = 0.0
    jpeg_quality: int = 0


class Imager:
    """Applies :class:`ImageEffects` to each camera's rendered images, with seeded noise."""

    def __init__(self, effects: ImageEffects, seed: int) -> None:
        self.effects = effects
        self._rng = np.random.default_rng(seed)
        self._falloff: dict[tuple[int, int], np.ndarray] = {}

    def apply(self, images: list[np.ndarray | None], t: float) -> list[np.ndarray | None]:
        """The images (H, W) uint8 as grabbed at time ``t`` (s); None stays None."""
        return [None if img is None else self._one(img, t) for img in images]

    def _one(self, image: np.ndarray, t: float) -> np.ndarray:
        e = self.effects
        img = image.astype(np.float32)
        if e.vignetting > 0:
            img *= self._vignette(img.shape)
        if e.defocus_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), e.defocus_px)
        if e.gain_drift:
            img *= 1.0 + e.gain_drift * math.sin(2 * math.pi * t / e.gain_period_s + e.gain_phase)
        var = np.float32(e.read_noise_dn ** 2) + np.clip(img, 0, None) * np.float32(
            e.shot_dn_per_e)
        if e.read_noise_dn > 0 or e.shot_dn_per_e > 0:
            img += np.sqrt(var) * self._rng.standard_normal(img.shape, dtype=np.float32)
        out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        if e.jpeg_quality > 0:
            ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(e.jpeg_quality)])
            out = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE) if ok else out
        return out

    def _vignette(self, shape: tuple[int, int]) -> np.ndarray:
        if shape not in self._falloff:
            h, w = shape
            v, u = np.mgrid[0:h, 0:w].astype(np.float32)
            r2 = ((u - (w - 1) / 2) ** 2 + (v - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2
                                                                     + ((h - 1) / 2) ** 2)
            self._falloff[shape] = (1.0 - self.effects.vignetting * r2).astype(np.float32)
        return self._falloff[shape]
