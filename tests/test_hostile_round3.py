"""Hostile input, third round (issue 59): refusals that come before the work, naming the option
and the value: an ``--mcap`` that cannot be written (under /proc), ``ik --seeds`` past its
bound; the refusal leaves nothing behind (the output folders are not created)."""

from __future__ import annotations

import time

import pytest

from cellsight.cli import main
from cellsight.commands.ik import MAX_SEEDS
from cellsight.errors import CellsightError
from cellsight.export.rosbag import check_output

PART = '{"part": {"xyz": [0.6, -0.15, 0.79], "rpy": [0, 0, 0.15]}}'


@pytest.mark.parametrize("where", ["/proc/cellsight.mcap", "/proc/self/new/run.mcap"])
def test_an_mcap_that_cannot_be_written_is_refused_before_the_work(where, tmp_path):
    with pytest.raises(CellsightError, match=r"^--mcap: cannot write under '/proc"):
        check_output(where, False, tmp_path / "run")


def test_a_writable_mcap_folder_is_left_as_it_was(tmp_path):
    before = sorted(tmp_path.iterdir())
    assert check_output(tmp_path / "new" / "run.mcap", False, tmp_path / "run") == (
        tmp_path / "new" / "run.mcap")
    assert sorted(tmp_path.iterdir()) == before  # no probe file, no folder made


def test_track_refuses_an_unwritable_mcap_before_tracking(tmp_path, capsys):
    out = tmp_path / "tracked"
    start = time.monotonic()
    code = main(["track", str(tmp_path / "absent.mcap"), "--out", str(out),
                 "--mcap", "/proc/cellsight.mcap"])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists() and time.monotonic() - start < 30
    assert "--mcap: cannot write under '/proc'" in err  # before the recording is even opened


@pytest.mark.parametrize("seeds", [MAX_SEEDS + 1, 10**9])
def test_ik_seeds_past_the_bound_are_refused_at_once(seeds, capsys):
    start = time.monotonic()
    assert main(["ik", "--part-pose", PART, "--seeds", str(seeds)]) == 2
    assert time.monotonic() - start < 10
    assert (f"--seeds: expected a whole number from 0 to {MAX_SEEDS} (about 30 ms each), "
            f"got {seeds}") in capsys.readouterr().err



def test_ik_names_a_redundant_arms_solutions_by_their_start(capsys):
    """A 7-axis arm has no branch flags: each row is named by the start that found it (HOME,
    middle, FINAL, random k), not "seed HOME" or "seed seed 17"."""
    part = '{"part": {"xyz": [0.6, -0.15, 0.79], "rpy": [0, 0, 0.35]}}'
    assert main(["ik", "--cell", "iiwa-cell", "--part-pose", part, "--seeds", "4"]) == 0
    starts = [line.split("│")[1].strip() for line in capsys.readouterr().out.splitlines()
              if line.startswith("│")]
    starts = [s for s in starts if s]  # not a wrapped row's continuation
    assert starts and "HOME" in starts and not any(s.startswith("seed") for s in starts)
    assert all(s in ("HOME", "middle", "FINAL") or s.startswith("random ") for s in starts)


def test_a_run_says_what_ended_it(tmp_path, capsys):
    """The time limit is named when it ends a run with the task not done, and the run's
    printed result says it (with the phase the task stopped in)."""
    from cellsight.experiments import RunConfig, run_experiment

    metrics = run_experiment(RunConfig(2, tmp_path / "limit", sensor="ideal", max_duration=3.0,
                                       progress=False, video_every=0))
    assert metrics["ended_by"] == "the time limit (3 s) with the task not done"
    assert metrics["final_phase"] == "waiting" and metrics["last_setback"] is None
    assert main(["run", "2", "--sensor", "ideal", "--duration", "2", "--quiet", "--out",
                 str(tmp_path / "short")]) == 0
    assert "ended by --duration 2 s; the task waiting" in " ".join(
        capsys.readouterr().out.split())


# ---- found by make fuzz's run_folder, recording and sweep_resume kinds (tests/fuzz_inputs.py)

def _answers_within(seconds: float, call):
    """``call()``'s exception (or None), from a daemon thread; a call still blocked after
    ``seconds`` fails the test instead of hanging it."""
    import threading

    caught: list[BaseException | None] = []

    def target():
        try:
            call()
            caught.append(None)
        except BaseException as exc:  # noqa: BLE001 - handed back to the test
            caught.append(exc)

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"still blocked after {seconds} s"
    return caught[0]


