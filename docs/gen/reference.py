"""The reference pages generated from the code: the command line from its argument parsers,
the cell file's and the realism profile's schemas from their pydantic models, the run folder
from :mod:`cellsight.runfolder`. Each function returns a page's Markdown; nothing here is
typed by hand but the headings."""

from __future__ import annotations

import argparse
import re
import types
import typing
from collections.abc import Iterator

from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

SCHEMA_NOTE = ("Generated from the pydantic models in `{module}`: every field, its type, "
               "its default (empty: required) and its unit.")


ROLE = re.compile(r":[a-z]+:`~?\.?([^`]+)`")


def plain(text: str) -> str:
    """A docstring's reStructuredText as Markdown: roles and double back-quotes become code."""
    return ROLE.sub(r"`\1`", text).replace("``", "`")


def _cell(text: object) -> str:
    """``text`` made safe for one Markdown table cell."""
    return plain(str(text)).replace("|", "\\|").replace("\n", " ").strip()


def _subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """(name, one-line help, parser) of each sub-command, in ``--help`` order."""
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {a.dest: a.help for a in action._choices_actions}
    return [(name, helps.get(name, ""), sub) for name, sub in action.choices.items()]


def _option_row(action: argparse.Action) -> str:
    """One option or positional argument as a table row: name, value, default, meaning."""
    name = ", ".join(f"`{o}`" for o in action.option_strings) or f"`{action.dest}`"
    if action.nargs == 0:
        value = ""
    elif action.choices is not None:
        value = " \\| ".join(f"`{c}`" for c in action.choices)
    else:
        value = f"`{action.metavar or action.dest.upper()}`"
        if action.nargs in ("+", "*"):
            value += " ..."
        elif action.nargs == "?":
            value = f"[{value}]"
    shown = action.default not in (None, False, argparse.SUPPRESS) and action.nargs != 0
    default = f"`{action.default}`" if shown else ""
    return f"| {name} | {value} | {default} | {_cell(action.help or '')} |"


def commands_table(parser: argparse.ArgumentParser) -> str:
    """The README's table of the commands: each with its one-line help."""
    lines = ["| command | what it does |", "|---|---|"]
    lines += [f"| `cellsight {name}` | {_cell(text)} |" for name, text, _ in _subcommands(parser)]
    return "\n".join(lines) + "\n"


def cli_page(parser: argparse.ArgumentParser) -> str:
    """The command line: every sub-command with its usage and every argument."""
    commands = _subcommands(parser)
    lines = ["# Command line", "",
             "Generated from `cellsight.cli.build_parser()`: every command, every argument. "
             "`cellsight COMMAND --help` prints the same. Every bad argument is refused in one "
             "line naming it (exit status 2) before anything is written.", "",
             "| command | what it does |", "|---|---|"]
    lines += [f"| [`{name}`](#{name}) | {_cell(text)} |" for name, text, _ in commands]
    for name, text, sub in commands:
        usage = sub.format_usage().removeprefix("usage: ").strip()
        lines += ["", f"## {name}", "", f"{text}.", "", "```text", usage, "```", "",
                  "| argument | value | default | meaning |", "|---|---|---|---|"]
        lines += [_option_row(a) for a in sub._actions if a.help != argparse.SUPPRESS
                  and not isinstance(a, argparse._HelpAction)]
    return "\n".join(lines) + "\n"


def _models_in(annotation: object) -> Iterator[type[BaseModel]]:
    """The pydantic models an annotation holds (in lists, unions, dicts, Annotated)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield annotation
        return
    for arg in typing.get_args(annotation):
        yield from _models_in(arg)


def models_of(root: type[BaseModel]) -> list[type[BaseModel]]:
    """``root`` and every model its fields reach, in the order first met (depth first)."""
    seen: list[type[BaseModel]] = []

    def visit(model: type[BaseModel]) -> None:
        if model in seen:
            return
        seen.append(model)
        for field in model.model_fields.values():
            for inner in _models_in(field.annotation):
                visit(inner)

    visit(root)
    return seen


def _type_name(annotation: object) -> str:
    """A field's type as a reader would write it: ``list[float]``, ``PoseSpec | None``."""
    if annotation is type(None):
        return "None"
    if isinstance(annotation, type) and not typing.get_args(annotation):
        return annotation.__name__
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        return _type_name(args[0])
    if origin in (typing.Union, types.UnionType):
        return " \\| ".join(_type_name(a) for a in args)
    if origin is typing.Literal:
        return " \\| ".join(repr(a) for a in args)
    if origin is not None:
        name = getattr(origin, "__name__", str(origin))
        return f"{name}[{', '.join(_type_name(a) for a in args)}]"
    return str(annotation).replace("typing.", "")


