"""What a real camera and frame grabber do to the rendered image, in the order light meets them.

1. optics: vignetting (brightness falls as ``1 - vignetting (r / r_corner)^2`` with the
   distance ``r`` from the image centre) and defocus (a Gaussian blur of ``defocus_px``);
2. the scene's lighting and the camera's gain drift slowly: every grey level is multiplied by
   ``1 + gain_drift sin(2 pi t / gain_period_s + gain_phase)``;
3. the sensor: shot noise (Poisson in electrons, as a Gaussian of variance ``I * shot_dn_per_e``
   grey levels^2 for a level ``I``) and read noise (Gaussian, ``read_noise_dn``), then 8 bits;
4. the link: optional JPEG compression at ``jpeg_quality`` (1-100; 0: none).

Grey levels (DN) are 0-255. Each exposure has one noise field over the whole image, so a
region of it (a camera that grabs only its windows, :class:`~cellsight.world.shots.Shot`)
comes out as the whole image's pixels there: the field is a window of a seeded bank of
``NOISE_BANK`` unit normals starting at the exposure's own random offset
(:meth:`Imager.exposure`), read at ``offset + v W + u`` for pixel (u, v). Two exposures share
a stretch of noise only when their offsets fall within an image's length of each other.
A region also needs its defocus context (:meth:`Imager.margin`) and, with JPEG, whole 8 x 8
blocks (:meth:`Imager.block`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

NOISE_BANK = 1 << 22  # unit normals in the noise bank (16 MiB of float32)
JPEG_BLOCK = 8  # px: JPEG codes 8 x 8 blocks of the image independently


@dataclass(frozen=True)
class ImageEffects:
    """The effects' strengths (module docstring); all zero is a clean render. ``exposure_s``
    (motion blur) and ``interlaced`` act on what is rendered
    (:mod:`cellsight.world.exposure_time`), before these effects."""

    read_noise_dn: float = 0.0
    shot_dn_per_e: float = 0.0
    gain_drift: float = 0.0
    gain_period_s: float = 20.0
    gain_phase: float = 0.0
    defocus_px: float = 0.0
    vignetting: float = 0.0
    jpeg_quality: int = 0
    exposure_s: float = 0.0
    interlaced: bool = False

    @property
    def noisy(self) -> bool:
        return self.read_noise_dn > 0 or self.shot_dn_per_e > 0


class Imager:
    """Applies :class:`ImageEffects` to each camera's rendered images, whole or by region, with
    seeded noise (module docstring)."""

    def __init__(self, effects: ImageEffects, seed) -> None:
        self.effects = effects
        self._rng = np.random.default_rng(seed)
        self._bank_seed = int(self._rng.integers(2 ** 63))
        self._bank: np.ndarray | None = None
        self._falloff: dict[tuple[int, int], np.ndarray] = {}

    def apply(self, images: list[np.ndarray | None], t: float) -> list[np.ndarray | None]:
        """The images (H, W) uint8 as grabbed at time ``t`` (s), one exposure each; None stays
        None."""
        return [None if img is None else self.whole(img, t, self.exposure()) for img in images]

    def whole(self, image: np.ndarray, t: float, offset: int) -> np.ndarray:
        """Every effect (steps 1-4) on a whole image exposed at ``t`` (s) with noise
        ``offset``."""
        return self.finish(self.develop(image, (0, 0), image.shape, t, offset))

    def exposure(self) -> int:
        """A new exposure's noise offset into the bank (module docstring)."""
        return int(self._rng.integers(NOISE_BANK)) if self.effects.noisy else 0

    def margin(self) -> int:
        """px of context a region needs on every side for its defocus blur to be the whole
        image's (OpenCV's float kernel reaches ``4 sigma``)."""
        return int(math.ceil(4 * self.effects.defocus_px)) + 1 if self.effects.defocus_px else 0

    def block(self) -> int:
        """px: a region must start and end on multiples of this (JPEG's blocks; 1: any)."""
        return JPEG_BLOCK if self.effects.jpeg_quality > 0 else 1

    def develop(self, image: np.ndarray, origin: tuple[int, int], shape: tuple[int, int],
                t: float, offset: int) -> np.ndarray:
        """Optics, gain and sensor (steps 1-3) on ``image``, the rendered pixels of a region
        whose top-left pixel is ``origin`` = (u, v) in a whole image of ``shape`` = (H, W),
        exposed at ``t`` (s) with noise ``offset`` (:meth:`exposure`): uint8, same shape.
        Pixels within :meth:`margin` of a region edge inside the image lack blur context."""
        e = self.effects
        img = image.astype(np.float32)
        h, w = img.shape
        u0, v0 = origin
        if e.vignetting > 0:
            img *= self._vignette(shape)[v0:v0 + h, u0:u0 + w]
        if e.defocus_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), e.defocus_px)
        if e.gain_drift:
            img *= 1.0 + e.gain_drift * math.sin(2 * math.pi * t / e.gain_period_s + e.gain_phase)
        if e.noisy:
            var = np.float32(e.read_noise_dn ** 2) + np.clip(img, 0, None) * np.float32(
                e.shot_dn_per_e)
            img += np.sqrt(var) * self._noise(origin, (h, w), shape[1], offset)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def finish(self, image: np.ndarray) -> np.ndarray:
        """The link (step 4) on a developed region that starts and ends on :meth:`block`."""
        q = self.effects.jpeg_quality
        if q <= 0:
            return image
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(q)])
        return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE) if ok else image

    def _noise(self, origin: tuple[int, int], size: tuple[int, int], width: int,
               offset: int) -> np.ndarray:
        """(h, w) float32 unit normals of the exposure's field over a region."""
        if self._bank is None:
            self._bank = np.random.default_rng(self._bank_seed).standard_normal(
                NOISE_BANK, dtype=np.float32)
        u0, v0 = origin
        h, w = size
        start = offset + (v0 + np.arange(h, dtype=np.int64))[:, None] * width + u0
        return self._bank.take(start + np.arange(w, dtype=np.int64), mode="wrap")

    def _vignette(self, shape: tuple[int, int]) -> np.ndarray:
        if shape not in self._falloff:
            h, w = shape
            v, u = np.mgrid[0:h, 0:w].astype(np.float32)
            r2 = ((u - (w - 1) / 2) ** 2 + (v - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2
                                                                     + ((h - 1) / 2) ** 2)
            self._falloff[shape] = (1.0 - self.effects.vignetting * r2).astype(np.float32)
        return self._falloff[shape]