@pytest.mark.parametrize("name", ["metrics.json", "frames.csv", "run_cell.yaml"])
def test_a_fifo_in_a_run_folder_is_refused_without_waiting_for_a_writer(tmp_path, name):
    """A FIFO where a run's file should be: read back (metrics, frames, the digests of the
    frames and the kept cell), it is refused at once, naming the file, not read for ever."""
    import os

    from cellsight.runfolder import FrameLog, read_metrics
    from cellsight.runfolder.digest import file_digest

    fifo = tmp_path / name
    os.mkfifo(fifo)
    assert _answers_within(10, lambda: file_digest(fifo)) is None
    assert file_digest(fifo) is None  # not a readable file: the run's digest no longer matches
    read = read_metrics if name == "metrics.json" else lambda folder: FrameLog.read(fifo)
    error = _answers_within(10, lambda: read(tmp_path))
    assert isinstance(error, CellsightError)
    assert f"{fifo}: not a regular file (a folder, a FIFO or a device)" in str(error)


@pytest.mark.parametrize("content, wanted", [
    (b"t,x\n0.0,\xff\xfe\n", "not UTF-8 text"),
    (b"t,x\n0.0," + b"9" * 200_000 + b"\n", "field larger than field limit"),
])
def test_a_frames_file_that_is_no_csv_text_is_one_error_naming_it(tmp_path, content, wanted):
    """frames.csv read without its digest (a run from before it, or metrics.json edited):
    bytes that are not UTF-8, a field past the csv module's limit: one CellsightError naming
    the file, not a UnicodeDecodeError or a csv.Error."""
    from cellsight.runfolder import FrameLog

    frames = tmp_path / "frames.csv"
    frames.write_bytes(content)
    with pytest.raises(CellsightError, match=rf"^{frames}: .*{wanted}"):
        FrameLog.read(frames)


def test_a_topic_of_two_message_types_is_refused_when_the_recording_is_opened(tmp_path):
    """Joint states written on a camera's image topic beside its images: refused at open,
    naming the topic and both types (its messages were read as images and failed with an
    AttributeError)."""
    import numpy as np
    from recordings import STORE, T
    from rosbags.rosbag2 import StoragePlugin, Writer

    from cellsight.recording.reader import RecordingError, open_recording

    time = T["builtin_interfaces/msg/Time"](sec=1, nanosec=0)
    header = T["std_msgs/msg/Header"](stamp=time, frame_id="cam1")
    image = T["sensor_msgs/msg/Image"](header=header, height=1, width=1, encoding="mono8",
                                       is_bigendian=0, step=1, data=np.zeros(1, np.uint8))
    joints = T["sensor_msgs/msg/JointState"](header=header, name=["a"],
                                             position=np.zeros(1), velocity=np.zeros(0),
                                             effort=np.zeros(0))
    for storage in (StoragePlugin.MCAP, StoragePlugin.SQLITE3):
        bag = tmp_path / storage.name
        with Writer(bag, version=8, storage_plugin=storage) as writer:
            for kind, msg in (("sensor_msgs/msg/Image", image),
                              ("sensor_msgs/msg/JointState", joints)):
                connection = writer.add_connection("/cam1/image_raw", kind, typestore=STORE)
                writer.write(connection, 10**9, STORE.serialize_cdr(msg, kind))
        for path in (bag, *bag.glob("*.mcap")):  # the folder, and its MCAP file alone
            if path.suffix == ".mcap":
                path = path.rename(tmp_path / f"{storage.name}.mcap")
            with pytest.raises(RecordingError, match=r"topic /cam1/image_raw holds messages of "
                               r"two types \(sensor_msgs/msg/Image and sensor_msgs/msg/Joint"):
                open_recording(path)