def field_unit(field: FieldInfo) -> str:
    """The unit a field declares (``json_schema_extra={"unit": ...}``); empty when none."""
    extra = field.json_schema_extra
    return str(extra.get("unit", "")) if isinstance(extra, dict) else ""


def _default(field: FieldInfo) -> str:
    if field.default is PydanticUndefined and field.default_factory is None:
        return ""
    value = field.default_factory() if field.default_factory else field.default
    if isinstance(value, BaseModel):
        value = {k: v for k, v in value.model_dump().items() if v not in (None, [], {})}
    return f"`{value}`" if value not in (None, [], {}) else ""


def schema_page(title: str, intro: str, root: type[BaseModel],
                sections: tuple[type[BaseModel], ...] = ()) -> str:
    """A schema's reference: one table per model, every field with its type, default, unit
    and description, and links from a field to the model it holds; a ``root`` made of
    ``sections`` (its bases) gets a table per section instead of one of its own."""
    models = [m for root_or_section in (sections or (root,))
              for m in models_of(root_or_section)]
    models = list(dict.fromkeys(models))
    anchors = {m: m.__name__.lower() for m in models}
    lines = [f"# {title}", "", intro, "",
             SCHEMA_NOTE.format(module=root.__module__), ""]
    for model in models:
        doc = plain(" ".join((model.__doc__ or "").split()))
        lines += [f"## {model.__name__}", "", doc, "",
                  "| field | type | default | unit | meaning |", "|---|---|---|---|---|"]
        for name, field in model.model_fields.items():
            kind = _type_name(field.annotation)
            for inner in _models_in(field.annotation):
                kind = kind.replace(inner.__name__, f"[{inner.__name__}](#{anchors[inner]})")
            lines.append(f"| `{name}` | {kind} | {_cell(_default(field))} | "
                         f"{_cell(field_unit(field))} | {_cell(field.description or '')} |")
        lines.append("")
    return "\n".join(lines)


def run_folder_page() -> str:
    """The run folder: its files, ``frames.csv``'s columns and ``metrics.json``'s fields."""
    from cellsight.runfolder import framelog
    from cellsight.runfolder.folder import RUN_FILE_DOCS
    from cellsight.runfolder.metric_sections import SECTIONS
    from cellsight.runfolder.metrics import RunMetrics

    header = framelog.columns(2, {"R7AX": 7, "R6AX": 6})
    lines = ["# Run folder", "",
             "What `cellsight run` and `cellsight track` write into `--out`, generated from "
             "`cellsight.runfolder`. `read_metrics`, `load_run` and `FrameLog.read` read it "
             "back, checked.", "", "## Files", "", "| file | what it holds |", "|---|---|"]
    lines += [f"| `{name}` | {_cell(text)} |" for name, text in RUN_FILE_DOCS.items()]
    lines += ["", "## frames.csv", "",
              plain(" ".join(framelog.__doc__.split("\n\n")[-1].split())), "",
              f"One row per vision frame. The built-in cell's header (2 cameras, R7AX with 7 "
              f"joints, R6AX with 6) has {len(header)} columns; `c` is the camera's number "
              "(1-based, in the cell file's order), `F` the part's number of features.", "",
              "| column | unit | meaning |", "|---|---|---|"]
    lines += [f"| `{family}` | {_cell(unit)} | {_cell(text)} |"
              for family, (unit, text) in framelog.COLUMN_DOCS.items()]
    lines += ["", schema_page("metrics.json", "One JSON object a run, written last, its fields "
                              "in sections (`cellsight.runfolder.metric_sections`).",
                              RunMetrics, SECTIONS)
              .replace("# metrics.json", "## metrics.json", 1).replace("\n## ", "\n### ")]
    return "\n".join(lines)

