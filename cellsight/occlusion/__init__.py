"""Occlusion prediction core: a BSP tree of the cell's polygons visited back to front.

``PolygonSoup`` holds the polygons in flat arrays, ``BSPTree`` builds the tree and answers
``visibility(points, viewpoint)``; ``visible_mask`` does all three in one call. The cell-level
predictor of a structure: :func:`~cellsight.occlusion.backends.visibility_predictor`.
"""

from cellsight.occlusion.bsp import BSPTree, visible_mask
from cellsight.occlusion.soup import PolygonSoup

__all__ = ["BSPTree", "PolygonSoup", "visible_mask"]
