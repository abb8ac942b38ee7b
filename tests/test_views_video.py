"""``views.mp4`` drawn on a thread of its own (:mod:`cellsight.experiments.views_video`): the
pictures are those the run's own thread draws from the same shots and records when it hands
them over, in order, one every ``video_every`` frames; a failure there ends the run as a failed
write of the video does, naming the file."""

from __future__ import annotations

import errno
import os
import threading
from pathlib import Path

import numpy as np
import pytest

from cellsight.cli import main
from cellsight.experiments import views_video
from cellsight.experiments.keyframes import draw_frame
from cellsight.experiments.runner import RunConfig, run_experiment
from cellsight.report.video import VideoWriter
from cellsight.runfolder import finished_metrics, read_metrics
from cellsight.runfolder.framelog import FrameLog
from cellsight.world.shots import Shot


@pytest.mark.slow
def test_the_video_thread_draws_what_the_run_handed_over(tmp_path: Path, monkeypatch) -> None:
    """The oracle: each picture drawn again on the run's thread as the frame is handed over,
    with a renderer of its own (the same settings as the thread's). A thread that drew from a
    later state, lost or reordered a frame, or rendered with the run's contexts would differ."""
    handed: list[np.ndarray] = []
    written: list[tuple[np.ndarray, str]] = []
    renderers = {}
    real_add = views_video.ViewsVideo.add

    def add(self, shown, frame, part, truth_visible, caption) -> None:
        shot = next(s for s in shown if isinstance(s, Shot))
        if "r" not in renderers:
            renderers["r"] = shot.renderer.twin(samples=0)
        images = [s.preview(0.5, renderers["r"]) for s in shown]
        handed.append(draw_frame(images, frame, part, truth_visible, self._cameras,
                                 caption, 0.5))
        real_add(self, shown, frame, part, truth_visible, caption)

    def record(self, rgb) -> None:
        written.append((np.array(rgb), threading.current_thread().name))

    monkeypatch.setattr(views_video.ViewsVideo, "add", add)
    monkeypatch.setattr(VideoWriter, "add", record)
    try:
        metrics = run_experiment(RunConfig(3, tmp_path / "run", duration=1.0, progress=False,
                                           video_every=3))
    finally:
        if "r" in renderers:
            renderers["r"].close()
    assert len(written) == len(handed) == -(-metrics["frames"] // 3) > 5
    assert {name for _, name in written} == {"views-video"}
    for (picture, _), expected in zip(written, handed, strict=True):
        assert np.array_equal(picture, expected)
    # the frames differ (the run moves), so an order mixed up would not pass
    assert not np.array_equal(written[0][0], written[-1][0])


def test_a_video_that_cannot_be_written_fails_the_run_naming_it(tmp_path: Path, monkeypatch,
                                                                capsys) -> None:
    """A full disk under ffmpeg at the third picture: raised on the run's thread at its next
    frame, recorded in metrics.json, and the rows written before are kept."""
    full = os.strerror(errno.ENOSPC)
    real_add, sent = VideoWriter.add, []

    def add(self, rgb) -> None:
        sent.append(1)
        if len(sent) >= 3:
            raise OSError(errno.ENOSPC, full)
        real_add(self, rgb)

    monkeypatch.setattr(VideoWriter, "add", add)
    out = tmp_path / "run"
    assert main(["run", "1", "--quiet", "--duration", "1.0", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert f"views.mp4: cannot write it ({full})" in err and "Traceback" not in err
    metrics = read_metrics(out)
    assert f"{out / 'views.mp4'}: cannot write it ({full})" in metrics["error"]
    assert finished_metrics(out) is None
    assert 4 <= metrics["frames"] < 26 and (out / "frames.csv").stat().st_size > 0


def test_no_video_runs_without_one(tmp_path: Path) -> None:
    """``run --no-video``: a rendered run that writes everything but ``views.mp4``."""
    out = tmp_path / "run"
    assert main(["run", "1", "--quiet", "--duration", "0.5", "--no-video", "--out",
                 str(out)]) == 0
    assert finished_metrics(out)["frames"] >= 13
    assert not (out / "views.mp4").exists() and (out / "report.html").is_file()
    assert "views.mp4" not in (out / "report.html").read_text()


@pytest.mark.slow
def test_the_video_changes_nothing_the_run_measures(tmp_path: Path) -> None:
    """The harsh world drops frames and draws each image's noise from a random stream: the
    video's picture of a dropped frame is rendered anew, and must not draw from it (it did:
    a run with the video and one without parted at the first dropped frame)."""
    rows = {}
    for every in (1, 0):
        out = tmp_path / f"video_{every}"
        metrics = run_experiment(RunConfig(2, out, realism="harsh", seed=2, duration=2.0,
                                           progress=False, video_every=every))
        assert metrics["frames_dropped"] > 0
        rows[every] = FrameLog.read(out / "frames.csv")
    assert (tmp_path / "video_1" / "views.mp4").stat().st_size > 0
    assert rows[1].n == rows[0].n > 40
    for name, values in rows[0].columns.items():
        if not name.endswith("_ms"):
            assert rows[1].text(name) == values, name
