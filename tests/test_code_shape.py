"""The shape of the code (issue 13): small functions, small classes, imports that only go
down the layers. Read from the source with :mod:`ast`; nothing is imported or run."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "cellsight"
MAX_FUNCTION_LINES = 60  # outside the numba kernels, whose loops are written out
MAX_CLASS_METHODS = 15  # a class stays below it: one at the cap has no room to grow
MAX_CLASS_LINES = 250
MAX_MODULE_LINES = 500  # outside the modules of compiled kernels, whose loops are written out
MAX_TRACKING_LINES = 400  # a tracking module, kernels included (issue 61)
MAX_TRACKER_LINES = 200  # the Tracker: a short loop over its parts

# Lowest first: a module may import from its own layer and the ones before it, never after.
LAYERS = [
    {"errors", "fields", "rates", "threads", "geometry"},
    {"camera", "_camera_kernel", "kinematics", "visibility", "trackers"},
    {"model"},
    {"occlusion", "tracking", "control"},
    {"world", "framelog", "runfolder", "realism"},
    {"report"},
    {"session"},
    {"experiments", "sweep", "view", "export", "placement", "recording", "calibration"},
    {"cli", "commands", "__init__", "__main__", "data"},
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
           and (n := sum(isinstance(b, ast.FunctionDef) for b in node.body)) >= MAX_CLASS_METHODS]
    assert not long and not big, f"{path.name}: too long: {long}; too many methods: {big}"
    tall = [f"{node.name} ({n} lines)" for node in ast.walk(tree)
            if isinstance(node, ast.ClassDef)
            and (n := node.end_lineno - node.lineno + 1) > MAX_CLASS_LINES]
    kernels = any(_is_jitted(node) for node in ast.walk(tree)
                  if isinstance(node, ast.FunctionDef))
    lines = len(path.read_text().splitlines())
    assert not tall, f"{path.name}: classes over {MAX_CLASS_LINES} lines: {tall}"
    assert kernels or lines <= MAX_MODULE_LINES, \
        f"{path.name}: {lines} lines, over {MAX_MODULE_LINES} (split it by idea)"
    if path.parent.name == "tracking" or path.parent.parent.name == "tracking":
        assert lines <= MAX_TRACKING_LINES, f"{path.name}: {lines} lines, over {MAX_TRACKING_LINES}"


def test_the_tracker_is_a_short_loop():
    tree = ast.parse((PACKAGE / "tracking" / "tracker.py").read_text())
    tracker = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Tracker")
    assert tracker.end_lineno - tracker.lineno + 1 <= MAX_TRACKER_LINES


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


# Within a layer, arrows that would point the wrong way: what a real cell's data goes through
# (recordings, exports) never needs the simulator or the experiments, nor the tracker the
# controller.
NEVER = {"recording": {"world", "experiments"}, "export": {"world", "experiments"},
         "tracking": {"control"}}
MAX_PARAMETERS = 8  # a function's, self aside, outside the compiled kernels


def _imports(path: Path) -> list[str]:
    """Every ``cellsight`` module ``path`` imports, at the top or inside a function, with
    the names it imports from each (``cellsight.a.b`` for ``from cellsight.a import b``)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names += [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
        elif isinstance(node, ast.Import):
            names += [a.name for a in node.names]
    return [n.removeprefix("cellsight.") for n in names if n.startswith("cellsight.")]


def test_the_wrong_way_arrows_stay_gone():
    found = {_relative(path): wrong for path in _sources()
             if (top := _relative(path).split(".")[0]) in NEVER
             and (wrong := sorted({n for n in _imports(path) if n.split(".")[0] in NEVER[top]}))}
    assert not found, f"imports that point the wrong way: {found}"


def test_no_import_cycle_anywhere():
    """Module by module, lazy imports and type-checking ones included: no cycle."""
    modules = {_relative(p).removesuffix(".__init__"): p for p in _sources()}
    graph = {m: {n for n in _imports(p) if n in modules and n != m} for m, p in modules.items()}
    state: dict[str, int] = {}  # 1: on the path, 2: done

    def cycle_from(m: str, path: list[str]) -> list[str] | None:
        state[m] = 1
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return [*path[path.index(n):], n] if n in path else [m, n]
            if n not in state and (found := cycle_from(n, [*path, n])):
                return found
        state[m] = 2
        return None

    cycles = [c for m in sorted(modules) if m not in state and (c := cycle_from(m, [m]))]
    assert not cycles, f"import cycles: {cycles}"


def test_functions_take_few_parameters():
    many = []
    for path in _sources():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not _is_jitted(node):
                args = node.args
                named = [a.arg for a in args.posonlyargs + args.args]
                n = len(named) + len(args.kwonlyargs) - (named[:1] in (["self"], ["cls"]))
                if n > MAX_PARAMETERS:
                    many.append(f"{_relative(path)}.{node.name} ({n})")
    assert not many, f"functions of more than {MAX_PARAMETERS} parameters: {many}"


def test_metrics_json_is_opened_only_in_the_run_folder_package():
    """``metrics.json`` has one writer and one reader (:mod:`cellsight.runfolder.metrics`):
    no other module names the file in code (messages and docstrings may)."""
    outside = [str(path.relative_to(PACKAGE)) for path in _sources()
               if path.parent.name != "runfolder"
               and any(isinstance(node, ast.Constant) and node.value == "metrics.json"
                       for node in ast.walk(ast.parse(path.read_text())))]
    assert not outside, f"metrics.json opened outside cellsight/runfolder/: {outside}"


REPO = PACKAGE.parent
WRITTEN = {"summary.md", "report.md"}  # files the tool writes (sweep, place-cameras), not cited
DOCUMENT = re.compile(r"(?<![\w/.-])((?:\.\./)?[\w/.-]*\w\.(?:md|txt|rst|pdf))\b")
OUTSIDE = re.compile(r"\.\./shared|METHOD-NOTES|METHOD_NOTES")


def _cited(text: str) -> list[str]:
    """The documents ``text`` names that the repository does not hold (by path from its root,
    or by file name), and any name of the project's papers kept outside it."""
    names = {p.name for top in ("cellsight", "docs", "tests", "bench", "scripts")
             for p in (REPO / top).rglob("*")} | {p.name for p in REPO.iterdir()}
    missing = [d for d in DOCUMENT.findall(text)
               if Path(d).name not in WRITTEN and not (REPO / d).exists()
               and Path(d).name not in names]
    return missing + OUTSIDE.findall(text)


def test_code_and_readme_cite_only_what_the_repository_holds():
    """The code, the README and the design cite only files the repository holds (the other
    pages' links are checked by the strict documentation build, which knows the generated
    pages)."""
    cited = {str(path.relative_to(REPO)): found
             for path in [*_sources(), REPO / "README.md", REPO / "docs" / "design.md"]
             if (found := _cited(path.read_text()))}
    links = re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", (REPO / "README.md").read_text())
    broken = [link for link in links if not (REPO / link).exists()]
    assert not cited and not broken, f"cites files outside the repository: {cited}; " \
                                     f"README links to missing files: {broken}"


def test_the_design_names_only_existing_files_and_every_module():
    """docs/design.md finds each idea in one step: every file it names exists, and it names
    every module of the package (``pkg/module.py``, or a top-level ``module.py``)."""
    text = (REPO / "docs" / "design.md").read_text()
    named = set(re.findall(r"`((?:cellsight/|tests/)?[\w/]+\.(?:py|yaml))`", text))
    missing = [n for n in named if not (PACKAGE / n).exists() and not (REPO / n).exists()]
    modules = {_relative(p).replace(".", "/") + ".py" for p in _sources()
               if p.name != "__init__.py"}
    unnamed = sorted(m for m in modules if m not in named and not any(
        n.endswith("/" + m) for n in named))
    assert not missing and not unnamed, f"docs/design.md names missing files {missing}; " \
                                        f"does not name {unnamed}"


WRITES = re.compile(r"\.(write_text|write_bytes|savefig|imwrite)\("
                    r"|\bopen\([^)]*[\"'][wax]b?\+?[\"']|\.open\([\"'][wax]")
OWN_WRITERS = {
    "runfolder/writes.py": "the one place",
    "runfolder/framelog.py": "frames.csv, written row by row; its failures go to RunWrites",
    "geometry/mesh_cache.py": "the mesh cache, outside any output folder, atomically",
    "occlusion/scale_cells.py": "the benchmark's generated cells",
    "model/calibration.py": "calibration files, written into cameras --write's staged folder",
}


def test_every_file_is_written_through_the_one_place():
    """Output files go through runfolder/writes.py (whole or not at all, a failure named and
    recorded in the run); the few modules that write on their own are listed with why."""
    found = {}
    for path in _sources():
        name = str(path.relative_to(PACKAGE))
        lines = [n for n, line in enumerate(path.read_text().splitlines(), 1)
                 if WRITES.search(line)]
        if lines and name not in OWN_WRITERS:
            found[name] = lines
    assert not found, f"files written outside cellsight/runfolder/writes.py: {found}"
    assert all((PACKAGE / name).exists() for name in OWN_WRITERS)
