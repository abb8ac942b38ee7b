"""One run session: frames from a source, through the tracker and the task, to sinks.

- :mod:`.frames`: what flows, one frame at a time (:class:`SourceFrame`, :class:`FrameRecord`,
  the truth);
- :mod:`.protocols`: :class:`FrameSource` and :class:`FrameSink`;
- :mod:`.run`: :class:`RunSession`, the one loop and the run folder's lifecycle;
- :mod:`.driver`: a camera driver as a source (the API's hook for a live cell);
- :mod:`.rows`, :mod:`.baseline`, :mod:`.events`: the sinks every run has (``frames.csv`` with
  the PnP baseline, the occlusion events of ``run.log``).
"""

from cellsight.session.frames import FrameRecord, FrameTruth, PartTruth, SourceFrame
from cellsight.session.protocols import FrameSink, FrameSource, RunContext
from cellsight.session.run import RunParts, RunSession

__all__ = ["FrameRecord", "FrameSink", "FrameSource", "FrameTruth", "PartTruth", "RunContext",
           "RunParts", "RunSession", "SourceFrame"]
