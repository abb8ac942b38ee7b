"""A griffe extension for the API reference: the docstrings' reStructuredText roles
(``:class:`~.tracker.Tracker```) and double back-quotes become Markdown code spans, as the
other generated pages write them (:func:`reference.plain`)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from griffe import Extension, Object

sys.path.insert(0, str(Path(__file__).resolve().parent))

from reference import plain  # noqa: E402


class SphinxRoles(Extension):
    """Rewrites every docstring once it is loaded."""

    def on_instance(self, *, obj: Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = plain(obj.docstring.value)
