"""Pictures of a run's worst wrong corners: for the spans that the gate accepted most
(:mod:`cellsight.runfolder.wrong_corners`), the camera's image at the span's first frame,
re-rendered from the run's log in the world the run had (:meth:`RunData.world_cell
<cellsight.runfolder.replay.RunData.world_cell>`: its realism draws; no image noise), cropped
around the feature's true projection and enlarged, with that projection marked (green cross):
the corner the extractor took instead lies within the window around it."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from cellsight.runfolder.replay import load_run
from cellsight.runfolder.writes import write_file
from cellsight.runfolder.wrong_corners import WrongSpan

HALF_PX = 24  # px: half the crop's side, around the true projection
ZOOM = 4


def wrong_corner_crops(run_dir: Path, spans: list[WrongSpan], shown: int = 4,
                       metrics: dict | None = None) -> list[Path]:
    """``fig_wrong_corner_<i>.png`` in ``run_dir`` for the first ``shown`` spans with an accepted
    corner; their paths. ``metrics``: the run's, when its
    metrics.json is not written yet."""
    worst = [s for s in spans if s.accepted][:shown]
    if not worst:
        return []
    from cellsight.world.replay import ReplayWorld  # the world only when there is a picture

    run = load_run(run_dir, metrics=metrics)
    world = ReplayWorld(run.world_cell())
    paths = []
    try:
        for i, span in enumerate(worst):
            k = int(np.argmin(np.abs(run.t - span.t_start)))
            c, f = span.camera_index, span.feature_index
            openings = {} if run.robot is None or not np.isfinite(run.opening[k]) else {
                run.robot: float(run.opening[k])}
            world.show_state({r: q[k] for r, q in run.joints.items()},
                             {run.part.name: run.T_true[k]}, openings)
            image = world.render([c])[c]
            point = run.T_true[k][:3, :3] @ run.part.feature_points[f] + run.T_true[k][:3, 3]
            px = world.cell.cameras[c].project(point[None])[0]
            paths.append(_save(run_dir / f"fig_wrong_corner_{i + 1}.png", image, px))
    finally:
        world.close()
    return paths


def _save(path: Path, image: np.ndarray, px: np.ndarray) -> Path:
    """The crop around ``px`` (u, v), enlarged, the point marked, as a PNG."""
    h, w = image.shape
    u, v = (int(round(x)) if np.isfinite(x) else 0 for x in px)
    u0, v0 = min(max(u - HALF_PX, 0), max(w - 2 * HALF_PX, 0)), min(max(v - HALF_PX, 0),
                                                                     max(h - 2 * HALF_PX, 0))
    crop = image[v0:v0 + 2 * HALF_PX, u0:u0 + 2 * HALF_PX]
    big = cv2.cvtColor(cv2.resize(crop, None, fx=ZOOM, fy=ZOOM,
                                  interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)
    centre = (int((px[0] - u0 + 0.5) * ZOOM), int((px[1] - v0 + 0.5) * ZOOM))
    cv2.drawMarker(big, centre, (0, 200, 0), cv2.MARKER_CROSS, 3 * ZOOM, 2)
    ok, png = cv2.imencode(".png", big)
    if not ok:
        raise ValueError(f"{path}: the crop could not be encoded")
    return write_file(path, png.tobytes())
