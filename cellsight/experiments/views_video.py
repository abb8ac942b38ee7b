"""``views.mp4`` drawn on a thread of its own, beside the run.

A frame of the video is each camera's whole image (rendered small,
:meth:`Shot.preview <cellsight.world.shots.Shot.preview>`) with the tracker's overlay
(:func:`~cellsight.experiments.keyframes.draw_frame`), encoded by ffmpeg
(:class:`~cellsight.report.video.VideoWriter`). Rendering and drawing took a quarter of a
rendered run's wall time on the run's own thread; here the run hands each frame's shots and
records over (:meth:`ViewsVideo.add`) and goes on. MuJoCo's rendering and OpenCV's drawing
release Python's lock, so the picture is made on the second core while the run simulates and
tracks on the first.

The thread has its own OpenGL renderer (:meth:`GrayRenderer.twin
<cellsight.world.render.GrayRenderer.twin>`: a context is current in one thread), made and
freed on it, without multisampling: two threads rendering at once slow each other, and the
tracker's renders keep theirs. What it reads is not changed after it is handed over: a shot
holds copies of the simulation's state, a frame's records are the tracker's of that frame;
the video is drawn from what each frame handed over, in order. At most ``depth`` frames wait; the
run waits when the thread lags further behind. A failure on the thread (ffmpeg gone, a full
disk) is raised by the next :meth:`ViewsVideo.add` or by :meth:`ViewsVideo.close`, as the run's
own thread would have raised it.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cellsight.camera import Camera
from cellsight.experiments.keyframes import draw_frame
from cellsight.report.video import VideoWriter
from cellsight.tracking.grabbing import grabbed
from cellsight.tracking.records import TrackerFrame
from cellsight.world.render import GrayRenderer
from cellsight.world.shots import Shot


@dataclass(frozen=True)
class _Picture:
    """One video frame to draw: per camera a :class:`Shot` or an image, the tracker's frame,
    the workpiece drawn and the truth's visibility of it (C, F), the caption."""

    shown: list[Any]
    frame: TrackerFrame
    part: str
    truth_visible: np.ndarray
    caption: str


class ViewsVideo:
    """``views.mp4`` of the cameras' views, drawn at ``scale`` of their resolution on a thread
    of its own (module docstring): ``fps`` the video's frame rate, ``depth`` the most frames
    waiting."""

    def __init__(self, path: str | Path, fps: float, cameras: Sequence[Camera],
                 scale: float = 0.5, depth: int = 4) -> None:
        self.writer = VideoWriter(path, fps=fps)
        self.path = self.writer.path
        self._cameras, self._scale = list(cameras), float(scale)
        self._jobs: queue.Queue[_Picture | None] = queue.Queue(maxsize=max(1, int(depth)))
        self._error: BaseException | None = None  # the thread's failure, not yet raised
        self._failed = False  # the thread failed: it drops what is queued
        self._thread = threading.Thread(target=self._work, name="views-video", daemon=True)
        self._thread.start()

    def add(self, shown: list[Any], frame: TrackerFrame, part: str, truth_visible: np.ndarray,
            caption: str) -> None:
        """Queue a frame: ``shown`` per camera a :class:`Shot` (rendered whole at the
        video's scale, or its whole image if the tracker rendered it) or an image (H, W)
        uint8; ``part`` the workpiece drawn, ``truth_visible`` its true visibility (C, F).
        Raises the thread's failure, if any."""
        self._raise()
        self._jobs.put(_Picture(list(shown), frame, part, np.array(truth_visible), caption))

    def close(self) -> None:
        """Draw what is queued, finish the file, end the thread; raises the thread's failure,
        if any. Safe to call twice."""
        if self._thread.is_alive():
            self._jobs.put(None)
            self._thread.join()
        self.writer.close()
        self._raise()

    def _raise(self) -> None:
        error, self._error = self._error, None
        if error is not None:
            raise error

    def _work(self) -> None:
        renderer: GrayRenderer | None = None
        try:
            while (job := self._jobs.get()) is not None:
                if self._failed:
                    continue
                try:
                    shot = next((s for s in job.shown if isinstance(s, Shot)), None)
                    if renderer is None and shot is not None:
                        renderer = shot.renderer.twin(samples=0)
                    self.writer.add(self._draw(job, renderer))
                except BaseException as exc:  # handed to the run's thread
                    self._error, self._failed = exc, True
        finally:
            if renderer is not None:
                renderer.close()

    def _draw(self, job: _Picture, renderer: GrayRenderer | None) -> np.ndarray:
        images = [s.preview(self._scale, renderer) if isinstance(s, Shot) else grabbed(s)
                  for s in job.shown]
        return draw_frame(images, job.frame, job.part, job.truth_visible, self._cameras,
                          job.caption, self._scale)