def test_a_message_whose_type_the_recording_defines_otherwise_names_the_field(tmp_path):
    """An MCAP file whose schema of sensor_msgs/msg/CameraInfo is not ROS 2's (a damaged
    byte made 'distortion_model' another name): its messages are refused, naming the topic,
    the message and the field, not read until an AttributeError."""
    from mcap_ros2.writer import Writer

    from cellsight.recording.reader import RecordingError, misfit, open_recording

    damaged = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_modem\n"
               "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n"
               "uint32 binning_y\nRegionOfInterest roi\n"
               "================================================================================\n"
               "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
               "================================================================================\n"
               "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
               "================================================================================\n"
               "MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\n"
               "uint32 height\nuint32 width\nbool do_rectify\n")
    path = tmp_path / "damaged.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        schema = writer.register_msgdef("sensor_msgs/msg/CameraInfo", damaged)
        writer.write_message("/cam1/camera_info", schema, {
            "header": {"stamp": {"sec": 1, "nanosec": 0}, "frame_id": "cam1"}, "height": 576,
            "width": 768, "distortion_modem": "plumb_bob", "d": [0.0] * 5, "k": [1.0] * 9,
            "r": [0.0] * 9, "p": [0.0] * 12, "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0,
                    "do_rectify": False}}, log_time=10**9)
        writer.finish()
    with open_recording(path) as recording, pytest.raises(
            RecordingError, match=r"/cam1/camera_info, message 1: no field 'distortion_model': "
                                  r"not a sensor_msgs/msg/CameraInfo as ROS 2 defines it"):
        list(recording.messages(["/cam1/camera_info"]))
    assert misfit("no/such/Type", object()) is None


def test_a_sweep_does_not_run_again_into_a_run_folder_linked_outside_its_out(tmp_path):
    """A run folder of a sweep's --out that is a link to a folder elsewhere: a run to do
    again there fails with one line naming the link (the sweep goes on) and the folder it
    leads to is left as it was (it was cleared and written through the link)."""
    from cellsight.sweep.grid import RunSpec, run_spec

    spec = RunSpec("dual-arm", 1, "ideal", "kinematic", 0, 0.2)
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "frames.csv").write_text("an earlier run's frames\n")
    (out / spec.folder).parent.mkdir(parents=True)
    (out / spec.folder).symlink_to(elsewhere)
    result = run_spec((spec, out))
    assert result["error"].startswith(f"RunFolderError: --out: '{out / spec.folder}' leads to "
                                      f"'{elsewhere}', outside '{out}' (a link)")
    assert [p.name for p in elsewhere.iterdir()] == ["frames.csv"]
    assert (elsewhere / "frames.csv").read_text() == "an earlier run's frames\n"


def test_images_far_apart_are_refused_not_filled_with_empty_frames_for_ever(tmp_path):
    """An image stamped in 2038 after images a frame apart: one RecordingError naming the gap,
    not ~5e10 empty frames (prediction steps) filling it, one after the other."""
    from types import SimpleNamespace as NS

    from cellsight import load_cell
    from cellsight.recording.frames import MAX_GAP_S, FrameGrouper, Topics
    from cellsight.recording.names import IMAGE
    from cellsight.recording.reader import RecordingError

    camera = load_cell().cameras[0]
    stamps = [(100, k * 40_000_000) for k in range(6)] + [(2**31 - 1, 0)]

    class Recording:
        path = tmp_path / "rec.mcap"

        def messages(self, topics):
            for sec, nanosec in stamps:
                yield "/cam1/image_raw", sec * 10**9 + nanosec, NS(
                    header=NS(stamp=NS(sec=sec, nanosec=nanosec), frame_id="cam1"),
                    height=camera.height, width=camera.width, encoding="mono8", is_bigendian=0,
                    step=camera.width, data=bytes(camera.width * camera.height))

    grouper = FrameGrouper(Recording(), [camera], Topics([("/cam1/image_raw", IMAGE)], [None],
                                                         {}), 0.019, 100 * 10**9)
    with pytest.raises(RecordingError, match=rf"no images from 0.200 s to 2147483547.000 s, "
                                             rf".* s \(more than {MAX_GAP_S:g} s\)"):
        for _ in zip(range(1000), grouper.frames(), strict=False):
            pass


def test_a_schema_the_decoder_cannot_parse_is_one_error_and_nothing_else_on_stderr(
        tmp_path, capsys):
    """A damaged schema text (a byte flipped in 'uint32 height'): the MCAP decoder prints the
    bad line to stderr before it raises; the recording's error is the one line, alone."""
    from mcap.writer import Writer

    from cellsight.recording.reader import RecordingError, open_recording

    path = tmp_path / "damaged.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2")
        schema = writer.register_schema("sensor_msgs/msg/RegionOfInterest", "ros2msg",
                                        b"uint32 x_offset\nuint32(height\n")
        channel = writer.register_channel("/roi", "cdr", schema)
        writer.add_message(channel, log_time=10**9, data=bytes(12), publish_time=10**9)
        writer.finish()
    capsys.readouterr()
    with open_recording(path) as recording, pytest.raises(
            RecordingError, match=r"damaged after 0 messages of /roi \(InvalidFieldDefinition"):
        list(recording.messages(["/roi"]))
    assert capsys.readouterr().err == ""
