"""The frames.csv schema (cellsight.runfolder.framelog): the exact format of the files already
written (header, quoting, empty fields), rows written and read back with the same values, the 0/1
coding, and a cut-off last line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cellsight.errors import CellsightError
from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.rates import VISION_HZ
from cellsight.runfolder.framelog import (
    POSE,
    FrameLog,
    FrameWriter,
    camera_column,
    columns,
    decode_bits,
    decode_corners,
    decode_windows,
    encode_bits,
    encode_corners,
    encode_labels,
    encode_windows,
    pose_fields,
    timing_fields,
)
from cellsight.tracking.timing import STAGES

# The header of the runs written before the schema had its own module: the format may not
# change (strings and missing values quoted, numbers not); columns are only added (the health
# columns nis, notfound, rejfrac after err_px, then the unknown-occluder map, the windows and
# the corners, per camera; the cameras' grab time at the end), and files without them still
# read.
OLD_HEADER = (
    '"t","phase","stage","status","true_x","true_y","true_z","true_roll","true_pitch",'
    '"true_yaw","est_x","est_y","est_z","est_roll","est_pitch","est_yaw","pnp_x","pnp_y",'
    '"pnp_z","pnp_roll","pnp_pitch","pnp_yaw","gripper_x","gripper_y","gripper_z",'
    '"jaw_opening","jaws_closed","grasped","vis_pred_c1","vis_true_c1","sel_c1","meas_c1",'
    '"rej_c1","wrong_c1","occ_pred_c1","occ_true_c1","grab_c1","err_px_c1","vis_pred_c2",'
    '"vis_true_c2","sel_c2","meas_c2","rej_c2","wrong_c2","occ_pred_c2","occ_true_c2",'
    '"grab_c2","err_px_c2","t_occlusion_ms","t_selection_ms","t_windowing_ms",'
    '"t_extraction_ms","t_ekf_ms","t_total_ms"'
)
HEADER = OLD_HEADER.replace(
    '"err_px_c1",', '"err_px_c1","nis_c1","notfound_c1","rejfrac_c1","unknown_c1",'
    '"windows_c1","corners_c1","held_out_c1",').replace(
    '"err_px_c2",', '"err_px_c2","nis_c2","notfound_c2","rejfrac_c2","unknown_c2",'
    '"windows_c2","corners_c2","held_out_c2",'
) + ',"t_grab_ms"'
F = 16


def _old_style_row() -> dict:
    """A row as the runner writes it: Python and numpy numbers, strings, None."""
    row: dict[str, object] = {"t": 0.078, "phase": "waiting", "stage": "start",
                              "status": "tracking"}
    row.update(dict(zip([f"true_{a}" for a in POSE], [0.55, 0.0, 0.62, 0.0, 0.0, 0.35],
                        strict=True)))
    row.update({"gripper_x": np.float64(0.5398199451773269), "gripper_y": -0.15,
                "gripper_z": 0.8, "jaw_opening": 0.09, "jaws_closed": 0, "grasped": 1})
    for c in (1, 2):
        mask = np.array([False] + [True] * (F - 1))
        row.update({camera_column("vis_pred", c): encode_bits(mask),
                    camera_column("occ_pred", c): encode_labels(["self"] + [""] * (F - 1)),
                    camera_column("grab", c): 0.07347276475694445,
                    camera_column("err_px", c): None})
    row.update(timing_fields(dict.fromkeys(STAGES, 0.0012345678)))
    return row


def test_the_format_is_that_of_the_runs_already_written(tmp_path: Path):
    path = tmp_path / "frames.csv"
    with FrameWriter(path, 2) as writer:
        writer.write(_old_style_row())
    header, line = path.read_text().splitlines()
    assert header == HEADER and columns(2) == [h.strip('"') for h in HEADER.split(",")]
    flags = '"0' + "1" * (F - 1) + '"'
    labels = '"self' + ";" * (F - 1) + '"'
    camera = f'{flags},"","","","","",{labels},"",0.07347276475694445,"","","","","","","","",'
    assert line == ('0.078,"waiting","start","tracking",0.55,0.0,0.62,0.0,0.0,0.35,'
                    + '"",' * 12 + "0.5398199451773269,-0.15,0.8,0.09,0,1,"
                    + camera * 2 + ",".join(["1.2346"] * len(STAGES)))


def test_windows_and_corners_round_trip():
    features, boxes = np.array([3, 0]), np.array([[10, 20, 30, 40], [0, 1, 2, 3]])
    got_features, got_boxes = decode_windows(encode_windows(features, boxes))
    assert np.array_equal(got_features, features) and np.array_equal(got_boxes, boxes)
    measured = np.full((F, 2), np.nan)
    measured[[2, 7]] = [[101.25, 33.5], [0.0004, 575.9996]]
    back = decode_corners(encode_corners(measured), F)
    assert np.array_equal(np.isnan(back), np.isnan(measured))
    assert np.nanmax(np.abs(back - measured)) <= 5e-4
    assert decode_windows("")[1].shape == (0, 4)
    with pytest.raises(ValueError, match="windows '3 1 2'"):
        decode_windows("3 1 2")
    with pytest.raises(ValueError, match="outside"):
        decode_corners("16 1 2", F)


def test_a_file_without_the_health_columns_reads_them_as_missing(tmp_path: Path):
    path = tmp_path / "frames.csv"
    with FrameWriter(path, 2) as writer:
        writer.write(_old_style_row())
    header, row = path.read_text().splitlines()
    old = [h.strip('"') for h in OLD_HEADER.split(",")]
    kept = [i for i, h in enumerate(h.strip('"') for h in header.split(",")) if h in old]
    path.write_text(OLD_HEADER + "\n" + ",".join(row.split(",")[i] for i in kept) + "\n")
    log = FrameLog.read(path)
    assert log.n == 1 and np.isnan(log.floats("nis_c1")).all()
    assert log.grids("unknown_c1") == [None]
    assert log.text("status") == ["tracking"]


def test_rows_read_back_with_the_values_written(tmp_path: Path):
    rng = np.random.default_rng(3)
    path = tmp_path / "frames.csv"
    written = []
    with FrameWriter(path, 3) as writer:
        for k in range(7):
            T = pose_from_xyz_rpy(rng.uniform(-1, 1, 3), rng.uniform(-3, 3, 3))
            bits = rng.random((3, F)) < 0.5
            labels = [[str(rng.choice(["", "self", "R7AX.gripper", "outside"])) for _ in range(F)]
                      for _ in range(3)]
            row = {"t": k / VISION_HZ, "phase": "approach", "status": "tracking",
                   **pose_fields("true", T), **pose_fields("est", None if k == 2 else T),
                   **timing_fields({s: rng.uniform(0, 0.01) for s in STAGES})}
            for c in range(3):
                row[camera_column("sel", c + 1)] = encode_bits(bits[c])
                row[camera_column("occ_true", c + 1)] = encode_labels(labels[c])
                row[camera_column("grab", c + 1)] = float(rng.random())
            writer.write(row)
            written.append((row, T, bits, labels))
    log = FrameLog.read(path)
    assert log.n == 7 and log.n_cameras == 3 and log.n_features == 0  # no vis_* columns
    np.testing.assert_array_equal(log.floats("t"), [k / VISION_HZ for k in range(7)])
    est = log.poses("est")
    assert np.isnan(est[2]).all() and log.present("est_x").tolist() == [k != 2 for k in range(7)]
    for k, (row, T, bits, labels) in enumerate(written):
        np.testing.assert_array_equal(log.poses("true")[k], [row[f"true_{a}"] for a in POSE])
        if k != 2:
            np.testing.assert_allclose(pose_from_xyz_rpy(est[k, :3], est[k, 3:]), T, atol=1e-12)
        for c in range(3):
            np.testing.assert_array_equal(log.bits(camera_column("sel", c + 1), F)[k], bits[c])
            assert log.labels(camera_column("occ_true", c + 1), F)[k].tolist() == labels[c]
            assert log.floats(camera_column("grab", c + 1))[k] == row[camera_column("grab", c + 1)]
        for s in STAGES:
            assert log.floats(f"t_{s}_ms")[k] == row[f"t_{s}_ms"]
    assert log.text("phase") == ["approach"] * 7 and log.text("stage") == [""] * 7
    assert np.isnan(log.floats("no_such_column")).all()


def test_bits_code_round_trip():
    mask = np.array([0, 1, 1, 0, 0, 0, 1], dtype=bool)
    assert encode_bits(mask) == "0110001"
    np.testing.assert_array_equal(decode_bits(encode_bits(mask)), mask)
    assert decode_bits("").shape == (0,)


def test_a_cut_off_last_row_is_dropped_and_a_missing_file_is_empty(tmp_path: Path):
    path = tmp_path / "frames.csv"
    with FrameWriter(path, 1) as writer:
        writer.write({"t": 0.0, "vis_pred_c1": "0110"})
        writer.write({"t": 0.04, "vis_pred_c1": "0111"})
    with path.open("a") as f:
        f.write('0.08,"approach","s')
    log = FrameLog.read(path)
    assert log.n == 2 and log.n_features == 4
    np.testing.assert_array_equal(log.bits("vis_pred_c1"), [[0, 1, 1, 0], [0, 1, 1, 1]])
    assert FrameLog.read(tmp_path / "absent.csv").n == 0


def test_wrong_columns_and_lengths_are_refused(tmp_path: Path):
    with FrameWriter(tmp_path / "frames.csv", 1) as writer, pytest.raises(KeyError, match="c2"):
        writer.write({"vis_pred_c2": "01"})
    log = FrameLog({"sel_c1": ["011", "01"], "occ_true_c1": ["a;b;c", "a;b"]}, 2)
    with pytest.raises(CellsightError, match="^frames.csv: column 'sel_c1', row 2: 2 flags, "
                                             "expected 3$"):
        log.bits("sel_c1", 3)
    with pytest.raises(CellsightError, match="column 'occ_true_c1', row 2: 2 labels, expected 3"):
        log.labels("occ_true_c1", 3)


@pytest.mark.parametrize("bad", ["abc", "1,5", "0x1p", "--1"])
def test_a_value_that_is_not_a_number_names_the_file_column_and_row(tmp_path: Path, bad: str):
    path = tmp_path / "frames.csv"
    path.write_text("t,true_x\n0.0,1.5\n0.04," + ('"1,5"' if "," in bad else bad) + "\n0.08,\n")
    log = FrameLog.read(path)
    np.testing.assert_array_equal(log.floats("t"), [0.0, 0.04, 0.08])
    with pytest.raises(CellsightError) as e:
        log.floats("true_x")
    assert str(e.value) == (f"{path}: column 'true_x', row 2: {bad!r} is not a number (edited "
                            f"by hand, or not a cellsight run's frames.csv?)")


def test_a_header_that_cannot_be_written_leaves_no_file_open(tmp_path: Path, monkeypatch):
    """A full disk at the header: one WriteError naming frames.csv, and the file it opened is
    closed (no writer exists to close it; the fuzz run's write failures kept such files open)."""
    import csv
    import errno

    from cellsight.runfolder.framelog import FrameWriter
    from cellsight.runfolder.writes import WriteError

    opened = []
    real_open = Path.open

    def tracked(self, *args, **kwargs):
        opened.append(real_open(self, *args, **kwargs))
        return opened[-1]

    def full(self):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "open", tracked)
    monkeypatch.setattr(csv.DictWriter, "writeheader", full)
    with pytest.raises(WriteError, match="frames.csv"):
        FrameWriter(tmp_path / "frames.csv", 2)
    assert len(opened) == 1 and opened[0].closed
