"""Realism: the simulated world departs from the cell file as a real cell does.

A :class:`~cellsight.realism.profile.Profile` (``exact``, ``lab``, ``harsh`` or a user's YAML
file) states each knob's unit, default and distribution; :func:`draw_world` draws one run's
world from it and a seed (its own cell, its imperfections, the scenario's shift);
:class:`~cellsight.realism.timing.FrameClock` draws each frame's latency and drops. The
predictor, the tracker and the planner keep the nominal cell file.
"""

from cellsight.realism.draws import ScenarioShift, WorldDraws, draw_world
from cellsight.realism.profile import BUILTIN, Profile, ProfileError, load_profile
from cellsight.realism.timing import FrameClock, FrameTiming

__all__ = ["BUILTIN", "FrameClock", "FrameTiming", "Profile", "ProfileError", "ScenarioShift",
           "WorldDraws", "draw_world", "load_profile"]
