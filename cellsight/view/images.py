"""The cameras' images for the view: MuJoCo renderings of the shown state with the features
and the tracker's windows drawn on them (:class:`CameraImages`, the drawing of
:func:`cellsight.report.overlay.draw_camera_overlay`, the run's pictures' code), rendered on a
worker thread that keeps only the latest request and renders at most a few per second
(:class:`ImageWorker`), so that scrubbing the timeline stays responsive.

Windows: a run logs its windows and measured corners (``windows_c<c>``, ``corners_c<c>``), drawn
as they were. A run logged before those columns keeps only which features were selected
(``sel_c<c>``), not the filter's innovation covariance, so its windows are planned again by
:func:`cellsight.tracking.windowing.plan_windows` around the predicted pixels with a settled
filter's covariance (zero: the smallest window, ``min_size_px``, which is the tracker's own size
once its covariance has converged), cut where they would hold another visible feature as in the
run.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import numpy as np

from cellsight.camera import Camera
from cellsight.model.cell import Cell
from cellsight.report.overlay import FeatureMarks, draw_camera_overlay
from cellsight.tracking.unknown import Grid
from cellsight.tracking.windowing import plan_windows
from cellsight.view.states import FeatureState, FrameState


def window_boxes(camera: Camera, pixels: np.ndarray, visible: np.ndarray,
                 selected: np.ndarray | None) -> np.ndarray:
    """(n, 4) int windows ``(u0, v0, u1, v1)`` of one camera's selected features (module
    docstring); none without a selection."""
    if selected is None:
        return np.zeros((0, 4), dtype=int)
    chosen = np.flatnonzero(selected & np.all(np.isfinite(pixels), axis=1))
    seen = np.flatnonzero(visible & np.all(np.isfinite(pixels), axis=1))
    own = np.array([int(np.searchsorted(seen, f)) if f in seen else -1 for f in chosen],
                   dtype=np.int64)
    plan = plan_windows(pixels[chosen], chosen, np.zeros((len(chosen), 2, 2)), camera.width,
                        camera.height, others=pixels[seen], own=own)
    return plan.boxes


def draw_view(image: np.ndarray, camera: Camera, c: int,
              features: dict[str, FeatureState], unknown: Grid | None = None) -> np.ndarray:
    """Camera ``c``'s grayscale image with every workpiece's features drawn on it: predicted
    visible (green) or hidden (red), selected (yellow ring), windows (blue), measurements
    (crosses), where the prediction disagrees with the ray-cast truth (magenta), and the
    tracker's unknown-occluder map ``unknown`` (shaded orange)."""
    out = image
    for feats in features.values():
        F = feats.pixels.shape[1]

        def row(bits: np.ndarray | None, F: int = F) -> np.ndarray:
            return np.zeros(F, dtype=bool) if bits is None else bits[c]

        measured = np.full((F, 2), np.nan)
        if feats.measured is not None and feats.measured_pixels is not None:
            measured[feats.measured[c]] = feats.measured_pixels[c][feats.measured[c]]
        marks = FeatureMarks(feats.pixels[c], feats.visible[c], row(feats.selected), measured,
                             row(feats.rejected), None if feats.truth is None else feats.truth[c])
        out = draw_camera_overlay(
            out, marks, boxes=(feats.windows[c] if feats.windows is not None else window_boxes(
                camera, feats.pixels[c], feats.visible[c], row(feats.selected))),
            title=camera.name, unknown=unknown)
        unknown = None  # shaded once
    return out


class CameraImages:
    """Renders the cell's cameras at a :class:`FrameState`, with the overlays. The MuJoCo world
    (:class:`~cellsight.world.replay.ReplayWorld`, no tasks) is made at the first call, on the
    calling thread: call it from one thread only (its OpenGL context stays there)."""

    def __init__(self, cell: Cell) -> None:
        self.cell = cell
        self._world = None

    def draw(self, state: FrameState) -> list[np.ndarray]:
        """One RGB (H, W, 3) uint8 image per camera (``cell.cameras`` order)."""
        if self._world is None:
            from cellsight.world.replay import ReplayWorld

            self._world = ReplayWorld(self.cell)
        self._world.show_state(state.joints, state.part_poses, state.openings)
        images = self._world.render()
        return [draw_view(img, cam, c, state.features,
                          state.unknown[c] if c < len(state.unknown) else None)
                for c, (img, cam) in enumerate(zip(images, self.cell.cameras, strict=True))]

    def close(self) -> None:
        if self._world is not None:
            self._world.close()
            self._world = None


class ImageWorker:
    """A thread that draws the latest requested state with ``draw`` and hands the images to
    ``publish``, at most one drawing per ``min_interval`` seconds; requests made meanwhile
    replace each other (only the last is drawn). Errors are kept in ``error`` and reported
    through ``on_error``."""

    def __init__(self, draw: Callable[[FrameState], Sequence[np.ndarray]],
                 publish: Callable[[Sequence[np.ndarray], FrameState], None],
                 min_interval: float = 0.2, close: Callable[[], None] | None = None,
                 on_error: Callable[[BaseException], None] | None = None) -> None:
        self._draw, self._publish, self._close = draw, publish, close
        self._on_error = on_error
        self.min_interval = float(min_interval)
        self._cond = threading.Condition()
        self._pending: FrameState | None = None
        self._busy = False
        self._stopped = False
        self.drawn = 0  # number of drawings published
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="cellsight-view-images",
                                        daemon=True)
        self._thread.start()

    def request(self, state: FrameState) -> None:
        with self._cond:
            self._pending = state
            self._cond.notify_all()

    def wait_idle(self, timeout: float = 30.0) -> bool:
        """Wait until every request so far has been drawn and published (or failed)."""
        end = time.monotonic() + timeout
        with self._cond:
            while self._pending is not None or self._busy:
                left = end - time.monotonic()
                if left <= 0 or self._stopped:
                    return False
                self._cond.wait(left)
        return True

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify_all()
        self._thread.join(timeout=10.0)

    def _next(self) -> FrameState | None:
        with self._cond:
            while self._pending is None and not self._stopped:
                self._cond.wait()
            if self._stopped:
                return None
            state, self._pending, self._busy = self._pending, None, True
            return state

    def _run(self) -> None:
        last = -np.inf
        try:
            while (state := self._next()) is not None:
                time.sleep(max(0.0, last + self.min_interval - time.monotonic()))
                with self._cond:  # a newer request made while waiting replaces this one
                    state, self._pending = self._pending or state, None
                last = time.monotonic()
                self._draw_one(state)
        finally:
            if self._close is not None:
                self._close()

    def _draw_one(self, state: FrameState) -> None:
        try:
            self._publish(self._draw(state), state)
            self.drawn += 1
        except Exception as exc:  # kept and shown; the view goes on without new images
            self.error = exc
            if self._on_error is not None:
                self._on_error(exc)
        finally:
            with self._cond:
                self._busy = False
                self._cond.notify_all()
