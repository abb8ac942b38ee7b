"""The one place a structure picks its back-end (:class:`~cellsight.visibility.Structure`)."""

from __future__ import annotations

from cellsight.errors import CellsightError
from cellsight.model.cell import Cell
from cellsight.occlusion.frame_bsp import FrameBSP
from cellsight.occlusion.object_bvh import ObjectBVH
from cellsight.occlusion.predictor import VisibilityPredictor
from cellsight.visibility import STRUCTURES, Structure

BACKENDS: dict[Structure, type[VisibilityPredictor]] = {Structure.OBJECT_BVH: ObjectBVH,
                                                        Structure.FRAME_BSP: FrameBSP}


def visibility_predictor(cell: Cell, structure: Structure | str = Structure.OBJECT_BVH,
                         **options: object) -> VisibilityPredictor:
    """The occlusion predictor of ``cell`` with the back-end of ``structure`` (default
    ``object-bvh``) and its ``options`` (:class:`~cellsight.occlusion.predictor.
    VisibilityPredictor`: ``cameras``, ``surface_tolerance``, ``near_px``, and the back-end's
    own)."""
    try:
        kind = Structure(structure)
    except ValueError:
        raise CellsightError(f"VisibilityPredictor: structure must be one of "
                             f"{', '.join(STRUCTURES)}, got {structure!r}") from None
    return BACKENDS[kind](cell, **options)
