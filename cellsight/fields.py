"""One helper for the pydantic schemas (the cell file, the realism profile, ``metrics.json``):
a field declared with its meaning and its unit, which the documentation's reference pages
print for every field."""

from __future__ import annotations

from typing import Any

from pydantic import Field


def about(default: Any, description: str, unit: str, **kw: Any) -> Any:
    """A field's default with its meaning and unit (``json_schema_extra={"unit": ...}``);
    ``kw``: more :func:`pydantic.Field` arguments (constraints given in the annotation stay
    there)."""
    return Field(default, description=description, json_schema_extra={"unit": unit}, **kw)
