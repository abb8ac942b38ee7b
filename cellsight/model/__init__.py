"""The cell model: robots (DH chains with link solids and tools), workpieces, static objects and
cameras, and the snapshot of every object's pose at one sampling time (paper, Section III-A)."""

from cellsight.model.cell import (
    Cell,
    CellObject,
    ExperimentSetup,
    Snapshot,
    StaticObject,
    Workpiece,
)
from cellsight.model.robot import ParallelGripper, Robot

__all__ = [
    "Cell",
    "CellObject",
    "ExperimentSetup",
    "ParallelGripper",
    "Robot",
    "Snapshot",
    "StaticObject",
    "Workpiece",
]
