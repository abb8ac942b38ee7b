"""Reading a cell file's YAML safely: bounded size, nesting and alias expansion.

A cell file is read as UTF-8 text of at most ``MAX_CELL_BYTES``; PyYAML's safe loader then builds
it, refusing a repeated key (plain PyYAML keeps the last one), collections nested deeper than
``MAX_YAML_DEPTH`` (PyYAML would recurse until a ``RecursionError``) and aliases that expand to
more than ``MAX_YAML_VALUES`` values (nested aliases, "billion laughs": a few kilobytes that
expand to gigabytes once validated). Anchors and aliases are welcome otherwise (the built-in cell
shares its DH links and gripper between the robots). Every refusal is a :class:`CellFileError`
naming the file and the line.
"""

from __future__ import annotations

import copy
from pathlib import Path

import yaml

from cellsight.errors import CellFileError

MAX_CELL_BYTES = 10 * 2**20  # bytes, largest cell file read
MAX_YAML_DEPTH = 64  # levels of nested collections, aliases expanded
MAX_YAML_VALUES = 2_000_000  # YAML values (scalars and collections), an alias counted per use


class _Refused(yaml.YAMLError):
    """YAML beyond a limit: what was found (short), what is accepted, and where."""

    def __init__(self, found: str, expected: str, mark) -> None:
        super().__init__(found)
        self.found, self.expected, self.problem_mark = found, expected, mark


class _CellLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a repeated key and nesting deeper than ``MAX_YAML_DEPTH``."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise _Refused("deeper nesting", f"collections nested at most {MAX_YAML_DEPTH} "
                               "levels deep", self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _unique_mapping(loader: _CellLoader, node: yaml.MappingNode, deep: bool = False):
    """The mapping of ``node``, a key repeated in it refused; YAML merge keys (``<<: *anchor``)
    are taken as PyYAML's safe loader takes them, the mapping's own keys winning."""
    seen = set()
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue
        key = loader.construct_object(key_node, deep=deep)
        try:
            repeated = key in seen
            seen.add(key)
        except TypeError:  # an unhashable key: construct_mapping names the problem
            repeated = False
        if repeated:
            raise yaml.constructor.ConstructorError(
                "while reading a mapping", node.start_mark, f"duplicate key {key!r}",
                key_node.start_mark)
    return loader.construct_mapping(node, deep=deep)


_CellLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def _expanded(node: yaml.Node, path: set[int], memo: dict[int, tuple[int, int]]) -> tuple[int, int]:
    """Number of values and depth of ``node`` with every alias expanded; each distinct node is
    visited once (memoised), so the cost is that of the text, not of the expansion."""
    key = id(node)
    if key in memo:
        return memo[key]
    if key in path:
        raise _Refused("an alias inside the collection it names", "no recursive values",
                       node.start_mark)
    if isinstance(node, yaml.MappingNode):
        children = [child for pair in node.value for child in pair]
    else:
        children = node.value if isinstance(node, yaml.SequenceNode) else []
    path.add(key)
    size, depth = 1, 0
    for child in children:
        n, d = _expanded(child, path, memo)
        size, depth = size + n, max(depth, d)
        if size > MAX_YAML_VALUES:
            raise _Refused(f"more than {MAX_YAML_VALUES} values", f"at most {MAX_YAML_VALUES} "
                           "values once aliases are expanded (nested aliases?)", node.start_mark)
        if len(path) + d > MAX_YAML_DEPTH:
            raise _Refused("deeper nesting", f"collections nested at most {MAX_YAML_DEPTH} "
                           "levels deep once aliases are expanded", child.start_mark)
    path.discard(key)
    memo[key] = (size, depth + 1)
    return memo[key]


def load_yaml(text: str, file: str) -> object:
    """The YAML document in ``text`` (safe types only), within the limits above; a
    :class:`CellFileError` naming ``file`` and the line otherwise."""
    if len(text) > MAX_CELL_BYTES:
        raise CellFileError(file, "<file>", f"{len(text)} characters",
                            f"a cell file of at most {MAX_CELL_BYTES} bytes")
    loader = None
    try:
        loader = _CellLoader(text)  # PyYAML's reader checks the characters here
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded(node, set(), {})
        return loader.construct_document(node)
    except _Refused as exc:
        mark = exc.problem_mark
        raise CellFileError(file, f"line {mark.line + 1}", exc.found, exc.expected) from exc
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark else "<yaml>"
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise CellFileError(file, where, problem, "valid YAML") from exc
    except RecursionError as exc:  # a backstop: the limits above should prevent it
        raise CellFileError(file, "<yaml>", "too deep", "less deeply nested YAML") from exc
    finally:
        if loader is not None:
            loader.dispose()


def read_cell_text(path: Path) -> str:
    """The text of a cell file: an existing, readable file of at most ``MAX_CELL_BYTES``
    bytes of UTF-8; a :class:`CellFileError` naming the file otherwise."""
    file = str(path)
    if not path.is_file():
        raise CellFileError(file, "<file>", file, "an existing YAML cell file")
    try:
        size = path.stat().st_size
        if size > MAX_CELL_BYTES:
            raise CellFileError(file, "<file>", f"{size} bytes",
                                f"a cell file of at most {MAX_CELL_BYTES} bytes")
        data = path.read_bytes()
    except OSError as exc:
        raise CellFileError(file, "<file>", file, f"a readable file ({exc.strerror})") from exc
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise CellFileError(file, f"line {line}", data[exc.start:exc.start + 4],
                            f"UTF-8 text (byte {exc.start} is not UTF-8)") from exc


def _absolute(value: str, folder: Path) -> str:
    """A file name of a cell file (relative to ``folder``) as an absolute one; URIs stay."""
    return value if "://" in value else str((folder / value).resolve())


def with_absolute_paths(raw: dict, folder: Path) -> dict:
    """A copy of a cell file's mapping whose mesh, URDF, calibration and hand-eye files and
    package folders are absolute (so that the cell loads from any folder); shared (aliased)
    parts stay shared."""
    data = copy.deepcopy(raw)
    packages = data.get("packages") or {}
    for name, sub in packages.items():
        packages[name] = _absolute(sub, folder)
    seen: set[int] = set()
    todo: list[object] = [data]
    while todo:
        node = todo.pop()
        if id(node) in seen or not isinstance(node, dict | list):
            continue
        seen.add(id(node))
        children = node.values() if isinstance(node, dict) else node
        if isinstance(node, dict):
            for key in ("mesh", "urdf", "calibration", "hand_eye"):
                if isinstance(node.get(key), dict) and isinstance(node[key].get("file"), str):
                    node[key]["file"] = _absolute(node[key]["file"], folder)
                elif key in ("calibration", "hand_eye") and isinstance(node.get(key), str):
                    node[key] = _absolute(node[key], folder)
        todo.extend(children)
    return data
