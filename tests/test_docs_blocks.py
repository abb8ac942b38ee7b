"""Every code block of the README and of the documentation pages, checked against the code, so
that the documentation cannot drift from it:

- ``python`` blocks run, a page's blocks in order in one namespace, in a fresh folder; a block
  preceded by ``<!-- test: tests/test_NAME.py -->`` needs set-up the page does not show (images
  from cameras) and is run by that test, which must exist and name the page;
- ``sh`` blocks: every ``cellsight ...`` command is parsed by cellsight's own argument parser
  (not run) and every ``make TARGET`` names a target of the Makefile;
- ``yaml`` blocks parse as YAML.

Output shown to the reader goes in ``text`` blocks, which are not checked.
"""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest
import yaml

from cellsight.cli import build_parser

REPO = Path(__file__).resolve().parent.parent
DOCS = REPO / "docs"
FENCE = re.compile(r"^(?P<indent>[ ]*)```(?P<lang>[\w-]*)[^\n]*\n(?P<body>.*?)^(?P=indent)```",
                   re.DOTALL | re.MULTILINE)
TESTED_BY = re.compile(r"<!--\s*test:\s*(\S+)\s*-->\s*$")


def pages() -> list[Path]:
    """The README and every hand-written page of the documentation (not the generated ones)."""
    found = [REPO / "README.md", *sorted(DOCS.rglob("*.md"))]
    return [p for p in found if "tutorials" not in p.relative_to(REPO).parts]


def blocks(page: Path, lang: str) -> list[tuple[int, str, str | None]]:
    """``page``'s fenced blocks of ``lang``: (line, code, the test that runs it or None)."""
    text = page.read_text()
    found = []
    for match in FENCE.finditer(text):
        if match.group("lang") != lang:
            continue
        indent = len(match.group("indent"))
        code = "\n".join(line[indent:] for line in match.group("body").splitlines())
        before = text[:match.start()].rstrip().splitlines()
        tested = TESTED_BY.search(before[-1]) if before else None
        found.append((text.count("\n", 0, match.start()) + 1, code,
                      tested.group(1) if tested else None))
    return found


def _ids(paths: list[Path]) -> list[str]:
    return [str(p.relative_to(REPO)) for p in paths]


def commands(code: str) -> list[str]:
    """The shell commands of a ``sh`` block: continuation lines joined, comments dropped."""
    joined = re.sub(r"\s*\\\n\s*", " ", code)
    lines = [line.split(" #")[0].strip() for line in joined.splitlines()]
    return [line.removeprefix("$ ") for line in lines if line and not line.startswith("#")]


PYTHON_PAGES = [p for p in pages() if blocks(p, "python")]
SH_PAGES = [p for p in pages() if blocks(p, "sh")]
YAML_PAGES = [p for p in pages() if blocks(p, "yaml")]


@pytest.mark.parametrize("page", PYTHON_PAGES, ids=_ids(PYTHON_PAGES))
def test_python_blocks_run(page: Path, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__docs__"}
    for line, code, tested_by in blocks(page, "python"):
        if tested_by:
            test = REPO / tested_by
            assert test.is_file(), f"{page.name}:{line}: {tested_by} does not exist"
            assert str(page.relative_to(REPO)) in test.read_text(), \
                f"{page.name}:{line}: {tested_by} does not name {page.relative_to(REPO)}"
            continue
        with contextlib.redirect_stdout(io.StringIO()):
            exec(compile(code, f"{page}:{line}", "exec"), namespace)


@pytest.mark.parametrize("page", SH_PAGES, ids=_ids(SH_PAGES))
def test_shell_commands_parse(page: Path) -> None:
    parser = build_parser()
    targets = set(re.findall(r"^([\w-]+):", (REPO / "Makefile").read_text(), re.MULTILINE))
    for line, code, _ in blocks(page, "sh"):
        for command in commands(code):
            words = shlex.split(command)
            if words[0] == "cellsight":
                try:
                    with contextlib.redirect_stderr(io.StringIO()) as err:
                        parser.parse_args(words[1:])
                except SystemExit as exc:
                    raise AssertionError(f"{page.name}:{line}: {command!r} does not parse: "
                                         f"{err.getvalue().strip()}") from exc
            elif words[0] == "make":
                missing = [w for w in words[1:] if "=" not in w and w not in targets]
                assert not missing, f"{page.name}:{line}: no make target {missing}"


@pytest.mark.parametrize("page", YAML_PAGES, ids=_ids(YAML_PAGES))
def test_yaml_blocks_parse(page: Path) -> None:
    for line, code, _ in blocks(page, "yaml"):
        try:
            yaml.safe_load(code)
        except yaml.YAMLError as exc:
            raise AssertionError(f"{page.name}:{line}: not YAML: {exc}") from exc


def test_the_checks_find_what_they_check(tmp_path) -> None:
    """The block finder sees every kind of block, indented ones too (in a list item), and the
    marker that hands a block to another test."""
    text = ("a\n\n```python\nx = 1\n```\n\n1. item\n\n   ```sh\n   cellsight cells\n   ```\n"
            "<!-- test: tests/test_x.py -->\n```python\ny = 2\n```\n")
    page = tmp_path / "probe.md"
    page.write_text(text)
    assert [(c, t) for _, c, t in blocks(page, "python")] == [
        ("x = 1", None), ("y = 2", "tests/test_x.py")]
    assert [c for _, c, _ in blocks(page, "sh")] == ["cellsight cells"]
    assert commands("cellsight run 3 \\\n  --seed 1  # a comment\n# only a comment\n$ make demo") \
        == ["cellsight run 3 --seed 1", "make demo"]
