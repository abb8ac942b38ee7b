"""A URDF found and read safely (for :mod:`.urdf`).

``package://NAME/path`` resolves through the cell file's ``packages`` map (a folder, or
``python://MODULE/sub/path`` inside an installed Python package), else through an installed
package's share folder (``<prefix>/share/NAME``, also the ``cmeel.prefix`` of wheels such as
``example-robot-data``). Other relative paths are relative to the URDF file.

Hostile input is refused before yourdfpy sees it (one :class:`UrdfError` line naming the URDF
and the element): XML that is not well-formed (a file cut off, not XML, an undefined entity;
yourdfpy would otherwise fall back on a recovering parser that drops what it cannot read), a
``DOCTYPE`` (no entity is ever declared, so none expands), a number that is not finite or a
list of the wrong length in an ``origin``, ``axis``, geometry size, mesh ``scale`` or joint
``limit``, two links or two joints of one name, a cylinder or sphere not of positive size.
"""

from __future__ import annotations

import importlib.util
import io
import logging
import site
import sys
import warnings
from collections import Counter
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from cellsight.errors import CellsightError, short_repr

# Numeric attributes checked in the XML: element tag -> (attribute, count (None: 1 or 3),
# required). yourdfpy also takes commas as separators.
_NUMBERS: dict[str, tuple[tuple[str, int | None, bool], ...]] = {
    "origin": (("xyz", 3, False), ("rpy", 3, False)),
    "axis": (("xyz", 3, False),),
    "box": (("size", 3, True),),
    "cylinder": (("radius", 1, True), ("length", 1, True)),
    "sphere": (("radius", 1, True),),
    "mesh": (("scale", None, False),),
    "limit": (("lower", 1, False), ("upper", 1, False), ("velocity", 1, False)),
}


