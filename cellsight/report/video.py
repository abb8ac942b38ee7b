"""H.264 MP4 writer for the camera-view animation, robust to interrupted runs.

Frames are piped to ffmpeg (the binary bundled with ``imageio-ffmpeg``) as RGB24 and encoded
with libx264 / yuv420p into a *fragmented* MP4 (``-movflags frag_keyframe+empty_moov``, a
keyframe every two seconds): every finished fragment is playable on its own, so a run killed
mid-way still leaves a file that plays up to its last fragment.

ffmpeg is started here, not by ``imageio_ffmpeg.write_frames``: that one keeps the terminal's
Ctrl-C from ffmpeg by a ``preexec_fn``, which makes Python start the child by a real
``fork()``, and a fork runs the BLAS's fork handler, which waits for a matrix product another
thread of the run has in hand while that product waits for the handler: a run hung so, once.
Here ffmpeg gets a session of its own (``start_new_session``: Ctrl-C reaches only cellsight,
which ends the file itself), which Python starts without running fork handlers. ffmpeg's own
messages go to a temporary file, not the terminal, and a failure to finish the file (ffmpeg's
exit code) is raised with its last lines.
"""

from __future__ import annotations

import errno
import subprocess
import tempfile
from contextlib import suppress
from fractions import Fraction
from pathlib import Path
from types import TracebackType

import numpy as np


class VideoWriter:
    """Append RGB frames to an MP4 file; the frame size is fixed by the first frame.

    ``path``: output file (parent folders created). ``fps``: frames per second of the video.
    ``crf``: x264 constant rate factor (0 lossless .. 51 worst; 28 gives small files that are
    still readable). Frame sizes should be even (see
    :func:`cellsight.report.overlay.compose_views`); odd sizes are scaled up by ffmpeg.
    Use as a context manager or call :meth:`close`; a write or a close that ffmpeg fails
    raises :class:`OSError` naming the file and ffmpeg's last messages.
    """

    def __init__(self, path: Path | str, fps: float, crf: int = 28) -> None:
        self.path = Path(path)
        self.fps = float(fps)
        self.crf = int(crf)
        self.frames = 0
        self._size: tuple[int, int] | None = None  # (W, H) px
        self._process: subprocess.Popen | None = None
        self._log = None  # ffmpeg's stderr, a temporary file

    def _command(self, size: tuple[int, int]) -> list[str]:
        """ffmpeg's command line for frames of ``size = (W, H)`` px."""
        import imageio_ffmpeg  # the bundled ffmpeg binary: loaded only when a video is written

        width, height = size
        gop = max(1, int(round(2.0 * self.fps)))
        even = [] if width % 2 == 0 and height % 2 == 0 else [
            "-vf", f"scale={width + width % 2}:{height + height % 2}"]
        return [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-nostdin", "-v", "error",
                "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}",
                "-r", str(Fraction(self.fps).limit_denominator()), "-i", "-", "-an",
                "-vcodec", "libx264", "-pix_fmt", "yuv420p", *even,
                "-crf", str(self.crf), "-preset", "veryfast", "-g", str(gop),
                "-movflags", "frag_keyframe+empty_moov", str(self.path)]

    def _open(self, size: tuple[int, int]) -> None:
        """Start ffmpeg for frames of ``size = (W, H)`` px."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._log = tempfile.TemporaryFile()
        self._process = subprocess.Popen(self._command(size), stdin=subprocess.PIPE,
                                         stdout=subprocess.DEVNULL, stderr=self._log,
                                         start_new_session=True)
        self._size = size

    def add(self, rgb: np.ndarray) -> None:
        """Append one (H, W, 3) uint8 RGB frame; every frame must have the first one's size."""
        frame = np.ascontiguousarray(rgb, dtype=np.uint8)
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"expected an (H, W, 3) RGB frame, got shape {frame.shape}")
        size = (frame.shape[1], frame.shape[0])
        if self._process is None:
            self._open(size)
        elif size != self._size:
            raise ValueError(f"frame size {size} differs from the video's {self._size} (W, H)")
        try:
            self._process.stdin.write(frame.data)
        except BrokenPipeError as exc:  # ffmpeg is gone: say why
            raise self._finish() or OSError(errno.EPIPE, "ffmpeg is gone", str(self.path)) \
                from exc
        self.frames += 1

    def close(self) -> None:
        """Finish the file (flushes ffmpeg and waits for it); safe to call twice or without
        frames. Raises :class:`OSError` when ffmpeg could not finish it."""
        if (failure := self._finish()) is not None:
            raise failure

    def _finish(self) -> OSError | None:
        """End ffmpeg's input and wait for it; returns its failure, if it failed."""
        process, self._process = self._process, None
        if process is None:
            return None
        try:
            with suppress(BrokenPipeError):  # ffmpeg already gone: its exit code says why
                process.stdin.close()
            process.wait()
        except BaseException:  # interrupted while waiting: do not leave ffmpeg behind
            process.kill()
            process.wait()
            raise
        finally:
            failure = self._failure(process.returncode) if process.returncode else None
            self._log.close()
        return failure

    def _failure(self, code: int | None) -> OSError:
        """ffmpeg's exit ``code`` and its last two lines, as the error of writing the file."""
        self._log.seek(0)
        lines = self._log.read().decode(errors="replace").strip().splitlines()
        why = "; ".join(line.strip() for line in lines[-2:]) or "no message"
        return OSError(errno.EIO, f"ffmpeg ended with exit code {code}: {why}", str(self.path))

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
