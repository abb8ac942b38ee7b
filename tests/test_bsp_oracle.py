"""BSP visibility against the independent oracle on >= 20,000 random seeded cases per run.

A case is one (scene, viewpoint, point) query. Cases the oracle marks ambiguous (crossing within
a small distance of a polygon's edge, point or viewpoint within a small band off a plane) are
left out, and the left-out fraction must stay small. Every other case must agree exactly on the
visible flag, and a hidden point's occluder must be the first polygon crossed from the
viewpoint (a tie in the crossing parameter accepted).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest
from oracle import (
    embree_visible,
    random_convex_solid,
    random_prism,
    random_soup,
    segment_oracle,
)

from cellsight.occlusion import BSPTree, PolygonSoup

MAX_LEFT_OUT = 0.02


@dataclass
class Tally:
    """Counts of compared / left-out / hidden cases and the disagreements found."""

    cases: int = 0
    left_out: int = 0
    hidden: int = 0
    errors: list[str] = field(default_factory=list)

    def check(self, minimum: int) -> None:
        """Zero disagreements, enough cases, few left out, a non-trivial hidden share."""
        assert not self.errors, f"{len(self.errors)} disagreements, first: {self.errors[:5]}"
        assert self.cases >= minimum, f"only {self.cases} cases"
        assert self.left_out <= MAX_LEFT_OUT * self.cases, f"left out {self.left_out}/{self.cases}"
        kept = self.cases - self.left_out
        assert 0.05 * kept < self.hidden < 0.95 * kept, f"hidden {self.hidden}/{kept}: trivial"


def compare(tally: Tally, polygons, points, viewpoints, label: str) -> None:
    """Compare BSP and oracle for every viewpoint; record disagreements in ``tally``."""
    tree = BSPTree.build(PolygonSoup.from_polygons(polygons))
    for view in viewpoints:
        visible, occluder = tree.visibility(points, view)
        answer = segment_oracle(polygons, points, view)
        keep = ~answer.ambiguous
        tally.cases += len(points)
        tally.left_out += int((~keep).sum())
        tally.hidden += int((keep & ~answer.visible).sum())
        for i in np.flatnonzero(keep & (visible != answer.visible)):
            tally.errors.append(f"{label}: point {i} bsp {visible[i]} oracle {answer.visible[i]}")
        for i in np.flatnonzero(keep & ~answer.visible & (occluder != answer.occluder)):
            if occluder[i] < 0 or not answer.hits[i, occluder[i]] or not np.isclose(
                answer.t[i, occluder[i]], answer.t[i, answer.occluder[i]], rtol=0, atol=1e-9
            ):
                tally.errors.append(
                    f"{label}: point {i} occluder bsp {occluder[i]} oracle {answer.occluder[i]}"
                )


def outside_viewpoints(rng: np.random.Generator, centre, count: int, near: float, far: float):
    """Viewpoints at random directions and distances in [near, far] from ``centre``."""
    direction = rng.normal(size=(count, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return np.asarray(centre) + direction * rng.uniform(near, far, (count, 1))


def random_solid(rng: np.random.Generator, centre, size: float):
    """A convex hull solid or a non-convex prism, equally likely."""
    make = random_convex_solid if rng.random() < 0.5 else random_prism
    return make(rng, centre, size)


def test_random_soups():
    """Convex, star and L polygons, random orientations; free points and polygon vertices."""
    rng = np.random.default_rng(1001)
    tally = Tally()
    for scene in range(250):
        polygons = random_soup(rng, int(rng.integers(5, 40)))
        corners = np.concatenate(polygons)
        points = np.concatenate(
            [rng.uniform(-1.5, 1.5, (36, 3)), corners[rng.choice(len(corners), 8)]]
        )
        compare(tally, polygons, points, rng.uniform(-2.5, 2.5, (1, 3)), f"soup {scene}")
    tally.check(10_000)


@pytest.mark.parametrize("kind", ["convex", "prism"])
def test_single_solid_self_occlusion(kind):
    """One closed solid, points on its vertices, viewpoints all around."""
    rng = np.random.default_rng(2002 if kind == "convex" else 2003)
    make = random_convex_solid if kind == "convex" else random_prism
    tally = Tally()
    for scene in range(150):
        faces, vertices = make(rng, rng.uniform(-1, 1, 3), rng.uniform(0.5, 1.5))
        views = outside_viewpoints(rng, vertices.mean(0), 4, 1.5, 5.0)
        compare(tally, faces, vertices, views, f"{kind} {scene}")
    tally.check(4_000)


def test_several_solids_mutual_occlusion():
    """Several solids (may interpenetrate), their vertices plus free points, outside views."""
    rng = np.random.default_rng(3004)
    tally = Tally()
    for scene in range(80):
        faces, vertices = [], []
        for _ in range(int(rng.integers(3, 7))):
            f, v = random_solid(rng, rng.uniform(-1.5, 1.5, 3), rng.uniform(0.4, 1.0))
            faces += f
            vertices.append(v)
        points = np.concatenate(vertices + [rng.uniform(-2, 2, (20, 3))])
        views = outside_viewpoints(rng, np.zeros(3), 2, 3.0, 6.0)
        compare(tally, faces, points, views, f"solids {scene}")
    tally.check(6_000)


def test_oracle_agrees_with_embree():
    """The oracle itself against float32 ray casts, away from edges and planes (1e-4 band)."""
    rng = np.random.default_rng(4005)
    compared = 0
    for _ in range(40):
        polygons = random_soup(rng, int(rng.integers(5, 30)))
        points = rng.uniform(-1.5, 1.5, (50, 3))
        view = rng.uniform(-2.5, 2.5, 3)
        answer = segment_oracle(polygons, points, view)
        crossing = (answer.t > 0) & (answer.t < 1)
        near_edge = (crossing & (answer.edge_dist < 1e-4)).any(axis=1)
        near_plane = (answer.point_plane < 1e-4).any(axis=1) | (answer.view_plane < 1e-4).any()
        keep = ~(near_edge | near_plane)
        embree = embree_visible(polygons, points, view, margin=1e-5)
        assert np.array_equal(embree[keep], answer.visible[keep])
        compared += int(keep.sum())
    assert compared > 1500
