"""Finding a part that is not tracked (for :mod:`.tracker`; the paper leaves it to its
references): a fix in windows at the guess or the last prediction, verified where it predicts
every usable feature; else the whole-image search's best confirmed candidate; then the fix's
twins (the part turned onto itself) tried, the one confirmed by the most points kept. A fix off
the support the kinematic prior says the part lies on, or away from where a holder just let it
go, is refused.

Data association: the parts are known by name, and each track keeps its own (its windows lie
where its own prediction puts its features). A part to be acquired may be found where another
part lies: the search proposes every place that fits its shape, and a part of the same shape
nearby fits as well as it does. So a fix whose feature points' centre lies within
``CLAIM_SHARE`` of the two parts' summed radii of another track's estimate (one neither lost
nor waiting) is that part's and is refused: two parts lying side by side on a support are
farther apart (the line's U and L prisms, touching, 6 cm or more, against 4.8 cm), and the
part keeps waiting until it shows itself elsewhere (a passing part entering the views, a part
put down beside another). Parts stacked on each other are not told apart."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.camera import Camera, seen_by_any
from cellsight.tracking.acquisition import rates_covariance
from cellsight.tracking.camera_check import CameraCheck
from cellsight.tracking.config import TrackerConfig, TrackerParts
from cellsight.tracking.grabbing import grabbed
from cellsight.tracking.measuring import Measurer
from cellsight.tracking.motion import POSE_DIM
from cellsight.tracking.part_track import (
    PartTrack,
    StepContext,
    cameras_grabbed,
    looked_at,
    observed_of,
    record_estimate,
)
from cellsight.tracking.pnp import PoseFix
from cellsight.tracking.prior.fusion import fits_prior
from cellsight.tracking.records import PartFrame
from cellsight.tracking.search import PlaneSearch
from cellsight.tracking.status import TrackStatus

TWIN_VERTICAL = np.cos(np.radians(10.0))  # a twin's turn axis this close to the vertical
CLAIM_SHARE = 0.4  # a fix this close (share of the two radii) to another track's is that part's
ENTRY_REACH_M = 2.0  # a part waiting out of view is looked for where it would come in, this near


class Measuring(Protocol):
    """What acquisition uses of the tracker: its cameras, parts, numbers, camera check and its
    :class:`~.measuring.Measurer` (which holds the extractor)."""

    cameras: list[Camera]
    components: TrackerParts
    config: TrackerConfig
    camera_check: CameraCheck
    measurer: Measurer
    tracks: dict[str, PartTrack]

    def initialise(self, name: str, T_base_part: np.ndarray, t: float,
                   covariance: np.ndarray | None = None,
                   offsets: dict[int, np.ndarray] | None = None) -> None:
        ...


class Acquirer:
    """Acquisition for ``tracker`` (module docstring)."""

    def __init__(self, tracker: Measuring) -> None:
        self.tracker = tracker

    def acquire(self, context: StepContext) -> PartFrame:
        """A fix at the guess or the last prediction, else from the whole-image search (module
        docstring); the filter starts from it. Returns the record of the windows that gave the
        fix (or of the guess's, when there is none)."""
        tracker, track = self.tracker, context.track
        acquisition = tracker.components.acquisition
        if track.holder is not None:  # held, not tracked: it is where the gripper holds it
            rec = context.rec
            tracker.initialise(rec.name, track.held_at, context.t, acquisition.covariance(
                np.diag(np.repeat(np.square(tracker.config.held_std), 3))))
            rec.status = TrackStatus.ACQUIRED
            record_estimate(rec, track.ekf)
            return rec
        verified = self.find(context)
        if verified is None:
            track.search_on(acquisition)
            return context.rec
        context, fix = verified
        rec = context.rec
        covariance = acquisition.start(fix)
        if track.lying is not None:  # on its support: as fast as a support moves it, at most
            covariance[POSE_DIM:, POSE_DIM:] = rates_covariance(tracker.config.support_speed)
        tracker.initialise(rec.name, fix.T_base_part, context.t, covariance, fix.offsets_px)
        for c, f in fix.dropped:
            rec.rejected[c, f] = True
        rec.status = TrackStatus.ACQUIRED
        record_estimate(rec, track.ekf)
        return rec

    def find(self, context: StepContext) -> tuple[StepContext, PoseFix] | None:
        """The verified fix of the part, with the context of its record, or None: at the
        guess or the last prediction, else from the whole-image search; its best twin."""
        track, acquisition = context.track, self.tracker.components.acquisition
        fix = self.fix(context, acquisition.window_px, coarse=True)
        verified = None if fix is None else self.verify(context, fix)
        if verified is not None and not self.fits(context, verified[1].T_base_part):
            verified = None  # off its support, or another part's: a wrong pose the corners fit
        searched = verified is None
        if searched:
            verified = self.search(context)
        if verified is not None:
            verified = best_twin(lambda fix: self.verify(context, fix, searched), track.twins,
                                 verified)
        return verified

    def fix(self, context: StepContext, size_px: float, coarse: bool = False,
            guess: np.ndarray | None = None, on_support: bool = False) -> PoseFix | None:
        """Windows of ``size_px`` (px) on every usable feature of the record's prediction, then
        a fix (:mod:`.acquisition`; ``coarse``: a first one, to be verified; ``guess``: the
        pose of that prediction, to seed the fix where it is already near; ``on_support``: a
        part lying on its support may be fitted there, the search's candidates and their
        verification), or None. A camera the camera check holds out of the filter (dropped
        as knocked, or awaiting its second look) is held out of the fix too."""
        context.rec.selected = self.tracker.measurer.usable(context, None)

        def covariance(c: int, idx: np.ndarray) -> np.ndarray:
            return np.zeros((len(idx), 2, 2))

        tracker = self.tracker
        usable = tracker.camera_check.usable
        obs = [o for o in tracker.measurer.measure(context, covariance, size_px)
               if usable(o.camera_index)]
        lying = context.track.lying
        support = None if lying is None or not on_support else (lying, tracker.config.rest_std)
        with context.timer("ekf"):
            return tracker.components.acquisition.fix(obs, tracker.config.sigma_px, coarse, guess,
                                                      support)

    def verify(self, context: StepContext, fix: PoseFix,
               on_support: bool = False) -> tuple[StepContext, PoseFix] | None:
        """The fix checked against every feature it predicts (:mod:`.acquisition`): narrow
        windows where it predicts them (moved by the cameras' offsets it estimated, if any), and
        a second fix from what they find (``on_support``: as for :meth:`_fix`); that fix with
        the context of its record, or None when it does not confirm the first."""
        trial = looked_at(context, fix.T_base_part, len(self.tracker.cameras))
        for c, shift in (fix.offsets_px or {}).items():  # where each camera shows the part
            trial.rec.pixels[c] += shift
        again = self.fix(trial, self.tracker.components.acquisition.verify_window_px,
                          guess=fix.T_base_part if on_support else None, on_support=on_support)
        if again is None:
            return None
        rec = trial.rec
        used = np.isfinite(rec.measured[..., 0])
        for c, f in again.dropped:
            used[c, f] = False
        looked = rec.selected & cameras_grabbed(context.observed, self.tracker.cameras)[:, None]
        confirmed = self.tracker.components.acquisition.confirms(again, looked.sum(axis=1),
                                                         used.sum(axis=1))
        return (trial, again) if confirmed else None

    def search_every(self, track: PartTrack, search: PlaneSearch) -> float | None:
        """How often (s) the part is searched for: ``search.every_s``; for a part never
        acquired whose guess lies outside every camera's view (it may come in: a part carried
        in from upstream), ``search.out_of_view_every_s``; never (None) for a part lost with
        its last estimate outside every camera's view: it left the views, and its track ends
        (a part carried out downstream does not come back)."""
        if not self.out_of_view(track):
            return search.every_s
        return search.out_of_view_every_s if track.ekf is None else None

    def out_of_view(self, track: PartTrack) -> bool:
        """The part's last known place (its last estimate, else its guess) puts its centre
        outside every camera's view (False without one)."""
        last = track.guess if track.ekf is None else track.ekf.pose
        return last is not None and not seen_by_any(self.tracker.cameras,
                                                    track.centre_at(last)[None])[0]

    def entry(self, track: PartTrack, search: PlaneSearch) -> list[np.ndarray]:
        """Where a part waiting out of every camera's view would come into them, on its
        support plane (x, y, m; the search looks around it too; none within reach: an empty
        list): a part a line carries (``track.travel``) at the first place along its travel
        at which some camera sees its centre; any other at the nearest place to its guess,
        within ``ENTRY_REACH_M``, at which some camera does. Found once, on a grid of the
        search's step."""
        if track.entry is None:
            if track.travel is not None:
                length = float(np.hypot(*track.travel[:2]))
                way = track.travel[:2] / length
                offsets = np.arange(0.0, length + 1e-9, search.step_m)[:, None] * way
            else:
                n = int(round(ENTRY_REACH_M / search.step_m))
                steps = np.arange(-n, n + 1)
                offsets = search.step_m * np.stack(np.meshgrid(steps, steps), -1).reshape(-1, 2)
                offsets = offsets[np.argsort(np.hypot(*offsets.T), kind="stable")]
            seen = seen_by_any(self.tracker.cameras, track.centre_at(track.support)
                               + np.column_stack([offsets, np.zeros(len(offsets))]))
            track.entry = ([track.support[:2, 3] + offsets[int(np.argmax(seen))]]
                           if seen.any() else [])
        return track.entry

    def fits(self, context: StepContext, T_base_part: np.ndarray) -> bool:
        """A fix of the context's part at ``T_base_part`` may stand: on the support the
        kinematic prior says it lies on (:func:`~.prior.fusion.fits_prior`), and not where
        another track holds its part (module docstring)."""
        return fits_prior(context.track, T_base_part, context.t) and not self.claimed(
            context, T_base_part)

    def claimed(self, context: StepContext, T_base_part: np.ndarray) -> bool:
        """Another track holds its part where the context's part would lie at ``T_base_part``
        (module docstring)."""
        name, track = context.rec.name, context.track
        centre = track.centre_at(T_base_part)
        return any(np.linalg.norm(other.centre_at(other.ekf.pose) - centre)
                   < CLAIM_SHARE * (track.radius + other.radius)
                   for other_name, other in self.tracker.tracks.items()
                   if other_name != name and other.claims)

    def search(self, context: StepContext) -> tuple[StepContext, PoseFix] | None:
        """The whole-image search, when it is due (:mod:`.search`): of its best candidates
        where no other track holds its part (:meth:`claimed`) whose windows give a fix of at
        least ``min_points`` points (seeded by the candidate; a part lying on its support
        may be fitted there, from fewer: :mod:`.acquisition`) that verification confirms,
        the one whose verifying fix has the most points (the fewest pixels of RMS among
        equals; a nearly symmetric part's turned twin fits fewer of its features than the
        part), with the context of its record; None otherwise. A camera held out of the
        filter (:meth:`fix`) is not searched."""
        search, track, t = self.tracker.components.search, context.track, context.t
        acquisition = self.tracker.components.acquisition
        detect = self.tracker.measurer.detect
        cameras, check = self.tracker.cameras, self.tracker.camera_check
        observed = [observed_of(context.observed, cameras, c) if check.usable(c) else None
                    for c in range(len(cameras))]
        every = None if search is None else self.search_every(track, search)
        if (every is None or detect is None or track.support is None
                or t - track.searched < every - 1e-9 or all(o is None for o in observed)):
            return None
        track.searched = t
        with context.timer("grab"):
            observed = [grabbed(o) for o in observed]
        with context.timer("extraction"):
            corners = [None if o is None else detect(o) for o in observed]
            centres = [track.support[:2, 3]] + ([] if track.ekf is None else
                                                [track.ekf.pose[:2, 3]])
            if track.ekf is None and self.out_of_view(track):
                centres += self.entry(track, search)
            candidates = search.candidates(self.tracker.cameras, track.points, track.support,
                                           np.array(centres), corners)
        unclaimed = [c for c in candidates if not self.claimed(context, c.T_base_part)]
        confirmed = []  # a candidate where another part lies is not worth a verification
        for candidate in unclaimed[:search.verify]:
            trial = looked_at(context, candidate.T_base_part, len(self.tracker.cameras))
            fix = self.fix(trial, acquisition.window_px, coarse=True,
                            guess=candidate.T_base_part, on_support=True)
            enough = fix is not None and (acquisition.enough(fix) if fix.on_support
                                          else fix.n_points >= search.min_points)
            if enough:
                verified = self.verify(trial, fix, on_support=True)
                if verified is not None and self.fits(context, verified[1].T_base_part):
                    confirmed.append(verified)
        return max(confirmed, key=lambda c: (c[1].n_points, -c[1].rms_px), default=None)


def best_twin(verify: Callable[[PoseFix], tuple[StepContext, PoseFix] | None],
               twins: Sequence[np.ndarray],
               verified: tuple[StepContext, PoseFix]) -> tuple[StepContext, PoseFix]:
    """``verified``, or the confirmation (``verify``) of one of its fix's ``twins`` (the part
    turned onto itself, :func:`~cellsight.tracking.acquisition.twin_turns`) with more points.
    Only twins turned about an axis within ``TWIN_VERTICAL`` of the vertical are tried: they
    keep a lying part the right way up (turned over, in ``harsh``, the twins' features above
    the belt gave them more points than the part). An exact twin, whose features fall where
    the fix's do, is as good, and not taken."""
    best, T = verified, verified[1].T_base_part
    for turn in twins:
        axis = Rotation.from_matrix(turn[:3, :3]).as_rotvec()
        if abs(T[:3, :3] @ axis)[2] < TWIN_VERTICAL * np.linalg.norm(axis):
            continue  # it would turn the part over
        other = verify(replace(verified[1], T_base_part=T @ turn))
        if other is not None and other[1].n_points > best[1].n_points:
            best = other
    return best
