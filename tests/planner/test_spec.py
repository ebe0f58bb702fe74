"""The world section: shape models, bounds, region checks, build, and the box generator."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

from planner.errors import WorldError
from planner.geometry.random_obstacles import boxes_distance_to, generate_boxes
from planner.geometry.shape_spec import PolygonSpec
from planner.geometry.shapes import Ball, Box, Polygon
from planner.geometry.world import World
from planner.geometry.world_spec import WorldSpec

BOUNDS = [[-10.0, 10.0], [-10.0, 10.0]]


def world(**fields: Any) -> WorldSpec:
    return WorldSpec.model_validate({"bounds": BOUNDS, **fields})


def errors(data: dict[str, Any]) -> list[tuple[tuple[int | str, ...], str, str]]:
    with pytest.raises(ValidationError) as info:
        WorldSpec.model_validate(data)
    return [(tuple(e["loc"]), e["type"], e["msg"]) for e in info.value.errors()]


def test_each_shape_kind_builds_the_planner_shape() -> None:
    spec = world(
        obstacles=[
            {"box": {"min": [1, 1], "max": [2, 3]}},
            {"ball": {"center": [4, 4], "radius": 0.5}},
            {"polygon": [[0, 0], [1, 0], [0, 1]]},
        ],
        regions={"g1": {"ball": {"center": [8, 8], "radius": 1}}},
    )
    assert [type(s).__name__ for s in spec.obstacles] == ["BoxSpec", "BallSpec", "PolygonSpec"]
    built = spec.build()
    assert isinstance(built, World)
    assert built.dim == 2
    assert built.region_names == ("g1",)
    assert [type(s) for s in built.obstacles] == [Box, Ball, Polygon]
    assert built.labels(np.array([1.5, 2.0])) == frozenset({"obstacle"})
    assert built.labels(np.array([8.0, 8.5])) == frozenset({"g1"})
    assert np.array_equal(built.bounds, np.array(BOUNDS))


def test_a_closing_polygon_vertex_is_dropped() -> None:
    spec = world(regions={"a": {"polygon": [[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]]}})
    shape = spec.regions["a"]
    assert isinstance(shape, PolygonSpec)
    assert len(shape.polygon) == 4


def test_three_dimensional_world() -> None:
    spec = WorldSpec.model_validate(
        {
            "bounds": [[0, 10], [0, 10], [0, 10]],
            "obstacles": [{"box": {"min": [1, 1, 1], "max": [2, 2, 2]}}],
            "regions": {"g1": {"ball": {"center": [5, 5, 5], "radius": 0.5}}},
        }
    )
    assert spec.dim == 3
    assert spec.build().labels(np.array([5.0, 5.0, 5.2])) == frozenset({"g1"})


@pytest.mark.parametrize(
    ("shape", "loc", "text"),
    [
        ({}, (), "empty shape"),
        ({"box": {"min": [0, 0], "max": [1, 1]}, "ball": {}}, (), "exactly one key"),
        ({"circle": {"radius": 1}}, (), "unknown shape 'circle'"),
        (3, (), "must be a mapping"),
        ({"ball": {"center": [0, 0], "radius": 0}}, ("ball", "ball", "radius"), "greater than 0"),
        ({"ball": {"center": [0], "radius": 1}}, ("ball", "ball", "center"), "got 1"),
        ({"box": {"min": [0, 2], "max": [1, 1]}}, ("box", "box"), "axis 1"),
        ({"box": {"min": [0, 0], "max": [1, 1, 1]}}, ("box", "box"), "max has 3"),
        ({"polygon": [[0, 0], [1, 1]]}, ("polygon", "polygon"), "at least 3 vertices, got 2"),
        ({"polygon": [[0, 0], [1, 1], [1, 0], [0, 1]]}, ("polygon", "polygon"), "not simple"),
        ({"polygon": [[0, 0], [1, 1], [2, 2]]}, ("polygon", "polygon"), "not simple"),
        ({"polygon": [[0, 0, 0], [1, 0, 0], [0, 1, 0]]}, ("polygon", "polygon"), "2D"),
        ({"ball": {"center": [0, 0], "radius": 1, "r": 2}}, ("ball", "ball", "r"), "Extra"),
    ],
)
def test_malformed_region_shape(shape: Any, loc: tuple[str, ...], text: str) -> None:
    [(where, _, message)] = errors({"bounds": BOUNDS, "regions": {"g1": shape}})
    assert where == ("regions", "g1", *loc)
    assert text in message


@pytest.mark.parametrize(
    ("bounds", "text"),
    [
        ([[0, 1]], "got 1"),
        ([[0, 1], [0, 1], [0, 1], [0, 1]], "got 4"),
        ([[0, 1], [2, 1]], "interval 1 must have lo < hi"),
        ([[0, 1], [0, 1, 2]], "interval 1 must be [lo, hi]"),
    ],
)
def test_bad_bounds(bounds: list[list[float]], text: str) -> None:
    [(where, _, message)] = errors({"bounds": bounds})
    assert where == ("bounds",)
    assert text in message


@pytest.mark.parametrize(
    ("label", "text"), [("G1", "not an atomic proposition"), ("obstacle", "reserved")]
)
def test_bad_region_label(label: str, text: str) -> None:
    data = {"bounds": BOUNDS, "regions": {label: {"ball": {"center": [0, 0], "radius": 1}}}}
    [(where, _, message)] = errors(data)
    assert where == ("regions", label, "[key]")
    assert text in message


def test_located_world_problems() -> None:
    data = {
        "bounds": BOUNDS,
        "obstacles": [
            {"box": {"min": [0, 0, 0], "max": [1, 1, 1]}},
            {"box": {"min": [20, 20], "max": [21, 21]}},
        ],
        "regions": {
            "inside": {"ball": {"center": [0, 0], "radius": 1}},
            "out": {"ball": {"center": [9.5, 0], "radius": 1}},
            "flat": {"ball": {"center": [0, 0, 0], "radius": 1}},
        },
        "random_obstacles": {"count": 1, "size": [1, 1, 1]},
    }
    [(where, kind, message)] = errors(data)
    assert (where, kind) == ((), "ltlnav_problems")
    assert "regions.out: lies outside the world bounds" in message
    with pytest.raises(ValidationError) as info:
        WorldSpec.model_validate(data)
    problems = dict(info.value.errors()[0]["ctx"]["problems"])
    assert set(problems) == {
        "obstacles.0",
        "obstacles.1",
        "regions.out",
        "regions.flat",
        "random_obstacles.size",
    }
    assert problems["obstacles.0"] == "is 3D but the world is 2D"
    assert problems["obstacles.1"] == "lies entirely outside the world bounds"


def test_numbers_must_be_finite() -> None:
    data = {"bounds": [[0, float("inf")], [0, 1]]}
    [(where, kind, _)] = errors(data)
    assert (where, kind) == (("bounds", 0, 1), "finite_number")


def test_random_obstacles_are_added_and_kept_clear() -> None:
    spec = world(
        obstacles=[{"box": {"min": [1, 1], "max": [2, 2]}}],
        random_obstacles={"count": 40, "size": [1.0, 0.5], "seed": 3, "clearance": 1.5},
        regions={
            "g1": {"ball": {"center": [8, 8], "radius": 1}},
            "g2": {"box": {"min": [-3, 4], "max": [-1, 6]}},
            "g3": {"polygon": [[2, -8], [6, -8], [4, -4]]},
        },
    )
    start = np.array([-8.0, -8.0])
    built = spec.build(keep_clear=[start])
    assert len(built.obstacles) == 41
    generated = [b for b in built.obstacles[1:] if isinstance(b, Box)]
    assert len(generated) == 40
    lo = np.array([b.lo for b in generated])
    hi = np.array([b.hi for b in generated])
    assert np.allclose(hi - lo, [1.0, 0.5])
    assert np.all(lo >= -10) and np.all(hi <= 10)
    for region in built.regions.values():
        assert np.all(boxes_distance_to(region, lo, hi) >= 1.5)
        pts = region.sample(np.random.default_rng(0), 500)
        assert not any(box.contains(pts, margin=1.4).any() for box in generated)
    assert not built.in_collision(start[None, :], clearance=1.5)[0]
    again = spec.build(keep_clear=[start])
    assert all(a == b for a, b in zip(again.obstacles, built.obstacles, strict=True))


def test_generator_is_deterministic_and_seeded() -> None:
    bounds = np.array([[0.0, 10.0], [0.0, 10.0], [0.0, 5.0]])
    size = np.array([1.0, 1.0, 2.0])
    avoid = [Ball(np.array([5.0, 5.0, 2.5]), 1.0)]

    def boxes(seed: int, count: int = 30) -> list[Box]:
        return generate_boxes(bounds, count, size, seed, 0.5, [np.zeros(3)], avoid)

    first = boxes(7)
    assert first == boxes(7)
    assert first != boxes(8)
    assert all(b.dim == 3 for b in first)
    assert boxes(7, count=0) == []


def test_generator_gives_up_with_a_located_error() -> None:
    spec = world(
        random_obstacles={"count": 20, "size": [2, 2], "clearance": 12.0},
        regions={"g1": {"ball": {"center": [0, 0], "radius": 1}}},
    )
    with pytest.raises(WorldError) as info:
        spec.build()
    assert info.value.field == "world.random_obstacles.count"
    assert "could place only 0 of 20" in str(info.value)


@pytest.mark.parametrize(
    "region",
    [
        Box(np.array([2.0, 2.0]), np.array([3.0, 4.0])),
        Ball(np.array([5.0, -1.0]), 1.5),
        Polygon(np.array([[-4.0, -4.0], [0.0, -5.0], [-1.0, -1.0], [-2.5, -3.5]])),
    ],
)
def test_box_distance_matches_dense_sampling(region: Box | Ball | Polygon) -> None:
    rng = np.random.default_rng(1)
    lo = rng.uniform(-8, 6, size=(200, 2))
    hi = lo + rng.uniform(0.2, 2.0, size=(200, 2))
    exact = boxes_distance_to(region, lo, hi)
    t = np.linspace(0.0, 1.0, 41)
    grid = np.stack(np.meshgrid(t, t, indexing="ij"), axis=-1).reshape(-1, 2)
    for i in range(len(lo)):
        pts = lo[i] + grid * (hi[i] - lo[i])
        sampled = float(region.distance(pts).min())
        # Sampling the box can only over-estimate, by at most the grid spacing.
        assert exact[i] <= sampled + 1e-9
        assert sampled <= exact[i] + float(np.linalg.norm(hi[i] - lo[i])) / 40 + 1e-9
