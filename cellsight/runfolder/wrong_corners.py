"""Where a run's wrong corners come from: every corner measured more than ``WRONG_PX`` (3 px)
from its feature's true projection (``wrong_c{c}`` of ``frames.csv``), grouped by camera and
feature into spans of frames, each with what the gate did (accepted, rejected; a frame of an
acquisition that gave no fix, ``waiting`` or ``lost``, used none of its corners, nor did a
camera held out of the filter, ``held_out_c{c}``: ``unused``, as the run's ``wrong_accepted``
counts) and what the simulator and the tracker said of the
feature then.

A span is a run of frames of one camera and feature with a wrong corner, frames less than
``GAP_FRAMES`` apart joined. Its ``truth`` is the simulator's most frequent label of the
feature over the span (``visible``, or what hides it: ``self``, a link, ``unknown.forearm``),
and ``predicted`` the tracker's: a wrong corner on a feature truly hidden but predicted
visible comes from the occluder's own corners; on a truly visible feature, from the extractor
(a corner beside it, an edge, noise).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from cellsight.runfolder.framelog import WRONG_PX, FrameLog, camera_column

GAP_FRAMES = 3  # frames: wrong corners of one feature this close belong to one span
__all__ = ["GAP_FRAMES", "WRONG_PX", "WrongSpan", "wrong_corner_spans"]


@dataclass(frozen=True)
class WrongSpan:
    """Wrong corners of one camera and feature over ``t_start``..``t_end`` (s): ``frames``
    with one, ``accepted`` by the gate (and used), ``rejected`` by it, ``unused`` (frames that
    used nothing); the ``phase`` (the first);
    ``truth`` and ``predicted``: the most frequent labels (module docstring); ``camera_index``
    and ``feature_index``: the camera's and the feature's 0-based index in the log, whatever
    their names."""

    camera: str
    feature: str
    t_start: float
    t_end: float
    frames: int
    accepted: int
    rejected: int
    unused: int
    phase: str
    truth: str
    predicted: str
    camera_index: int
    feature_index: int

    def as_dict(self) -> dict:
        return asdict(self)


def wrong_corner_spans(run_dir: str | Path, cameras: list[str] | None = None,
                       features: list[str] | None = None) -> list[WrongSpan]:
    """The spans of a run folder's wrong corners (module docstring), most accepted first.
    ``cameras`` and ``features`` name them (default ``cam<c>``, 1-based, and ``#<j>``, the
    0-based index of the log's flags)."""
    log = FrameLog.read(Path(run_dir) / "frames.csv")
    t, phases, used_by = log.floats("t"), log.text("phase"), log.used_by_camera()
    F = log.n_features
    spans: list[WrongSpan] = []
    for c in range(1, log.n_cameras + 1):
        wrong = log.bits(camera_column("wrong", c), F)
        rejected = log.bits(camera_column("rej", c), F)
        truth = log.labels(camera_column("occ_true", c), F)
        predicted = log.labels(camera_column("occ_pred", c), F)
        camera = cameras[c - 1] if cameras else f"cam{c}"
        used = used_by[:, c - 1]
        for f in np.flatnonzero(wrong.any(axis=0)):
            for rows in _runs(np.flatnonzero(wrong[:, f])):
                spans.append(WrongSpan(
                    camera, features[f] if features else f"#{f}", float(t[rows[0]]),
                    float(t[rows[-1]]), len(rows), int((~rejected[rows, f] & used[rows]).sum()),
                    int(rejected[rows, f].sum()), int((~rejected[rows, f] & ~used[rows]).sum()),
                    phases[rows[0]],
                    _most(truth[rows, f]), _most(predicted[rows, f]), c - 1, int(f)))
    return sorted(spans, key=lambda s: (-s.accepted, -s.frames, s.t_start))


def _runs(rows: np.ndarray) -> list[np.ndarray]:
    """``rows`` (sorted frame indices) split where two are ``GAP_FRAMES`` or more apart."""
    if rows.size == 0:
        return []
    return np.split(rows, np.flatnonzero(np.diff(rows) >= GAP_FRAMES) + 1)


def _most(labels: np.ndarray) -> str:
    """The most frequent label (empty: ``visible``)."""
    label, _ = Counter(str(x) for x in labels).most_common(1)[0]
    return label or "visible"
