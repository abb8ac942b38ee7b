"""SIGINT and SIGTERM during a run: the run ends at the next frame boundary, its files
whole."""

from __future__ import annotations

import signal
import threading


class StopSignals:
    """SIGINT and SIGTERM while a run holds them (a context manager): the first one only
    records its name (:attr:`name`) for the loop to stop at the next frame boundary; later ones
    are ignored, so that the final writing (metrics, report) is never cut. The previous
    handlers come back on exit. Python sets handlers only in the main thread; elsewhere
    nothing is installed and the signals act as before."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.name: str | None = None
        self._previous: dict[int, object] = {}

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self._record)
        return self

    def _record(self, signum: int, frame: object) -> None:
        if self.name is None:
            self.name = signal.Signals(signum).name

    def __exit__(self, *exc_info: object) -> None:
        for sig, previous in self._previous.items():
            signal.signal(sig, signal.SIG_DFL if previous is None else previous)
        self._previous.clear()
