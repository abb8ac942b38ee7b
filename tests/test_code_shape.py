"""The shape of the code (issue 13): small functions, small classes, imports that only go
down the layers. Read from the source with :mod:`ast`; nothing is imported or run."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "cellsight"
MAX_FUNCTION_LINES = 60  # outside the numba kernels, whose loops are written out
MAX_CLASS_METHODS = 15

# Lowest first: a module may import from its own layer and the ones before it, never after.
LAYERS = [
    {"errors", "rates", "geometry"},
    {"camera", "_camera_kernel", "kinematics", "visibility"},
    {"model"},
    {"occlusion", "tracking", "control"},
    {"world", "framelog", "runfolder", "realism"},
    {"report"},
    {"experiments", "sweep", "view", "export", "placement"},
    {"cli", "cameras_cli", "__init__", "__main__", "data"},
]


def _sources() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def _is_jitted(node: ast.FunctionDef) -> bool:
    return any("jit" in ast.unparse(d) for d in node.decorator_list)


def _layer(module: str) -> int:
    top = module.split(".")[0]
    for i, layer in enumerate(LAYERS):
        if top in layer:
            return i
    raise AssertionError(f"module cellsight.{module} is in no layer of {__name__}.LAYERS")


def _relative(path: Path) -> str:
    return ".".join(path.relative_to(PACKAGE).with_suffix("").parts)


@pytest.mark.parametrize("path", _sources(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_functions_and_classes_are_small(path: Path):
    tree = ast.parse(path.read_text())
    long = [f"{node.name} ({node.end_lineno - node.lineno + 1} lines)"
            for node in ast.walk(tree)
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not _is_jitted(node)
            and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES]
    big = [f"{node.name} ({n} methods)" for node in ast.walk(tree)
           if isinstance(node, ast.ClassDef)
           and (n := sum(isinstance(b, ast.FunctionDef) for b in node.body)) > MAX_CLASS_METHODS]
    assert not long and not big, f"{path.name}: too long: {long}; too many methods: {big}"


@pytest.mark.parametrize("path", _sources(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_only_go_down_the_layers(path: Path):
    own = _layer(_relative(path))
    upward = []
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            if name.startswith("cellsight.") and _layer(name.removeprefix("cellsight.")) > own:
                upward.append(name)
    assert not upward, f"cellsight.{_relative(path)} (layer {own}) imports upward: {upward}"
