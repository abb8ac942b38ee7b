"""cellsight: occlusion prediction and occlusion-aware visual tracking for robot cells.

Predicts at camera frame rate which feature points of the workpieces each fixed camera of a
multi-arm robot cell can see (BSP tree of every surface, visited back to front from each
optical centre), and uses it to track the workpieces and guide the robots.
"""

from cellsight.threads import prefer_sleeping_threads

prefer_sleeping_threads()  # before numba launches its threads (cellsight.threads)

from cellsight.camera import Camera  # noqa: E402
from cellsight.model.loader import load_cell  # noqa: E402

__all__ = ["Camera", "load_cell"]
__version__ = "0.1.0"
