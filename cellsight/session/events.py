"""The run log's occlusion events: a sink that logs a line whenever what hides the part from a
camera changes (predicted visibility)."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Sequence

from cellsight.session.frames import FrameRecord
from cellsight.session.protocols import RunContext

log = logging.getLogger(__name__)


class OcclusionEvents:
    """A line in the log (predicted visibility) whenever the set of what hides the part from a
    camera changes, or the count of visible points crosses 3 or 1."""

    def __init__(self) -> None:
        self.cameras: list[str] = []
        self._state: dict[int, tuple] = {}

    def start(self, run: RunContext) -> None:
        self.cameras = [c.name for c in run.cell.cameras]

    def frame(self, record: FrameRecord) -> None:
        self.update(record.t, record.phase, record.part.reasons)

    def close(self, completed: bool) -> None:
        """Nothing to finish: every line is logged as it comes."""

    def update(self, t: float, phase: str, reasons: Sequence[Sequence[str]]) -> None:
        """``reasons``: per camera, per feature, '' or why it is predicted hidden."""
        for c, per_feature in enumerate(reasons):
            hidden = Counter(r for r in per_feature if r)
            n_visible = sum(1 for r in per_feature if not r)
            state = (frozenset(hidden), min(n_visible, 3), n_visible == 0)
            if self._state.get(c) == state:
                continue
            self._state[c] = state
            text = ", ".join(f"{label} {n}" for label, n in sorted(hidden.items()))
            log.info("t=%6.2f s %-10s %s: %d/%d visible%s", t, phase, self.cameras[c],
                     n_visible, len(per_feature), f"; hidden: {text}" if text else "")
