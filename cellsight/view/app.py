"""The view as a running web server (:class:`ViewApp`): the viser server, the cell's scene
(:mod:`cellsight.view.scene`), the GUI (which camera colours the features, the ray-cast truth
instead of the prediction, the cameras' images) and, with a run, its timeline
(:mod:`cellsight.view.timeline`). The 3D scene follows the timeline at once; the camera images
follow through a throttled worker (:class:`cellsight.view.images.ImageWorker`)."""

from __future__ import annotations

import contextlib
import io
import math
import sys
import threading
from collections.abc import Sequence

import numpy as np
import viser

from cellsight.errors import CellsightError
from cellsight.model.cell import Cell
from cellsight.view.images import CameraImages, ImageWorker
from cellsight.view.inputs import check_port
from cellsight.view.replay import RunReplay
from cellsight.view.scene import CellScene
from cellsight.view.states import FrameState, static_state
from cellsight.view.timeline import Timeline

IMAGE_INTERVAL_S = 0.25  # at most 4 camera renderings per second while scrubbing or playing


def overview_camera(cell: Cell) -> tuple[np.ndarray, np.ndarray]:
    """A starting viewpoint (eye, target): 3.3 m away along the base frame's +x axis, 30
    degrees up, looking at a point between the workpieces and the cameras (a quarter of the
    way to the cameras, horizontally)."""
    part = np.mean([p.T_base_part[:3, 3] for p in cell.workpieces], axis=0)
    cams = np.mean([c.center for c in cell.cameras], axis=0) if cell.cameras else part
    target = part + np.array([0.25 * (cams[0] - part[0]), 0.25 * (cams[1] - part[1]), 0.1])
    up = math.radians(30)
    return target + 3.3 * np.array([math.cos(up), 0.0, math.sin(up)]), target


class ViewApp:
    """``cellsight view`` serving on ``host:port`` (0: any free port).

    Without ``replay``: the cell in ``state`` (:func:`~cellsight.view.states.static_state`;
    default: robots at HOME, parts nominal, grippers open), features coloured by the predictor.
    With
    ``replay``: the run's frames, starting at the frame nearest ``start_time`` (s; default the
    first). Bad joints or part
    names and a busy port are :class:`~cellsight.errors.CellsightError` before anything is
    served.
    """

    def __init__(self, cell: Cell, *, replay: RunReplay | None = None,
                 state: FrameState | None = None, host: str = "127.0.0.1",
                 port: int = 8080, start_time: float | None = None,
                 image_interval: float = IMAGE_INTERVAL_S) -> None:
        self.cell, self.replay = cell, replay
        self._lock = threading.RLock()
        self._last_images: Sequence[np.ndarray] | None = None
        start = 0 if replay is None or start_time is None else replay.frame_at(start_time)
        self.state = (replay.state(start) if replay
                      else state if state is not None else static_state(cell))
        cell.snapshot(self.state.joints, self.state.part_poses, self.state.openings)  # checks
        check_port(host, port)
        with contextlib.redirect_stdout(io.StringIO()):  # viser's banner: we print the URL
            self.server = viser.ViserServer(host=host, port=port, label="cellsight view",
                                            verbose=False)
        if port and self.server.get_port() != port:  # taken between the check and the bind
            self._stop_server()
            raise CellsightError(f"--port: {host}:{port} is already in use")
        self.host, self.port = host, self.server.get_port()
        eye, target = overview_camera(cell)
        self.server.initial_camera.position, self.server.initial_camera.look_at = eye, target
        self.scene = CellScene(self.server, cell)
        self.timeline = None
        if replay is not None:
            self.timeline = Timeline(self.server.gui, replay.t, self.show_frame, start)
        self._gui()
        self.images = CameraImages(replay.run.world_cell() if replay else cell)
        self.worker = ImageWorker(self.images.draw, self._publish, image_interval,
                                  close=self.images.close, on_error=self._image_error)
        self._show(self.state)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def _gui(self) -> None:
        gui, names = self.server.gui, [c.name for c in self.cell.cameras]
        with gui.add_folder("Features"):
            self.camera_choice = gui.add_dropdown(
                "seen by", names, initial_value=names[0],
                hint="the camera whose view colours the feature points: green visible, red "
                     "hidden")
            self.truth_choice = gui.add_checkbox(
                "ray-cast truth", False, disabled=self.replay is None,
                hint="colour by what the simulator's ray casts saw (vis_true) instead of the "
                     "prediction (vis_pred)")
            self.counts = gui.add_markdown("")
        self.camera_choice.on_update(lambda _: self._recolour())
        self.truth_choice.on_update(lambda _: self._recolour())
        with gui.add_folder("Cameras"):
            self.in_frustums = gui.add_checkbox("images in frustums", True)
            self.status = gui.add_markdown("")
            self.gui_images = [
                gui.add_image(np.zeros((cam.height, cam.width, 3), np.uint8), label=cam.name,
                              format="jpeg", jpeg_quality=85)
                for cam in self.cell.cameras]
        self.in_frustums.on_update(lambda _: self._toggle_frustum_images())

    @property
    def camera(self) -> int:
        return [c.name for c in self.cell.cameras].index(self.camera_choice.value)

    def show_frame(self, k: int) -> None:
        """Show frame ``k`` of the run: the scene now, the camera images when the worker gets
        to it."""
        assert self.replay is not None
        self._show(self.replay.state(k))

    def _show(self, state: FrameState) -> None:
        with self._lock:
            self.state = state
            self.scene.show(state, self.camera, self.truth_choice.value)
            self._caption()
        self.worker.request(state)

    def _recolour(self) -> None:
        with self._lock:
            self.scene.colour_features(self.state, self.camera, self.truth_choice.value)
            self._caption()

    def _caption(self) -> None:
        truth = self.truth_choice.value and self.replay is not None
        lines = []
        for part, feats in self.state.features.items():
            seen = [int(feats.colour_mask(c, truth).sum()) for c in range(len(self.cell.cameras))]
            lines.append(f"**{part}** ({'ray-cast truth' if truth else 'predicted'}): " + ", ".join(
                f"{cam.name} sees {n}/{feats.visible.shape[1]}"
                for cam, n in zip(self.cell.cameras, seen, strict=True)))
        self.counts.content = "  \n".join(lines)
        if self.timeline is not None:
            estimate = "shown (magenta)" if self.state.estimates else "none"
            self.timeline.caption.content = f"{self.state.caption}  \nestimate: {estimate}"

    def _publish(self, images: Sequence[np.ndarray], state: FrameState) -> None:
        with self.server.atomic():
            for handle, image in zip(self.gui_images, images, strict=True):
                handle.image = image
            if self.in_frustums.value:
                self.scene.set_images(images)
        self._last_images = images
        self.status.content = f"images: {state.caption}"

    def _toggle_frustum_images(self) -> None:
        images = self._last_images
        for handle in self.scene.frustums:
            handle.image = None
        if self.in_frustums.value and images is not None:
            self.scene.set_images(images)

    def _image_error(self, exc: BaseException) -> None:
        text = f"camera images unavailable: {type(exc).__name__}: {exc}"
        self.status.content = text
        print(f"cellsight view: {text}", file=sys.stderr)

    def close(self) -> None:
        if self.timeline is not None:
            self.timeline.stop()
        self.worker.stop()
        self._stop_server()

    def _stop_server(self) -> None:
        with contextlib.redirect_stdout(io.StringIO()):  # viser's "Server stopped"
            self.server.stop()
