"""Two helpers for what the files hold: a pydantic field declared with its meaning and its unit
(the cell file, the realism profile, ``metrics.json``; the documentation's reference pages
print them for every field), and an enum whose members are their names (:class:`NamedEnum`:
the task's phases and stages, the sensor, the occlusion structure)."""

from __future__ import annotations

from enum import Enum
from typing import Any

from pydantic import Field


def about(default: Any, description: str, unit: str, **kw: Any) -> Any:
    """A field's default with its meaning and unit (``json_schema_extra={"unit": ...}``);
    ``kw``: more :func:`pydantic.Field` arguments (constraints given in the annotation stay
    there)."""
    return Field(default, description=description, json_schema_extra={"unit": unit}, **kw)


class NamedEnum(str, Enum):
    """An enum whose members equal, print and serialise as their names (``"descend"``), as
    the files and the command line write them."""

    def __str__(self) -> str:
        return self.value
