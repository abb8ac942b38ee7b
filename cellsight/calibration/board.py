"""The ChArUco calibration board: its geometry, its printed image, its detection by OpenCV's
aruco module, its YAML file, and a simulated world whose robot carries it on its flange.

**Board frame** (OpenCV's own: ``CharucoBoard.getChessboardCorners()``, ``getObjPoints()``):
origin at the outer corner of the chessboard's first square (the top-left one as the printed
face is read, the top-left of :meth:`Board.texture`), x along the first row of squares
(``squares[0]`` of them, left to right as printed), y down the columns (``squares[1]``), z = x
cross y into the plate. The printed face lies in z = 0 and faces -z (:attr:`Board.face_normal`):
a camera that reads the board unmirrored looks along +z. ChArUco corner ``i`` (the inner
corners, row by row) is at ``((i mod (sx - 1) + 1) s, (i div (sx - 1) + 1) s, 0)`` for
``squares = (sx, sy)`` and ``s = square_m``. The plate is the squares plus ``margin_m`` of white
on every side, ``thickness_m`` deep behind the face (0 <= z <= thickness_m). Lengths in metres.

**Mount**: ``T_flange_board``, the board frame in the robot's flange frame (frame n of its
chain, ``robot.chain.fkine(q)[-1]``, in robot frame 0). Default: the squares centred on the
flange's z axis, the printed face facing the flange's +z, ``STANDOFF_M`` out from the flange
face (z = 0 of frame n), the board's x along the flange's x: the plate, as thick as the
standoff, sits on the flange face.

**Board file** (``cellsight calibrate --board FILE``): a YAML mapping of the fields of
:class:`BoardSpec`, each optional; a bad one is a :class:`~cellsight.errors.CellFileError`
naming the file, the field and the value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError

from cellsight.calibration.presenting import BoardOnFlange
from cellsight.errors import CellFileError
from cellsight.fields import about
from cellsight.geometry.transforms import is_rigid, make_pose, transform_points
from cellsight.model import Cell
from cellsight.model.robot import Robot
from cellsight.model.schema import PoseSpec
from cellsight.model.spec_types import Count, Number
from cellsight.model.yaml_input import load_yaml, read_cell_text
from cellsight.world import World
from cellsight.world.board_plate import Plate
from cellsight.world.world import Hands

STANDOFF_M = 0.01  # m: the default mount's printed face out from the flange face
PLATE_PX_PER_M = 20000.0  # texels per metre of the plate's texture in the world (20 per mm)
IN_CODE = "calibration board"  # the "file" a board built in code names in its errors
_HALF_TURN_X = np.diag([1.0, -1.0, -1.0])  # the default mount's rotation: z against z
_YAML_FIELD = {"T_flange_board": "mount"}  # a field's name in the board file


@dataclass(frozen=True, eq=False)
class Board:
    """A ChArUco board on a robot's flange (module docstring for its frame and its mount;
    ``T_flange_board`` None: the default mount, filled in on construction). A bad field is a
    :class:`~cellsight.errors.CellFileError` naming ``IN_CODE``, the field and the value."""

    squares: tuple[int, int] = (7, 5)
    square_m: float = 0.03
    marker_m: float = 0.022
    dictionary: str = "DICT_5X5_100"
    T_flange_board: np.ndarray | None = None
    margin_m: float = 0.01
    thickness_m: float = 0.01

    def __post_init__(self) -> None:
        sx, sy = self._checked_squares()
        for name in ("square_m", "marker_m", "margin_m", "thickness_m"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, int | float) and
                                               math.isfinite(value) and value > 0):
                raise CellFileError(IN_CODE, name, value, "a finite length > 0 (m)")
        if self.marker_m >= self.square_m:
            raise CellFileError(IN_CODE, "marker_m", self.marker_m,
                                f"less than square_m ({self.square_m} m): a marker sits inside "
                                "its square")
        names = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        if self.dictionary not in names:
            raise CellFileError(IN_CODE, "dictionary", self.dictionary,
                                f"one of OpenCV's ArUco dictionaries: {', '.join(names)}")
        have = len(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
                   .bytesList)
        if have < sx * sy // 2:
            raise CellFileError(IN_CODE, "dictionary", self.dictionary,
                                f"a dictionary of at least {sx * sy // 2} markers (one per "
                                f"white square of {sx} x {sy}); it has {have}")
        object.__setattr__(self, "T_flange_board", self._checked_mount())

    def _checked_squares(self) -> tuple[int, int]:
        squares = self.squares
        if not (isinstance(squares, tuple) and len(squares) == 2 and all(
                isinstance(n, int) and not isinstance(n, bool) and n >= 2 for n in squares)):
            raise CellFileError(IN_CODE, "squares", squares, "two whole numbers >= 2 (x, y)")
        return squares

    def _checked_mount(self) -> np.ndarray:
        """``T_flange_board`` as given (checked: a rigid 4x4), or the default mount."""
        if self.T_flange_board is None:
            sx, sy = self.squares
            centre = np.array([sx, sy, 0.0]) * self.square_m / 2
            T = make_pose(_HALF_TURN_X, np.array([0.0, 0.0, STANDOFF_M]) - _HALF_TURN_X @ centre)
        else:
            T = np.array(self.T_flange_board, dtype=float)
            if T.shape != (4, 4) or not np.isfinite(T).all() or not is_rigid(T):
                raise CellFileError(IN_CODE, "T_flange_board", self.T_flange_board,
                                    "a rigid 4x4 transform (a rotation and a translation, m)")
        T.setflags(write=False)
        return T

    @classmethod
    def from_yaml(cls, path: str | Path) -> Board:
        """The board of the YAML board file ``path`` (module docstring)."""
        file = str(path)
        if not Path(path).is_file():
            raise CellFileError(file, "<file>", file, "an existing YAML board file")
        raw = load_yaml(read_cell_text(Path(path)), file)
        if raw is None:
            raw = {}
        if not isinstance(raw, dict):
            raise CellFileError(file, "<root>", raw,
                                f"a mapping of {', '.join(BoardSpec.model_fields)}")
        try:
            spec = BoardSpec.model_validate(raw)
        except ValidationError as exc:
            err = exc.errors()[0]
            field = ".".join(str(p) for p in err["loc"]) or "<root>"
            expected = (f"one of the fields {', '.join(BoardSpec.model_fields)}"
                        if err["type"] == "extra_forbidden" else err["msg"])
            raise CellFileError(file, field, err.get("input"), expected) from exc
        given: dict[str, Any] = spec.model_dump(exclude_unset=True, exclude={"mount"})
        if spec.mount is not None:
            given["T_flange_board"] = _mount(file, spec.mount)
        try:
            return cls(**given)
        except CellFileError as exc:
            raise CellFileError(file, _YAML_FIELD.get(exc.field, exc.field), exc.value,
                                exc.expected) from exc

    def cv_board(self) -> cv2.aruco.CharucoBoard:
        """OpenCV's board (lengths in m): the same corners, ids and markers."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_m, self.marker_m, dictionary)

    def corners(self) -> np.ndarray:
        """(N, 3) m, board frame: row i is ChArUco corner id i (OpenCV's
        ``getChessboardCorners()``, in float64)."""
        sx, sy = self.squares
        ids = np.arange((sx - 1) * (sy - 1))
        return np.column_stack([(ids % (sx - 1) + 1) * self.square_m,
                                (ids // (sx - 1) + 1) * self.square_m, np.zeros(len(ids))])

    @property
    def face_normal(self) -> np.ndarray:
        """The unit normal out of the printed face, board frame: -z."""
        return np.array([0.0, 0.0, -1.0])

    def on_flange(self) -> BoardOnFlange:
        """The board as its mount puts it on the flange: its corners, face normal and outline
        in the flange frame (what the calibration's plan presents)."""
        return BoardOnFlange.from_flange(
            transform_points(self.T_flange_board, self.corners()),
            self.T_flange_board[:3, :3] @ self.face_normal,
            transform_points(self.T_flange_board, self.outline()))

    def outline(self) -> np.ndarray:
        """(4, 3) m, board frame: the printed face's corners (the plate's outline), from the
        texture's top-left corner, clockwise as the face is read."""
        sx, sy = self.squares
        lo, right, down = -self.margin_m, sx * self.square_m, sy * self.square_m
        return np.array([[lo, lo, 0.0], [right - lo, lo, 0.0], [right - lo, down - lo, 0.0],
                         [lo, down - lo, 0.0]])

    def texture(self, px_per_m: float) -> np.ndarray:
        """(H, W) uint8 grey levels of the printed face, outline to outline, at ``px_per_m``
        px per metre rounded so that a square and the margin are whole numbers of pixels
        (``round(square_m px_per_m)`` and ``round(margin_m px_per_m)``): the top-left pixel's
        outer corner is the outline's first corner, a square's edges fall on pixel edges
        (OpenCV's ``generateImage``, white margin)."""
        return self._image(round(self.square_m * px_per_m), round(self.margin_m * px_per_m))

    def _image(self, square: int, margin: int) -> np.ndarray:
        """The printed squares, ``square`` px each, in a white margin of ``margin`` px."""
        sx, sy = self.squares
        size = (sx * square + 2 * margin, sy * square + 2 * margin)
        return self.cv_board().generateImage(size, marginSize=margin, borderBits=1)

    def plate(self, px_per_m: float = PLATE_PX_PER_M) -> Plate:
        """The world's plate of this board (:mod:`cellsight.world.board_plate`), its face the
        :meth:`outline`. Its texture has a power of two of texels a square, the nearest to
        ``square_m px_per_m``, and a white margin of at least ``margin_m``, a multiple of an
        eighth of a square: the squares' edges stay on texel edges down to the mipmap level
        of 8 texels a square (:mod:`cellsight.world.board_plate`)."""
        square = 2 ** max(round(math.log2(self.square_m * px_per_m)), 3)
        scale, step = square / self.square_m, square // 8  # texels per m; margin's step
        margin = math.ceil(self.margin_m * scale / step) * step
        image = self._image(square, margin)
        inset = margin - self.margin_m * scale  # the face's edge inside the texture's
        face = (inset, inset, image.shape[1] - inset, image.shape[0] - inset)
        T_flange_face = self.T_flange_board @ make_pose(None, (-self.margin_m, -self.margin_m,
                                                               0.0))
        return Plate(image, scale, face, self.thickness_m, T_flange_face)

    @cached_property
    def _detector(self) -> cv2.aruco.CharucoDetector:
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        params.cornerRefinementMaxIterations = 100
        params.cornerRefinementMinAccuracy = 0.01
        charuco = cv2.aruco.CharucoParameters()
        charuco.tryRefineMarkers = True
        return cv2.aruco.CharucoDetector(self.cv_board(), charuco, params)

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The board's corners found in the (H, W) uint8 image ``gray`` by OpenCV's
        ``CharucoDetector`` (markers' and corners' sub-pixel refinement on): their ids (m,)
        and pixels (m, 2) (OpenCV's: the top-left pixel's centre at (0, 0)), by id. None
        (empty arrays) where the corners found lie on one line of the board (a row, a
        column, a diagonal): no pose follows from them, and one such view of six corners in a
        row sent OpenCV's calibrateCamera of a whole camera astray."""
        corners, ids, _, _ = self._detector.detectBoard(gray)
        ids = None if ids is None else ids.ravel().astype(int)
        if ids is None or _on_a_line(self.corners()[ids, :2], self.square_m):
            return np.zeros(0, dtype=int), np.zeros((0, 2))
        order = np.argsort(ids)
        return ids[order], corners.reshape(-1, 2).astype(float)[order]


def _on_a_line(points: np.ndarray, square_m: float) -> bool:
    """Whether the board points (n, 2) (m, board frame) span less than half a square (of side
    ``square_m``) across their main line: the second singular value of them, centred."""
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return bool(len(spread) < 2 or spread[1] < 0.5 * square_m)


class BoardSpec(BaseModel):
    """A board file: every field optional (default: the :class:`Board`'s); their values are
    checked by :class:`Board`."""

    model_config = ConfigDict(extra="forbid")

    squares: tuple[Count, Count] = about(
        Board.squares, "Squares of the chessboard along the board's x (a row) and its y (a "
        "column), each at least 2.", "")
    square_m: Number = about(Board.square_m, "A square's side, > 0.", "m")
    marker_m: Number = about(Board.marker_m, "An ArUco marker's side, > 0, less than square_m.",
                             "m")
    dictionary: str = about(Board.dictionary, "OpenCV's predefined ArUco dictionary, with at "
                            "least one marker per white square.", "")
    margin_m: Number = about(Board.margin_m, "The white border around the squares, > 0.", "m")
    thickness_m: Number = about(Board.thickness_m, "The plate's thickness behind the printed "
                                "face, > 0.", "m")
    mount: dict | list | None = about(
        None, "The board frame in the flange frame: {xyz, rpy} as a gripper's mount, or a 4x4 "
        "rigid transform (rows); default: the printed face 10 mm out from the flange face, "
        "facing the flange's +z, the squares centred on its axis.", "m, rad")


def _mount(file: str, value: dict | list) -> np.ndarray:
    """The board file's ``mount``: {xyz, rpy} or a 4x4 matrix (rigidity: :class:`Board`)."""
    if isinstance(value, dict):
        try:
            return PoseSpec.model_validate(value).matrix()
        except ValidationError as exc:
            err = exc.errors()[0]
            field = ".".join(["mount", *map(str, err["loc"])])
            raise CellFileError(file, field, err.get("input"), err["msg"]) from exc
    try:
        T = np.array(value, dtype=float)
    except (TypeError, ValueError):
        T = np.empty(0)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise CellFileError(file, "mount", value, "{xyz: [x, y, z], rpy: [roll, pitch, yaw]} "
                            "(m, rad) or a 4x4 rigid transform (rows of numbers)")
    return T


def _presenter(robot: Robot) -> Robot:
    """``robot`` without its tool and without its flange link's solids: a cell's last link
    solid reaches past the flange face into the gripper's palm (the built-in cells' by 40
    mm: a segment's overhang), where it would stick through the board."""
    links = robot.solid_links
    return replace(robot, tool=None, link_solids=robot.link_solids[:-1] + ((),),
                   solid_links=None if links is None else links[:-1] + ((),))


def board_world(cell: Cell, robot: str, board: Board, **world: Any) -> World:
    """A :class:`~cellsight.world.World` of ``cell`` whose robot ``robot`` carries ``board`` on
    its flange in place of its gripper (:func:`_presenter`); ``world``: the World's other
    keyword arguments (seed, errors, render_size, initial_joints...)."""
    cell.robot(robot)  # a KeyError naming the cell's robots
    robots = [_presenter(r) if r.name == robot else r for r in cell.robots]
    bare = Cell(cell.name, robots, cell.workpieces, cell.static, cell.cameras, cell.source,
                cell.experiments, cell.files)
    return World(bare, hands=Hands(plates={robot: board.plate()}), **world)
