"""Runs exported for other tools: ``cellsight export RUN_DIR --mcap FILE`` writes a run folder
as an MCAP file of ROS 2 messages (TF, camera images and info, part poses, visibility markers)
for ROS 2 tools and Foxglove (:mod:`cellsight.export.mcap_run`; the command line:
:mod:`cellsight.commands.export`). Names are loaded on first use, so that the command line can
register the command without importing the MCAP libraries."""

from __future__ import annotations

_NAMES = {"ExportOptions": "mcap_run", "ExportResult": "mcap_run", "Stop": "mcap_run",
          "export_mcap": "mcap_run"}

__all__ = sorted(_NAMES)


def __getattr__(name: str):
    if name not in _NAMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib import import_module

    return getattr(import_module(f"{__name__}.{_NAMES[name]}"), name)
