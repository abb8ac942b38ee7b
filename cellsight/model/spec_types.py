"""The value types the input files' schemas share (the cell file: :mod:`.schema`; the
realism profile: :mod:`cellsight.realism.profile`): numbers that refuse booleans, finite
vectors, counts and flags that refuse look-alikes, names safe in file names, and the strict
base model that refuses unknown keys."""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

MIN_CONVEYOR_STEP_M = 1e-6  # m: the shortest leg of a conveyor path
SAFE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}")  # a camera name: part of file names


def _no_bool(value: object) -> object:
    """Refuse ``true``/``false`` where a number is expected (pydantic would read 1.0, 0.0)."""
    if isinstance(value, bool):
        raise ValueError("a number, not a boolean")
    return value


def _safe_name(value: str) -> str:
    """Accept a camera name that is safe as part of a file name (:data:`SAFE_NAME`)."""
    if not SAFE_NAME.fullmatch(value):
        raise ValueError("a name of at most 64 letters, digits, '_', '-' and '.', not starting "
                         "with '.' (it becomes part of output file names)")
    return value


Number = Annotated[float, BeforeValidator(_no_bool)]
Finite = Annotated[Number, Field(allow_inf_nan=False)]
Vec2 = Annotated[list[Finite], Field(min_length=2, max_length=2)]
Vec3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]
Positive = Annotated[Number, Field(gt=0, allow_inf_nan=False)]
Count = Annotated[int, Field(strict=True)]  # an integer: 2.0, "2" and true are refused
Flag = Annotated[bool, Field(strict=True)]  # true or false: 1 and "yes" are refused
JOINT_UNIT = "rad (m for a prismatic joint)"  # the unit of a joint value



class _Strict(BaseModel):
    """A spec that refuses unknown keys (a misspelt field is an error, not ignored)."""

    model_config = ConfigDict(extra="forbid")
