"""cellsight: occlusion prediction and occlusion-aware visual tracking for robot cells.

Predicts at camera frame rate which feature points of the workpieces each fixed camera of a
multi-arm robot cell can see (BSP tree of every surface, visited back to front from each
optical centre), and uses it to track the workpieces and guide the robots.
"""

from cellsight.camera import Camera
from cellsight.model.loader import load_cell

__all__ = ["Camera", "load_cell"]
__version__ = "0.1.0"
