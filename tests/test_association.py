"""Data association at acquisition (:mod:`cellsight.tracking.acquire`): a fix of one part where
another track holds its part is that part's, and refused; elsewhere it stands.

Oracles: the line cell's own parts (a U prism and an L prism) placed by hand: on top of a
tracked twin (the search's typical wrong find), touching it side by side (the closest two real
parts lie), and far apart.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight import load_cell
from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.tracking.acquire import Acquirer
from cellsight.tracking.eligibility import NearOccluderHold
from cellsight.tracking.part_track import PartTrack


@pytest.fixture(scope="module")
def line():
    return load_cell("line-cell")


def _track(points: np.ndarray, pose: np.ndarray | None = None, lost: bool = False) -> PartTrack:
    track = PartTrack(points, None, NearOccluderHold(0.0), monitor=None)
    track.ekf = None if pose is None else SimpleNamespace(pose=pose)
    track.lost = lost
    return track


def _fits(tracks: dict[str, PartTrack], name: str, T: np.ndarray) -> bool:
    acquirer = Acquirer(SimpleNamespace(tracks=tracks))
    return acquirer.fits(SimpleNamespace(rec=SimpleNamespace(name=name), track=tracks[name],
                                         t=0.0), T)


@settings(max_examples=40, deadline=None)
@given(dx=st.floats(-0.015, 0.015), dy=st.floats(-0.015, 0.015),
       turn=st.floats(-np.pi, np.pi), twin=st.sampled_from(["u1", "l1"]))
def test_a_fix_on_a_tracked_part_is_that_part_s(line, dx, dy, turn, twin):
    """A fix of u3 within 15 mm of where u1 (or l1) is tracked, turned any way, is refused."""
    other = line.workpiece(twin)
    T_other = other.T_base_part
    tracks = {twin: _track(other.feature_points, T_other),
              "u3": _track(line.workpiece("u3").feature_points)}
    fix = T_other @ pose_from_xyz_rpy([dx, dy, 0.0], [0.0, 0.0, turn])
    assert not _fits(tracks, "u3", fix)


@pytest.mark.parametrize("gap_m, stands", [(0.0, False), (0.06, True), (0.2, True)])
def test_parts_side_by_side_are_two_parts(line, gap_m, stands):
    """Two U prisms (10 x 6 cm) side by side, 6 cm apart across their long sides, touch: both
    stand; on top of each other, the second is refused."""
    u = line.workpiece("u3").feature_points
    T = pose_from_xyz_rpy([0.5, 0.1, 0.62], [0.0, 0.0, 0.0])
    tracks = {"u1": _track(u, T), "u3": _track(u)}
    beside = T @ pose_from_xyz_rpy([0.0, gap_m, 0.0], [0.0, 0.0, 0.0])
    assert _fits(tracks, "u3", beside) is stands


@pytest.mark.parametrize("state", ["lost", "waiting", "itself"])
def test_only_a_held_place_refuses(line, state):
    """A lost track's or a waiting one's place claims nothing, nor does a part's own."""
    u = line.workpiece("u3").feature_points
    T = line.workpiece("u1").T_base_part
    if state == "itself":
        tracks = {"u3": _track(u, T)}
    else:
        tracks = {"u1": _track(u, T if state == "lost" else None, lost=state == "lost"),
                  "u3": _track(u)}
    assert _fits(tracks, "u3", T)


@pytest.mark.parametrize("where, acquired, expected", [
    ("u1", False, "every_s"), ("u3", False, "out_of_view_every_s"),
    ("u1", True, "every_s"), ("u3", True, None)])
def test_a_part_is_searched_for_while_it_may_come_in_and_not_after_it_left(line, where,
                                                                          acquired, expected):
    """On the line: a part waiting at u1's place (in view) is searched for every 0.2 s, at u3's
    (upstream, out of every view) once a second; one lost there after it was tracked left the
    views, and is not searched for."""
    from cellsight.tracking.search import PlaneSearch

    search = PlaneSearch()
    T = line.workpiece(where).T_base_part
    track = _track(line.workpiece("u3").feature_points, T if acquired else None, lost=acquired)
    track.guess = T
    acquirer = Acquirer(SimpleNamespace(tracks={"u3": track}, cameras=line.cameras))
    every = acquirer.search_every(track, search)
    assert every == (None if expected is None else getattr(search, expected))


@pytest.mark.parametrize("travel", [None, (2.0, 0.0)])
def test_a_part_waiting_upstream_is_looked_for_where_it_would_come_into_the_views(line, travel):
    """u3 waits 0.3 m upstream of the views: the search also looks around where it would come
    into them, straight downstream of its guess: the first place along its travel at which a
    camera sees its centre (a grid step from where none does), or without its travel, the
    nearest place on the belt at which one does (here the same)."""
    from cellsight.tracking.search import PlaneSearch

    search = PlaneSearch()
    part = line.workpiece("u3")
    track = _track(part.feature_points)
    track.guess = track.support = part.T_base_part
    track.travel = None if travel is None else np.array(travel)
    acquirer = Acquirer(SimpleNamespace(tracks={"u3": track}, cameras=line.cameras))
    (entry,) = acquirer.entry(track, search)
    offset = track.centre_at(part.T_base_part) - part.T_base_part[:3, 3]

    def seen(xy):
        centre = np.array([[*xy, part.T_base_part[2, 3]]]) + offset
        return any(camera.sees(centre)[0] for camera in line.cameras)

    guess = part.T_base_part[:2, 3]
    assert seen(entry) and not seen(entry - [search.step_m, 0.0])
    assert 0.15 < entry[0] - guess[0] < 0.4 and abs(entry[1] - guess[1]) <= search.step_m + 1e-9
