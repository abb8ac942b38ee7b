"""The tracker a user chooses, for ``cellsight run``, ``track``, ``sweep`` and the API (no heavy
imports: the command line's parsers read it).

The ``kinematic`` tracker (the default) is the paper's tracker plus the kinematic prior
(:mod:`cellsight.tracking.prior`: a held part follows the gripper's measured motion, a lying one
keeps its support's height, roll and pitch) and the cameras' registration to the gripper
(:mod:`cellsight.tracking.registration`), which hold it in the realistic worlds; the ``plain``
one is the paper's, from the images alone, kept for comparison. Occlusion prediction is on or
off. The :data:`EXPERIMENTAL` options have not earned their place in the 20-seed tables: the
camera offsets cost accuracy in ``exact`` and ``lab``, and the unknown-occluder map masks
features with nothing in view. :func:`cellsight.tracking.setup.build_tracker` builds the
choice.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

from cellsight.errors import CellsightError

TrackerKind = Literal["kinematic", "plain"]
TRACKERS: tuple[str, ...] = get_args(TrackerKind)
"""The trackers: ``kinematic`` (default) and ``plain`` (module docstring)."""

Experimental = Literal["camera-offsets", "unknown-occluders"]
EXPERIMENTAL: tuple[str, ...] = get_args(Experimental)
"""The experimental options: ``camera-offsets`` estimates each camera's calibration error as an
image offset (:mod:`cellsight.tracking.offsets`, a prior of :data:`CAMERA_OFFSETS_PRIOR_PX`);
``unknown-occluders`` learns where objects the cell file does not know hide the part
(:mod:`cellsight.tracking.unknown`)."""

CAMERA_OFFSETS_PRIOR_PX = 5.0
"""The prior (px per axis) of the experimental camera offsets."""


@dataclass(frozen=True)
class TrackerChoice:
    """The tracker a run uses (module docstring): ``kind`` (:data:`TRACKERS`),
    ``occlusion_prediction`` (off: every feature inside the image counts as visible) and the
    ``experimental`` options (:data:`EXPERIMENTAL`)."""

    kind: TrackerKind = "kinematic"
    occlusion_prediction: bool = True
    experimental: frozenset[Experimental] = frozenset()

    def __post_init__(self) -> None:
        if self.kind not in TRACKERS:
            raise CellsightError(f"--tracker: expected one of {', '.join(TRACKERS)}, got "
                                 f"{self.kind!r}")
        bad = sorted(set(self.experimental) - set(EXPERIMENTAL))
        if bad:
            raise CellsightError(f"--experimental: expected any of {', '.join(EXPERIMENTAL)}, "
                                 f"got {', '.join(map(repr, bad))}")
        object.__setattr__(self, "experimental", frozenset(self.experimental))

    @property
    def kinematic(self) -> bool:
        """Whether the kinematic prior and the cameras' registration are on."""
        return self.kind == "kinematic"

    @property
    def unknown_occluders(self) -> bool:
        """Whether the unknown-occluder map is on (experimental)."""
        return "unknown-occluders" in self.experimental

    @property
    def camera_offsets_px(self) -> float:
        """The camera offsets' prior (px; 0: off, the default)."""
        return CAMERA_OFFSETS_PRIOR_PX if "camera-offsets" in self.experimental else 0.0

    def describe(self) -> str:
        """One line for the log: the tracker, prediction and experimental options."""
        words = [f"{self.kind} tracker",
                 "occlusion prediction " + ("on" if self.occlusion_prediction else "off")]
        words += [f"experimental {name}" for name in sorted(self.experimental)]
        return ", ".join(words)


DEFAULT_TRACKER = TrackerChoice()
"""What a run uses without options: the kinematic tracker, occlusion prediction on."""
