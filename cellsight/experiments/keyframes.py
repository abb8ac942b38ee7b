"""Pictures of a run: one vision frame drawn over the camera images (:func:`draw_frame`, also
the frames of ``views.mp4``), and the key moments worth a picture (:class:`KeyFrames`:
``keyframes/<key>.png`` listed in ``keyframes.json``)."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np

from cellsight.camera import Camera
from cellsight.control import Phase
from cellsight.report.overlay import FeatureMarks, compose_views, draw_camera_overlay
from cellsight.runfolder.writes import WriteError, write_file
from cellsight.tracking.records import PartFrame, TrackerFrame
from cellsight.tracking.unknown import UNKNOWN_LABEL

Draw = Callable[[str], np.ndarray]
"""Draws the current frame with a caption: RGB image (H, W, 3) uint8."""


def draw_frame(images: Sequence[np.ndarray], frame: TrackerFrame, part: str,
               truth_visible: np.ndarray, cameras: Sequence[Camera], caption: str,
               scale: float) -> np.ndarray:
    """The cameras' images side by side, each with the tracker's prediction, selection,
    windows and measurements of workpiece ``part`` in ``frame``, its unknown-occluder map, and
    where the prediction disagrees with the truth (``truth_visible`` (C, F)); scaled by
    ``scale``, ``caption`` below."""
    rec = frame.parts[part]
    visible = rec.predicted_visible
    views = []
    for c, cam in enumerate(cameras):
        plan = rec.windows[c]
        marks = FeatureMarks(rec.pixels[c], visible[c], rec.selected[c], rec.measured[c],
                             rec.rejected[c], truth_visible[c])
        views.append(draw_camera_overlay(
            images[c], marks, boxes=np.zeros((0, 4), int) if plan is None else plan.boxes,
            title=cam.name, unknown=frame.unknown[c] if c < len(frame.unknown) else None))
    return compose_views(views, scale=scale, caption=caption)


class KeyFrames:
    """The frames worth a picture, each key with a score per frame; the best frame so far is
    drawn and saved. Keys: ``start`` (the first estimate; the self-occluded points),
    ``gripper`` (Grasp phase: most points the grasping robot's gripper hides),
    ``crossing_<camera>`` (most points the crossing robot hides from that camera), ``unknown``
    (most points under the tracker's unknown-occluder map, :mod:`cellsight.tracking.unknown`)."""

    def __init__(self, out: Path, cameras: Sequence[str], robot: str,
                 crossing: str | None) -> None:
        self.out = Path(out)
        self.folder = self.out / "keyframes"
        self.folder.mkdir(parents=True, exist_ok=True)
        self.cameras, self.robot, self.crossing = list(cameras), robot, crossing
        self.best: dict[str, dict] = {}

    def offer_frame(self, t: float, phase: str, rec: PartFrame, draw: Draw) -> None:
        """Score this frame (time ``t`` s, task ``phase``) for every key, from the predicted
        reasons why features are hidden; nothing before the part has an estimate."""
        if not rec.status.has_estimate:
            return
        reasons = rec.reasons
        head = f"t = {t:.2f} s, {phase}"

        def counts(prefix: str) -> list[int]:
            return [sum(r.startswith(prefix) for r in per_cam) for per_cam in reasons]

        if "start" not in self.best:
            self.offer("start", 1, t, f"{head}: first estimate; self-occluded points: "
                       + ", ".join(f"{cam} {n}" for cam, n in
                                   zip(self.cameras, counts("self"), strict=True)), draw)
        gripper = counts(f"{self.robot}.gripper")
        if phase == Phase.GRASP:
            self.offer("gripper", sum(gripper), t, f"{head}: the gripper hides "
                       + ", ".join(f"{n} points from {cam}" for cam, n in
                                   zip(self.cameras, gripper, strict=True)), draw)
        unknown = counts(UNKNOWN_LABEL)
        self.offer("unknown", sum(unknown), t, f"{head}: unknown occluders (shaded) cover "
                   + ", ".join(f"{n} points in {cam}" for cam, n in
                               zip(self.cameras, unknown, strict=True)), draw)
        if self.crossing is not None:
            for c, n in enumerate(counts(f"{self.crossing}.")):
                left = sum(1 for r in reasons[c] if not r)
                self.offer(f"crossing_{self.cameras[c]}", n, t,
                           f"{head}: {self.crossing} hides {n} points from "
                           f"{self.cameras[c]}, {left} visible", draw)

    def offer(self, key: str, score: float, t: float, caption: str, draw: Draw) -> None:
        """Keep this frame for ``key`` if it beats the best so far (``score`` > 0): draw it,
        save it and rewrite ``keyframes.json`` (ordered by time)."""
        if score <= 0 or score <= self.best.get(key, {}).get("score", 0):
            return
        ok, png = cv2.imencode(".png", cv2.cvtColor(draw(caption), cv2.COLOR_RGB2BGR))
        if not ok:
            raise WriteError(self.folder / f"{key}.png", "OpenCV could not encode the picture")
        write_file(self.folder / f"{key}.png", png.tobytes())
        self.best[key] = {"name": key, "t": round(t, 3), "caption": caption,
                          "file": f"keyframes/{key}.png", "score": score}
        ordered = sorted(self.best.values(), key=lambda k: k["t"])
        write_file(self.out / "keyframes.json", json.dumps(ordered, indent=1))
