"""Collisions in the simulated cell: every contact that is not the grasp is an event, never silent.

After each control step MuJoCo's collision detection (``mj_collision``, meshes as their convex
hulls) lists the geoms in contact. A contact counts when the geoms overlap by more than
``depth_m`` and it is none of these:

- two solids of the same robot (its links overlap at the joints by construction, and its own
  controller keeps it clear of itself);
- a mount (:func:`mount_pairs`): a pair of objects already touching at the start (a robot's
  base on the floor), or a robot's base or carriage and a fixed object within
  :data:`MOUNT_GAP_M` of it at the start (a carriage in its track: the track, set up by eye,
  a little out of line with the carriage's travel, whose contact the travel makes and
  breaks);
- a gripper's palm and the workpiece its jaws clamp or hold (the grasp);
- a gripper's jaw and any workpiece: the jaws straddle and clamp parts, and MuJoCo's convex
  hull of a non-convex part swallows them (so a jaw hitting a part is not detected; the palm
  hitting one is).

Each counted pair of objects (named by their labels: ``R6AX.link4``, ``table``, ``part``,
``unknown.forearm``) gives one :class:`Collision` per episode of contact: when it began and
ended (s) and its deepest overlap (m). An episode ends once the pair has been apart for
:data:`APART_S`: a resting contact that flickers on and off from one control step to the next
(a gripper pressing on the conveyor, its contact pushed back and made again) is one episode,
not hundreds; its ``end`` is the first check at which they were apart.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from cellsight.model import Cell
from cellsight.world.mjcf import body_name
from cellsight.world.scene import Scene

APART_S = 0.1
"""How long (s) two objects must be apart for their episode of contact to end."""

MOUNT_GAP_M = 0.005
"""How far (m) a robot's base or carriage may be from a fixed object at the start for the pair
to be a mount (:func:`mount_pairs`): a track 0.06 deg out of line with a carriage's travel (the
`harsh` profile's base rotation, 1 sigma) rises or falls 1 mm over a metre of it."""


@dataclass
class Collision:
    """One episode of contact between two objects (module docstring); ``end`` None while it
    lasts."""

    bodies: tuple[str, str]
    start: float
    depth_m: float
    end: float | None = None

    def as_dict(self) -> dict:
        return {"bodies": list(self.bodies), "t_start_s": round(self.start, 3),
                "t_end_s": None if self.end is None else round(self.end, 3),
                "depth_mm": round(1e3 * self.depth_m, 2)}


class ContactMonitor:
    """Finds the collisions of the module docstring. ``grasps``: robot name -> the workpiece
    its gripper clamps or holds (None), asked at each check."""

    def __init__(self, scene: Scene, cell: Cell, depth_m: float,
                 grasps: Callable[[str], str | None]) -> None:
        self.scene, self.depth_m, self._grasps = scene, float(depth_m), grasps
        model = scene.model
        index = {o.name: i for i, o in enumerate(cell.objects)}
        self._label, self._robot, self._tool, self._jaw, self._part = [], [], [], [], []
        for g in range(model.ngeom):
            i = index.get(model.geom(g).name)
            obj = None if i is None else cell.objects[i]
            self._label.append(obj.label if obj else model.geom(g).name)
            self._robot.append(obj.robot if obj else None)
            self._tool.append(obj is not None and obj.kind == "tool")
            self._jaw.append(i is not None and cell.frames[i].kind == "jaw")
            self._part.append(obj is not None and obj.kind == "workpiece")
        self._tool_robots = [r.name for r in cell.robots if r.tool is not None]
        robots = {r.name: i for i, r in enumerate(cell.robots)}
        robot_of = np.array([robots.get(r, -1) for r in self._robot])  # -1: no robot
        lower, upper = robot_of[:, None], robot_of[None, :]
        # [g1, g2] with g1 < g2: the pair may count (not two solids of one robot, not a mount)
        self._counts = (lower != upper) | (lower < 0)
        self._open: dict[tuple[str, str], Collision] = {}
        self._apart_since: dict[tuple[str, str], float] = {}  # open episodes not in contact
        self.collisions: list[Collision] = []
        for g1, g2 in mount_pairs(scene, cell):
            self._counts[g1, g2] = False

    def check(self, t: float) -> None:
        """Record the contacts at time ``t`` (s) into :attr:`collisions`."""
        pairs = self._geom_pairs(self.depth_m)
        held = {robot: self._grasps(robot) for robot in self._tool_robots} if pairs else {}
        now: dict[tuple[str, str], float] = {}
        for key, depth in pairs:
            if self._is_grasp(*key, held):
                continue
            names = self._names(key)
            now[names] = max(depth, now.get(names, 0.0))
        for pair, depth in now.items():
            self._apart_since.pop(pair, None)
            if pair in self._open:
                self._open[pair].depth_m = max(self._open[pair].depth_m, depth)
            else:
                self._open[pair] = Collision(pair, t, depth)
                self.collisions.append(self._open[pair])
        for pair in [p for p in self._open if p not in now]:
            since = self._apart_since.setdefault(pair, t)
            if t - since >= APART_S:
                self._open.pop(pair).end = self._apart_since.pop(pair)

    def _geom_pairs(self, depth: float) -> list[tuple[tuple[int, int], float]]:
        """((geom, geom) in increasing order, overlap m) of every contact deeper than ``depth``
        (m) between geoms of different robots (or of no robot), mounts left out once known."""
        self.scene.sync()
        model, data = self.scene.model, self.scene.data
        mujoco.mj_collision(model, data)
        contacts = data.contact
        dist = contacts.dist
        deep = np.flatnonzero(-dist > depth)
        if not deep.size:
            return []
        geoms = np.sort(contacts.geom[deep], axis=1)
        keep = self._counts[geoms[:, 0], geoms[:, 1]]
        if not keep.any():
            return []
        return [((int(a), int(b)), -float(d)) for (a, b), d in
                zip(geoms[keep], dist[deep][keep], strict=True)]

    def _is_grasp(self, g1: int, g2: int, held: dict[str, str | None]) -> bool:
        if (self._jaw[g1] and self._part[g2]) or (self._jaw[g2] and self._part[g1]):
            return True
        for tool, other in ((g1, g2), (g2, g1)):
            if self._tool[tool] and held.get(self._robot[tool]) == self._label[other]:
                return True
        return False

    def _names(self, pair: tuple[int, int]) -> tuple[str, str]:
        return tuple(sorted((self._label[pair[0]], self._label[pair[1]])))

    def report(self) -> list[dict]:
        """Every collision so far, as plain data for ``metrics.json`` (an episode whose
        objects are apart now, for less than :data:`APART_S`, ends when they parted)."""
        out = [c.as_dict() for c in self.collisions]
        for c, d in zip(self.collisions, out, strict=True):
            if c.bodies in self._apart_since and self._open.get(c.bodies) is c:
                d["t_end_s"] = round(self._apart_since[c.bodies], 3)
        return out


