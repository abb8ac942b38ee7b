"""A printed plate fixed to a robot's flange (a calibration board in place of the gripper), as
MJCF for :func:`~cellsight.world.mjcf.cell_mjcf` and a texture file for MuJoCo.

The plate is a box, one mesh geom named ``R.board`` on the robot's flange body ``R/n`` (frame
n of its chain, :func:`~cellsight.world.mjcf.body_name`), its vertices written in that frame.
Its printed face carries a rectangle of the texture (``R.board.png`` among the model's assets:
:func:`plate_files`), at the texture's own scale; the other five faces take one colour, the
face's top-left texel (a white margin for a board). The material reflects no highlight (no
specular light), so the printed contrast is what the lights and the texture make of it.

MuJoCo samples the texture at each pixel's centre, with mipmaps (OpenGL's, each level a 2 x 2
box average of the one before) and trilinear filtering. A printed edge stays where it is in a
level only where it falls on that level's texel edges: a pattern whose edges are every ``2^k``
texels of a texture whose sides are multiples of ``2^k`` keeps them down to level k; else the
levels' edges shift by up to half their texel (measured: up to 0.3 px on ChArUco corners of 45
px squares). Aligned, a texture finer than the image (minified) still puts an edge up to about
0.15 px off, by its phase on the pixel grid (Mesa's llvmpipe, measured; a GPU's sampler may
differ); a coarser one (magnified, bilinear) within 0.02-0.06 px.

Face frame (``T_flange_face``, m): origin at the printed face's top-left corner (the texture's
point ``face_px[:2]``), x along the texture's rows (image u), y down its columns (image v), z
into the plate (the printed face seen from -z is the texture, unmirrored); the plate fills
``0 <= x <= width``, ``0 <= y <= height``, ``0 <= z <= thickness``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import cv2
import numpy as np

from cellsight.geometry.transforms import is_rigid, transform_points

# The box's six faces as corner indices (bit 0: x, bit 1: y, bit 2: z), counter-clockwise
# seen from outside; the first one is the printed face (z = 0, outward normal -z).
_FACES = ((0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5))


@dataclass(frozen=True, eq=False)
class Plate:
    """A plate whose printed face is the rectangle ``face_px`` = (u0, v0, u1, v1) (texel edges:
    0 to W, 0 to H) of ``texture`` ((H, W) uint8 grey levels, row 0 at the top) at ``px_per_m``
    texels per metre; ``thickness_m`` behind the face; its face frame in the flange frame
    ``T_flange_face`` (module docstring)."""

    texture: np.ndarray
    px_per_m: float
    face_px: tuple[float, float, float, float]
    thickness_m: float
    T_flange_face: np.ndarray

    def __post_init__(self) -> None:
        if self.texture.ndim != 2 or self.texture.dtype != np.uint8 or not self.texture.size:
            raise ValueError(f"plate: the texture must be a (H, W) uint8 image, got "
                             f"{self.texture.dtype} {self.texture.shape}")
        if not (self.px_per_m > 0 and self.thickness_m > 0):
            raise ValueError(f"plate: px_per_m {self.px_per_m} and thickness_m "
                             f"{self.thickness_m} must be > 0")
        h, w = self.texture.shape
        u0, v0, u1, v1 = self.face_px
        if not (0 <= u0 < u1 <= w and 0 <= v0 < v1 <= h):
            raise ValueError(f"plate: face_px {self.face_px} is not a rectangle inside the "
                             f"{w} x {h} texture")
        if np.shape(self.T_flange_face) != (4, 4) or not is_rigid(self.T_flange_face):
            raise ValueError("plate: T_flange_face must be a rigid 4x4 transform")

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the printed face, m."""
        u0, v0, u1, v1 = self.face_px
        return (u1 - u0) / self.px_per_m, (v1 - v0) / self.px_per_m


def _name(robot: str) -> str:
    return f"{robot}.board"


def _num(values: np.ndarray) -> str:
    return " ".join(f"{float(v):.17g}" for v in np.ravel(values))


def plate_assets(robot: str, plate: Plate) -> list[str]:
    """The ``<texture>``, ``<material>`` and ``<mesh>`` assets of ``robot``'s plate."""
    name = _name(robot)
    w, h = plate.size_m
    corners = np.array([[w * (k & 1), h * (k >> 1 & 1), plate.thickness_m * (k >> 2)]
                        for k in range(8)])
    vertices = transform_points(plate.T_flange_face, corners[np.ravel(_FACES)])
    rows, cols = plate.texture.shape
    origin = np.array(plate.face_px[:2])
    texcoord = (origin + corners[np.ravel(_FACES), :2] * plate.px_per_m) / [cols, rows]
    texcoord[4:] = (origin + 0.5) / [cols, rows]  # the other faces: the face's top-left texel
    triangles = [(4 * f, 4 * f + 1, 4 * f + 2, 4 * f, 4 * f + 2, 4 * f + 3) for f in range(6)]
    return [
        f'<texture name={quoteattr(name)} type="2d" file={quoteattr(name + ".png")}/>',
        f"<material name={quoteattr(name)} texture={quoteattr(name)} rgba=\"1 1 1 1\" "
        f'specular="0" shininess="0" reflectance="0"/>',
        f'<mesh name={quoteattr(name)} vertex="{_num(vertices)}" texcoord="{_num(texcoord)}" '
        f'face="{" ".join(map(str, np.ravel(triangles)))}" inertia="shell"/>',
    ]


def plate_geom(robot: str, group: int) -> str:
    """The plate's geom (in geom group ``group``), for ``robot``'s flange body."""
    name = quoteattr(_name(robot))
    return f'<geom name={name} type="mesh" mesh={name} material={name} group="{group}"/>'


def plate_files(plates: Mapping[str, Plate]) -> dict[str, bytes]:
    """The plates' texture files (PNG), by the names their ``<texture>`` assets give, for
    ``mujoco.MjModel.from_xml_string(xml, assets)``."""
    files = {}
    for robot, plate in plates.items():
        ok, png = cv2.imencode(".png", plate.texture)
        if not ok:
            raise ValueError(f"plate of {robot}: its texture could not be encoded as PNG")
        files[_name(robot) + ".png"] = png.tobytes()
    return files
