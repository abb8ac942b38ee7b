"""H.264 MP4 writer for the camera-view animation, robust to interrupted runs.

Frames are piped to ffmpeg (the binary bundled with ``imageio-ffmpeg``) as RGB24 and encoded
with libx264 / yuv420p into a *fragmented* MP4 (``-movflags frag_keyframe+empty_moov``, a
keyframe every two seconds): every finished fragment is playable on its own, so a run killed
mid-way still leaves a file that plays up to its last fragment.
"""

from __future__ import annotations

from pathlib import Path
from types import TracebackType

import numpy as np


class VideoWriter:
    """Append RGB frames to an MP4 file; the frame size is fixed by the first frame.

    ``path``: output file (parent folders created). ``fps``: frames per second of the video.
    ``crf``: x264 constant rate factor (0 lossless .. 51 worst; 28 gives small files that are
    still readable). Frame sizes should be even (see
    :func:`cellsight.report.overlay.compose_views`); odd sizes are scaled up by ffmpeg.
    Use as a context manager or call :meth:`close`.
    """

    def __init__(self, path: Path | str, fps: float, crf: int = 28) -> None:
        self.path = Path(path)
        self.fps = float(fps)
        self.crf = int(crf)
        self.frames = 0
        self._size: tuple[int, int] | None = None  # (W, H) px
        self._writer = None

    def _open(self, size: tuple[int, int]) -> None:
        """Start ffmpeg for frames of ``size = (W, H)`` px."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        gop = max(1, int(round(2.0 * self.fps)))
        import imageio_ffmpeg  # the bundled ffmpeg binary: loaded only when a video is written

        self._writer = imageio_ffmpeg.write_frames(
            str(self.path), size, fps=self.fps, codec="libx264", pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p", quality=None, macro_block_size=2,
            output_params=["-crf", str(self.crf), "-preset", "veryfast", "-g", str(gop),
                           "-movflags", "frag_keyframe+empty_moov"],
        )
        self._writer.send(None)
        self._size = size

    def add(self, rgb: np.ndarray) -> None:
        """Append one (H, W, 3) uint8 RGB frame; every frame must have the first one's size."""
        frame = np.ascontiguousarray(rgb, dtype=np.uint8)
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"expected an (H, W, 3) RGB frame, got shape {frame.shape}")
        size = (frame.shape[1], frame.shape[0])
        if self._writer is None:
            self._open(size)
        elif size != self._size:
            raise ValueError(f"frame size {size} differs from the video's {self._size} (W, H)")
        self._writer.send(frame)
        self.frames += 1

    def close(self) -> None:
        """Finish the file (flushes ffmpeg); safe to call twice or without frames."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
