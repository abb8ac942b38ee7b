"""The timeline of a replayed run (:class:`Timeline`): a frame slider, a play/pause button, a
playback speed and a caption (time, phase, tracker status). Moving the slider, by hand or while
playing, calls ``on_frame(k)``; playback follows the run's own clock, times ``speed``, skipping
frames when a frame's update takes longer than the frames' spacing."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
import viser

SPEEDS = ("0.25x", "0.5x", "1x", "2x", "4x")
PLAY_RATE_HZ = 15.0  # slider steps per second while playing, at most


class Timeline:
    """GUI controls over frames at times ``times`` (s), starting at frame ``start``."""

    def __init__(self, gui: viser.GuiApi, times: np.ndarray, on_frame: Callable[[int], None],
                 start: int = 0) -> None:
        self.times = np.asarray(times, dtype=float)
        self.n = len(self.times)
        self._on_frame = on_frame
        self._playing = threading.Event()
        self._lock = threading.Lock()  # one frame change at a time, always to the latest value
        self._thread: threading.Thread | None = None
        with gui.add_folder("Timeline"):
            self.caption = gui.add_markdown("")
            self.slider = gui.add_slider("frame", 0, max(self.n - 1, 1), 1, self.clamp(start),
                                         hint="the run's vision frames, from 0")
            self.button = gui.add_button("Play", icon=viser.Icon.PLAYER_PLAY,
                                         hint="play or pause the replay")
            self.speed = gui.add_dropdown("speed", SPEEDS, initial_value="1x",
                                          hint="playback speed")
        self.slider.on_update(lambda _: self._changed())
        self.button.on_click(lambda _: self.toggle())

    def _changed(self) -> None:
        """The slider moved (callbacks may run on several threads, in any order): show the
        frame it is on now."""
        with self._lock:
            self._on_frame(self.frame)

    def clamp(self, k: float) -> int:
        return int(min(max(round(k), 0), self.n - 1))

    @property
    def frame(self) -> int:
        """The frame the slider is on."""
        return self.clamp(self.slider.value)

    @property
    def playing(self) -> bool:
        return self._playing.is_set()

    def toggle(self) -> None:
        """Play from the slider's frame (from the start when at the end), or pause."""
        if self.playing:
            self.pause()
            return
        if self.frame >= self.n - 1:
            self.slider.value = 0
        self._playing.set()
        self.button.label, self.button.icon = "Pause", viser.Icon.PLAYER_PAUSE
        self._thread = threading.Thread(target=self._play, name="cellsight-view-play",
                                        daemon=True)
        self._thread.start()

    def pause(self) -> None:
        self._playing.clear()
        self.button.label, self.button.icon = "Play", viser.Icon.PLAYER_PLAY

    def _play(self) -> None:
        """Move the slider along the run's clock until the end, a pause or a stop; a slider
        moved by hand meanwhile restarts the clock from there."""
        anchor_wall, anchor_frame, shown = time.monotonic(), self.frame, self.frame
        while self._playing.is_set():
            if self.frame != shown:  # moved by hand
                anchor_wall, anchor_frame = time.monotonic(), self.frame
            speed = float(self.speed.value.rstrip("x"))
            t = self.times[anchor_frame] + (time.monotonic() - anchor_wall) * speed
            shown = self.clamp(np.searchsorted(self.times, t, side="right") - 1)
            self.slider.value = shown
            if shown >= self.n - 1:
                break
            time.sleep(1.0 / PLAY_RATE_HZ)
        if self._playing.is_set():
            self.pause()

    def stop(self) -> None:
        self._playing.clear()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