def merge_episodes(collisions: list[dict], apart_s: float = APART_S) -> list[dict]:
    """``metrics.json`` collisions (:meth:`ContactMonitor.report`) with the episodes of a pair
    less than ``apart_s`` apart merged, as the monitor reports them now (for run folders
    written before episodes were merged); order of their starts."""
    merged: list[dict] = []
    last: dict[tuple[str, ...], dict] = {}
    for c in sorted(collisions, key=lambda c: c["t_start_s"]):
        pair = tuple(c["bodies"])
        prev = last.get(pair)
        if prev is not None and prev["t_end_s"] is not None and \
                c["t_start_s"] - prev["t_end_s"] < apart_s:
            prev["t_end_s"] = c["t_end_s"]
            prev["depth_mm"] = max(prev["depth_mm"], c["depth_mm"])
            continue
        last[pair] = dict(c, bodies=list(c["bodies"]))
        merged.append(last[pair])
    return merged


def mount_pairs(scene: Scene, cell: Cell) -> set[tuple[int, int]]:
    """The (geom, geom) pairs, in increasing order, that are mounts in the scene's state (the
    start): those in contact (MuJoCo's ``mj_collision``), and each robot's base and carriage
    (its bodies before its first revolute joint) with every geom fixed to the world within
    :data:`MOUNT_GAP_M` of it (``mj_geomDistance``)."""
    scene.sync()
    model, data = scene.model, scene.data
    mujoco.mj_collision(model, data)
    pairs = {(int(min(a, b)), int(max(a, b))) for a, b in data.contact.geom}
    fixed = np.flatnonzero(model.body_weldid[model.geom_bodyid] == 0)
    for robot in cell.robots:
        lead = next((i for i, p in enumerate(robot.chain.prismatic) if not p), robot.n_joints)
        for i in range(lead + 1):
            body = model.body(body_name(robot.name, i)).id
            for g in np.flatnonzero(model.geom_bodyid == body):
                pairs.update((int(min(g, f)), int(max(g, f))) for f in fixed if f != g and
                             mujoco.mj_geomDistance(model, data, int(g), int(f), MOUNT_GAP_M,
                                                    None) < MOUNT_GAP_M)
    return pairs


def mount_bodies(scene: Scene, cell: Cell) -> list[tuple[str, str]]:
    """The pairs of distinct bodies (names, sorted) of :func:`mount_pairs`."""
    model = scene.model
    return sorted({tuple(sorted((model.body(a).name, model.body(b).name)))
                   for a, b in (model.geom_bodyid[list(p)] for p in mount_pairs(scene, cell))
                   if a != b})