class UrdfError(CellsightError, ValueError):
    """A URDF robot cannot be built; ``field`` is the ``urdf`` sub-field at fault (``file``,
    ``geometry`` or ``flange``)."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        super().__init__(message)


def installed_package_folder(name: str) -> Path | None:
    """The share folder of an installed package ``name`` (``<prefix>/share/<name>`` or
    ``<site-packages>/cmeel.prefix/share/<name>``), else the folder of an importable Python
    package ``name`` (such as ``rtbdata``), or None."""
    roots = [Path(sys.prefix) / "share"]
    for sp in [*site.getsitepackages(), *sys.path]:
        roots.append(Path(sp) / "cmeel.prefix" / "share")
    for root in roots:
        if (root / name).is_dir():
            return root / name
    return python_package_folder(name)


def python_package_folder(name: str) -> Path | None:
    """The folder of the importable Python package ``name`` (not imported), or None."""
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def package_folder(value: str, folder: Path) -> Path:
    """A ``packages`` map's folder: ``python://MODULE/sub/path`` inside an installed Python
    package (portable: wherever it is installed), else a path relative to ``folder``; a
    :class:`UrdfError` (field ``packages``) for a Python package not installed."""
    if not value.startswith("python://"):
        return folder / value
    name, _, rest = value[len("python://"):].partition("/")
    root = python_package_folder(name)
    if root is None:
        raise UrdfError("packages", f"{value}: no installed Python package {name!r}")
    return root / rest


def resolve_uri(uri: str, packages: Mapping[str, Path], folder: Path) -> Path:
    """A URDF file name as a path: ``package://NAME/rest`` (``packages`` first, then an
    installed package), ``file://`` or a path relative to ``folder``; a :class:`UrdfError`
    (field ``file``) for an unknown package."""
    if uri.startswith("package://"):
        name, _, rest = uri[len("package://"):].partition("/")
        root = packages.get(name) or installed_package_folder(name)
        if root is None:
            raise UrdfError("file", f"{uri}: unknown package {name!r} (give it in the cell "
                            f"file's 'packages' map, or install it); known: {sorted(packages)}")
        return Path(root) / rest
    if uri.startswith("file://"):
        return Path(uri[len("file://"):])
    return folder / uri


def _where(element) -> str:
    """Where an element sits in a URDF: ``link 'arm', collision 0, origin`` (link and joint by
    name, collision and visual by index among their like, as in the geometry errors)."""
    parts = []
    while element.getparent() is not None:
        tag, parent = element.tag, element.getparent()
        if tag in ("link", "joint"):
            parts.append(f"{tag} {element.get('name')!r}")
        elif tag in ("collision", "visual"):
            parts.append(f"{tag} {parent.findall(tag).index(element)}")
        else:
            parts.append(tag)
        element = parent
    return ", ".join(reversed(parts))


def _check_numbers(root, path: Path) -> None:
    """Refuses a non-finite number, or a list of the wrong length, in the ``_NUMBERS``
    attributes of the links and joints."""
    for top in root.iterchildren("link", "joint"):
        for element in top.iter(*_NUMBERS):
            for attr, count, required in _NUMBERS[element.tag]:
                text = element.get(attr)
                if text is None and not required:
                    continue
                words = (text or "").replace(",", " ").split()
                try:
                    values = np.array(words, dtype=float)
                except ValueError:
                    values = np.array([np.nan])
                counts = (1, 3) if count is None else (count,)
                if len(values) not in counts or not np.all(np.isfinite(values)):
                    wanted = " or ".join(map(str, counts))
                    raise UrdfError("file", f"URDF file {path}: {_where(element)} {attr}="
                                    f"{short_repr(text)} is not {wanted} finite number(s)")


def _read_xml(path: Path):
    """The root element of a URDF file parsed strictly: well-formed XML, no ``DOCTYPE`` (so no
    entity declared or expanded, no DTD or network read), finite numbers (``_NUMBERS``)."""
    from lxml import etree

    parser = etree.XMLParser(resolve_entities=False, load_dtd=False, no_network=True,
                             remove_blank_text=True)
    try:
        tree = etree.parse(str(path), parser)
    except etree.XMLSyntaxError as exc:
        raise UrdfError("file", f"URDF file {path}: not well-formed XML ({exc.msg[:100]}); "
                        f"a file cut off or not XML is refused") from exc
    if tree.docinfo.doctype:
        raise UrdfError("file", f"URDF file {path}: has a DOCTYPE "
                        f"({short_repr(tree.docinfo.doctype)}); a URDF declares no DTD or "
                        f"entity")
    root = tree.getroot()
    _check_numbers(root, path)
    return root


@contextmanager
def _silenced() -> Iterator[None]:
    """yourdfpy's log records and Python's warnings kept off stderr while yourdfpy reads a URDF
    (its complaints come back as exceptions, reported as one line)."""
    log = logging.getLogger("yourdfpy")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        log.setLevel(level)


def _parse(path: Path):
    """The yourdfpy robot model of a URDF file (meshes not loaded), read from the element tree
    of :func:`_read_xml`."""
    import yourdfpy
    from lxml import etree

    if not path.is_file():
        raise UrdfError("file", f"URDF file {path} does not exist (or is not a file)")
    text = etree.tostring(_read_xml(path))
    try:
        with _silenced():
            urdf = yourdfpy.URDF.load(io.BytesIO(text), build_scene_graph=False,
                                      load_meshes=False, build_collision_scene_graph=False,
                                      load_collision_meshes=False)
    except Exception as exc:  # yourdfpy raises anything on bad input
        detail = str(exc).splitlines()[0][:100] if str(exc) else type(exc).__name__
        raise UrdfError("file", f"URDF file {path}: not a readable URDF ({detail})") from exc
    return urdf.robot


def _tree(robot, path: Path) -> tuple[str, dict[str, list]]:
    """The root link and each link's child joints; refuses a URDF that is not one tree, or
    two links (two joints) of one name."""
    names = [lk.name for lk in robot.links]
    for kind, named in (("links", names), ("joints", [j.name for j in robot.joints])):
        twice = sorted(n for n, k in Counter(named).items() if k > 1)
        if twice:
            raise UrdfError("file", f"URDF file {path}: two {kind} named {twice[0]!r}; "
                            f"{kind} must have unique names")
    children: dict[str, list] = {n: [] for n in names}
    child_links = set()
    for j in robot.joints:
        if j.parent not in children or j.child not in children:
            raise UrdfError("file", f"URDF file {path}: joint {j.name!r} names a missing link")
        children[j.parent].append(j)
        child_links.add(j.child)
    roots = [n for n in names if n not in child_links]
    if len(roots) != 1 or len(child_links) != len(robot.joints):
        raise UrdfError("file", f"URDF file {path}: links must form one tree (roots: {roots})")
    return roots[0], children


def urdf_files(path: Path, geometry: str = "collision",
               packages: Mapping[str, Path] | None = None) -> list[Path]:
    """The URDF file in ``path`` and the mesh files of its ``geometry`` (``collision`` or
    ``visual``) elements, in link order: what a robot built from it was read from."""
    robot = _parse(path)
    files = [path]
    for link in robot.links:
        for element in (link.collisions if geometry == "collision" else link.visuals):
            mesh = element.geometry.mesh if element.geometry is not None else None
            if mesh is not None:
                files.append(resolve_uri(mesh.filename, dict(packages or {}), path.parent))
    return files
