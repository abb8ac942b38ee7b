"""``metrics.json``, a run's facts and figures: its schema (:class:`RunMetrics`), its one writer
(:func:`write_metrics`) and its one reader (:func:`read_metrics`).

The file is a JSON object. ``metrics_version`` (:data:`METRICS_VERSION`) says which schema wrote
it; a file without one was written before versions and reads the same. Every field is optional
on reading (a run cut short writes what it has; ``cellsight compare`` takes any two), but a
field that is there must have its type: a hand-edited ``"seed": "three"`` or ``"phases": [1]``
is one :class:`~cellsight.runfolder.replay.RunDataError` naming the file and the field. Fields
the schema does not know are kept as they are. The figures' meaning and units are those of
:mod:`cellsight.runfolder.figures` (``*_mm`` in mm, ``*_deg`` in degrees, ``*_s`` in s).
"""

from __future__ import annotations

import json
from pathlib import Path

from pydantic import ValidationError

from cellsight.errors import CellsightError, short_repr
from cellsight.runfolder.digest import file_digest, is_regular_file
from cellsight.runfolder.metric_sections import RunMetrics
from cellsight.runfolder.writes import write_file

METRICS_VERSION = 1
"""Version of the schema :func:`write_metrics` writes (``metrics_version``)."""


class RunDataError(CellsightError, ValueError):
    """A run folder that cannot be read or replayed: missing, unreadable, or inconsistent."""





_EXPECTED = {"dict_type": "expected an object", "int_type": "expected a whole number",
             "float_type": "expected a number", "string_type": "expected text",
             "bool_type": "expected true or false", "list_type": "expected a list",
             "model_type": "expected an object"}
"""What a pydantic error type expects, in the words of a JSON file."""


def _located(data: dict, loc: tuple) -> tuple[str, object]:
    """The dotted field name and value at a pydantic error's ``loc`` in ``data`` (the parts
    naming union members rather than keys or indices are left out)."""
    names, value = [], data
    for part in loc:
        if isinstance(value, dict) and part in value or (
                isinstance(value, list) and isinstance(part, int) and part < len(value)):
            names.append(str(part))
            value = value[part]
    return ".".join(names), value


def _checked(data: object, path: Path) -> dict:
    """``data`` checked against :class:`RunMetrics`: the fields as they were, or one
    :class:`RunDataError` naming ``path`` and the first wrong field."""
    if not isinstance(data, dict):
        raise RunDataError(f"{path}: expected a JSON object of metrics, got "
                           f"{type(data).__name__} {short_repr(data)}")
    try:
        RunMetrics.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        field, value = _located(data, first["loc"])
        expected = _EXPECTED.get(first["type"], first["msg"].lower())
        raise RunDataError(f"{path}: field {field!r}: {expected}, got "
                           f"{short_repr(value)}") from None
    version = data.get("metrics_version", 0)
    if version > METRICS_VERSION:
        raise RunDataError(f"{path}: field 'metrics_version' is {version}: written by a newer "
                           f"cellsight (this one reads up to {METRICS_VERSION})")
    return data


def _json_object(path: Path, folder: Path) -> object:
    """The JSON value in ``path``; a :class:`RunDataError` naming it when it cannot be read."""
    if path.exists() and not is_regular_file(path):  # a FIFO would block for ever
        raise RunDataError(f"{path}: not a regular file (a folder, a FIFO or a device); "
                           f"expected the run's metrics.json")
    try:
        text = path.read_bytes()
    except (FileNotFoundError, NotADirectoryError) as exc:
        raise RunDataError(f"{path}: no metrics.json here (is {folder} a run's output "
                           f"folder?)") from exc
    except (OSError, ValueError) as exc:  # a folder, unreadable, a NUL in the name
        reason = getattr(exc, "strerror", None) or str(exc)
        raise RunDataError(f"{path}: cannot read it ({reason})") from exc
    try:
        return json.loads(text.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise RunDataError(f"{path}: not UTF-8 text") from exc
    except json.JSONDecodeError as exc:
        raise RunDataError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from exc
    except (ValueError, RecursionError) as exc:  # a number too long, nested too deeply
        shown = " ".join(str(exc).split())[:80]
        raise RunDataError(f"{path}: not usable JSON ({shown})") from exc


def read_metrics(folder: str | Path, missing_ok: bool = False) -> dict:
    """``<folder>/metrics.json`` as a dict, checked (module docstring); ``missing_ok``: ``{}``
    when the file is absent (a run cut short before writing it). Every problem is one
    :class:`RunDataError` naming the folder or the file."""
    folder = Path(folder)
    path = folder / "metrics.json"
    if missing_ok and not path.exists():
        return {}
    if not folder.is_dir():
        what = "it does not exist" if not folder.exists() else "it is not a folder"
        raise RunDataError(f"{folder}: no such run folder ({what}), so no metrics.json here; "
                           f"expected a run's output folder (cellsight run)")
    return _checked(_json_object(path, folder), path)


def checked_metrics(folder: Path, metrics: dict) -> dict:
    """``metrics`` as :func:`write_metrics` would write them into ``folder`` (with
    ``metrics_version``), checked against :class:`RunMetrics`; nothing is written."""
    out = {"metrics_version": METRICS_VERSION, **metrics}
    return _checked(out, Path(folder) / "metrics.json")


def write_metrics(folder: Path, metrics: dict) -> dict:
    """Write ``metrics`` as ``<folder>/metrics.json`` (with ``metrics_version`` and the
    ``frames_sha256`` of the folder's frames.csv, closed by then), checked against
    :class:`RunMetrics` first; returns what was written. The file is written whole or
    not at all (:func:`~cellsight.runfolder.writes.write_file`: a failure is a
    :class:`~cellsight.runfolder.writes.WriteError` and leaves no ``metrics.json`` of it)."""
    frames = file_digest(Path(folder) / "frames.csv")
    out = checked_metrics(folder, metrics if frames is None else
                          {**metrics, "frames_sha256": frames})
    write_file(Path(folder) / "metrics.json", json.dumps(out, indent=1))
    return out


def finished_metrics(folder: Path) -> dict | None:
    """The metrics of a finished run in ``folder`` (neither interrupted nor failed), else None:
    not run yet, cut short while writing, or not a run's metrics. A run that could not write
    one of its files (a full disk) is a failed one: its ``metrics.json``, written last, has the
    ``error``, or it has none (:mod:`cellsight.runfolder.writes`)."""
    try:
        metrics = read_metrics(folder)
    except RunDataError:
        return None
    return None if metrics.get("interrupted") or metrics.get("error") else metrics
