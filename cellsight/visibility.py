"""What every visibility source answers: which feature points of a workpiece a camera sees,
and why the others are hidden.

These sources give this answer, one class each, behind one interface
(:class:`VisibilitySource`):

- the occlusion predictor's back-ends, one per structure (:data:`STRUCTURES`), on a shared
  base that projects the features, tests the near-occluder ring and labels the answers
  (:class:`cellsight.occlusion.predictor.VisibilityPredictor`; ``visibility_predictor(cell,
  structure=name)`` builds the one of that name): per-object hierarchies
  (:class:`cellsight.occlusion.object_bvh.ObjectBVH`) and the paper's per-frame BSP tree
  (:class:`cellsight.occlusion.frame_bsp.FrameBSP`);
- :class:`cellsight.occlusion.projection.ProjectionOnly`: in front of the camera and inside the
  image, occlusions ignored (the ``--no-occlusion-prediction`` baseline);
- the simulator's truth (:meth:`cellsight.world.World.true_views`, MuJoCo ray casts at the true
  state; it answers for the world's own state rather than for given joints and poses, so it is
  not a :class:`VisibilitySource`, but its answers have the same type).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from cellsight.fields import NamedEnum

if TYPE_CHECKING:
    from cellsight.camera import Camera

BEHIND, OUTSIDE, SELF = "behind", "outside", "self"
#: The predictor's structures, one back-end class each
#: (:class:`cellsight.occlusion.predictor.VisibilityPredictor`): static per-object hierarchies
#: built once in each object's frame (the default), or the paper's one BSP tree of the culled
#: surfaces per frame. Here, so that the command line can name them without importing the
#: predictor.
class Structure(NamedEnum):
    """The occlusion predictor's back-ends
    (:func:`cellsight.occlusion.backends.visibility_predictor` builds one): per-object
    hierarchies built once (the default) or the paper's per-frame BSP tree. A structure
    equals, prints and serialises as its name."""

    OBJECT_BVH = "object-bvh"
    FRAME_BSP = "frame-bsp"


OBJECT_BVH, FRAME_BSP = Structure.OBJECT_BVH, Structure.FRAME_BSP
STRUCTURES = tuple(s.value for s in Structure)
STATUS_INSIDE, STATUS_BEHIND, STATUS_OUTSIDE = 0, 1, 2  # codes of CameraVisibility.status


@dataclass
class CameraVisibility:
    """One workpiece seen by one camera at one sampling time (F features).

    ``visible`` (F,) bool in feature order; ``pixels`` (F, 2) (u, v) as in the image, with
    distortion (NaN behind the camera); ``occluder`` (F,) index into ``object_labels`` of the
    nearest hiding object, or -1; ``status`` (F,) ``STATUS_INSIDE`` (0) in the image,
    ``STATUS_BEHIND`` (1) behind the camera, ``STATUS_OUTSIDE`` (2) outside the image;
    ``part_object``: the workpiece's own index into ``object_labels``. :attr:`reason` names why
    each feature is hidden. ``near_occluder`` (F,) bool: visible, but another object's
    silhouette passes within a few pixels of its projection (the occlusion predictor's ring test;
    all False for the other sources).
    """

    camera: str
    visible: np.ndarray
    pixels: np.ndarray
    occluder: np.ndarray
    status: np.ndarray
    object_labels: list[str]
    part_object: int
    near_occluder: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.near_occluder is None:
            self.near_occluder = np.zeros(len(self.visible), dtype=bool)

    @property
    def count(self) -> int:
        """Number of visible features."""
        return int(self.visible.sum())

    @property
    def reason(self) -> list[str]:
        """Per feature: '' when visible, else 'behind', 'outside', 'self' (hidden by its own
        workpiece) or the label of the object hiding it (``R7AX.gripper``, ``table``)."""
        out = []
        for st, occ in zip(self.status, self.occluder, strict=True):
            if st == STATUS_BEHIND:
                out.append(BEHIND)
            elif st == STATUS_OUTSIDE:
                out.append(OUTSIDE)
            elif occ < 0:
                out.append("")
            else:
                out.append(SELF if occ == self.part_object else self.object_labels[occ])
        return out


Views = dict[str, list[CameraVisibility]]
"""Workpiece name -> one :class:`CameraVisibility` per camera, in the source's camera order."""


class VisibilitySource(Protocol):
    """Predicts what each camera sees for given robot joints (robot name -> joint vector, m and
    rad), workpiece poses (name -> ``T_base_part``; a workpiece left out stays at the cell's
    nominal pose) and jaw openings (robot name -> opening, m; None: the cell's default)."""

    def predict(
        self,
        joints: Mapping[str, np.ndarray] | None = None,
        part_poses: Mapping[str, np.ndarray] | None = None,
        openings: Mapping[str, float] | None = None,
    ) -> Views: ...


@runtime_checkable
class Recalibrating(Protocol):
    """A visibility source that takes a camera's refined calibration from then on (the BSP
    predictors and the projection baseline do)."""

    def recalibrate(self, index: int, camera: Camera) -> None:
        """Use ``camera`` for camera ``index`` (the source's camera order) from now on."""
        ...
