"""The schema of a cell file's ``experiments`` section (for :mod:`.schema`): the grasping
robot and workpiece, or a line's picks and where they are put down, the conveyor's path, the
parts passing through the views, and the crossing robot's timed joint waypoints. Lengths m,
times s, angles rad.
"""

from __future__ import annotations

import math
from typing import Annotated

from pydantic import Field, field_validator

from cellsight.fields import about
from cellsight.model.spec_types import (
    JOINT_UNIT,
    MIN_CONVEYOR_STEP_M,
    Finite,
    Number,
    Positive,
    Vec2,
    _Strict,
)


class ConveyorSpec(_Strict):
    """The conveyor's path of the part in experiments 2 and 3: x, y points (m), speed (m/s)."""

    points: Annotated[list[Vec2], Field(min_length=2)] = about(
        ..., "The path of the part frame's origin, x, y in the cell's base frame (at least 2, "
        "each at least 1e-6 m from the last); the part keeps its nominal height and "
        "orientation.", "m")
    speed: Positive = about(..., "The part's speed along the path, until the last point or "
                            "until it is grasped.", "m/s")
    t_start: Annotated[Number, Field(ge=0, allow_inf_nan=False)] = about(
        0.0, "When the part starts moving (>= 0, from the run's start); it waits at the first "
        "point until then.", "s")

    @field_validator("points")
    @classmethod
    def _distinct(cls, points: list[Vec2]) -> list[Vec2]:
        for i in range(1, len(points)):
            if math.dist(points[i - 1], points[i]) < MIN_CONVEYOR_STEP_M:
                raise ValueError(f"points {i - 1} and {i} coincide ({list(points[i])}): each "
                                 f"point must be at least {MIN_CONVEYOR_STEP_M:g} m from the last")
        return points


class PassingSpec(_Strict):
    """A line's parts the belt carries through the views in experiments 2 and 3 without being
    picked: each from its nominal place by ``travel`` at ``speed``, from ``t_start``."""

    parts: Annotated[list[Annotated[str, Field(min_length=1)]], Field(min_length=1)] = about(
        ..., "The passing parts: workpieces of the cell, none of them picked, each once.", "-")
    travel: Vec2 = about(..., "How far each part travels from its nominal place, x, y in the "
                         "cell's base frame (at least 1e-6 m); it keeps its nominal height and "
                         "orientation, and stays at the end.", "m")
    speed: Positive = about(..., "The parts' speed along the belt.", "m/s")
    t_start: Annotated[Number, Field(ge=0, allow_inf_nan=False)] = about(
        0.0, "When the parts start moving (>= 0, from the run's start).", "s")

    @field_validator("travel")
    @classmethod
    def _moves(cls, travel: Vec2) -> Vec2:
        if math.hypot(*travel) < MIN_CONVEYOR_STEP_M:
            raise ValueError(f"travel {list(travel)} must be at least {MIN_CONVEYOR_STEP_M:g} m")
        return travel


class WaypointSpec(_Strict):
    """A timed joint waypoint: time (s) and joint vector."""

    t: Positive = about(..., "When the robot reaches q, from the run's start (> 0, after the "
                        "previous waypoint's).", "s")
    q: Annotated[list[Finite], Field(min_length=1)] = about(
        ..., "The joint vector to reach at t, one value per joint within its limits (a smooth "
        "quintic step from the previous waypoint, or from HOME).", JOINT_UNIT)


class CrossingSpec(_Strict):
    """Experiment 3: a robot's own timed joint waypoints (absolute times, s)."""

    robot: Annotated[str, Field(min_length=1)] = about(
        ..., "The crossing robot, another than the grasping one; it starts at its HOME.", "-")
    waypoints: Annotated[list[WaypointSpec], Field(min_length=1)] = about(
        ..., "Its timed joint waypoints, times increasing; it holds the last one.", "-")


class ExperimentsSpec(_Strict):
    """The experiments' setup: the grasping robot and workpiece (or a line's picks), the
    conveyor, the crossing robot and a line's passing parts."""

    robot: str | None = about(None, "The grasping robot (it needs a tool and a final); "
                              "default: the first robot with both.", "-")
    workpiece: str | None = about(None, "The part to grasp; default: the cell's first "
                                  "workpiece.", "-")
    picks: list[Annotated[str, Field(min_length=1)]] | None = about(
        None, "A line: the parts the robot picks in turn, each through Approach, Grasp, "
        "Manipulate and Release (instead of one workpiece); in experiments 2 and 3 the conveyor "
        "carries them all, the first along its path and the others keeping their places on "
        "the belt.", "-")
    place_step: Vec2 | None = about(
        None, "A line: each pick is put down at FINAL's TCP pose moved by this step (x, y in the "
        "cell's base frame) times its place in the order, the first at FINAL, so that the parts "
        "do not land on each other; default: all at FINAL.", "m")
    conveyor: ConveyorSpec | None = about(None, "The conveyor moving the part in experiments 2 "
                                          "and 3 (needed for them).", "-")
    crossing: CrossingSpec | None = about(None, "The robot crossing the cameras' views in "
                                          "experiment 3 (needed for it).", "-")
    passing: PassingSpec | None = about(
        None, "A line: parts the belt carries through the views in experiments 2 and 3, not "
        "picked (entering and leaving the views); none by default.", "-")
