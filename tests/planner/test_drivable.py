"""Drivable paths: a polyline redrawn from a car's pose as clear, curvature-bounded arcs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.geometry.drivable import STEP, drivable_path, thin, waypoints
from planner.geometry.pose import Pose
from planner.geometry.shapes import Ball, Box
from planner.geometry.world import World

LANE = np.array([[2.0, 2.0], [10.0, 2.0]])


def _world(obstacles: list[Box] | None = None, height: float = 6.0) -> World:
    regions = {"far": Ball(np.array([10.0, 2.0]), 0.8), "off": Ball(np.array([1.0, 4.5]), 0.8)}
    return World(np.array([[-2.0, 12.0], [-2.0, height]]), obstacles or [], regions)


def _turns(points: np.ndarray) -> np.ndarray:
    """Heading change per metre between consecutive steps (discrete curvature)."""
    steps = np.diff(points, axis=0)
    yaw = np.arctan2(steps[:, 1], steps[:, 0])
    length = np.linalg.norm(steps, axis=1)
    return np.abs(np.remainder(np.diff(yaw) + math.pi, 2 * math.pi) - math.pi) / length[1:]


def test_a_start_facing_along_a_straight_polyline_keeps_it() -> None:
    drawn = drivable_path(_world(), LANE, Pose(np.array([2.0, 2.0]), 0.0), rho=1.0, clearance=0.3)
    assert drawn is not None and drawn.cusp == 0
    path = drawn.points
    np.testing.assert_allclose(path[0], [2.0, 2.0])
    np.testing.assert_allclose(path[-1], [10.0, 2.0])
    assert np.abs(path[:, 1] - 2.0).max() < 1e-6
    assert np.linalg.norm(np.diff(path, axis=0), axis=1).max() <= STEP + 1e-9


def test_a_start_facing_away_turns_round_on_a_loop_of_the_radius() -> None:
    world = _world()
    drawn = drivable_path(world, LANE, Pose(np.array([2.0, 2.0]), math.pi), rho=1.0, clearance=0.3)
    assert drawn is not None and drawn.cusp == 0
    path = drawn.points
    length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    assert length >= 8.0 + math.pi * 1.0 - 0.1  # at least a half circle more than the lane
    assert _turns(path).max() <= 1.0 / 1.0 + 0.05
    assert path[:, 0].min() < 2.0 - 0.9  # the loop goes out behind the start
    assert not world.in_collision(path, 0.3).any()
    np.testing.assert_allclose(path[-1], [10.0, 2.0])


def test_the_loop_avoids_obstacles() -> None:
    below = Box(np.array([-2.0, -2.0]), np.array([4.0, 1.2]))
    world = _world([below])
    drawn = drivable_path(world, LANE, Pose(np.array([2.0, 2.0]), math.pi), rho=1.0, clearance=0.3)
    assert drawn is not None
    path = drawn.points
    assert path[:, 1].max() > 3.0  # round the top: the box is below
    assert not world.in_collision(path, 0.3).any()


def test_the_loop_meets_no_region_the_polyline_does_not_meet() -> None:
    free = drivable_path(
        _world(), LANE, Pose(np.array([2.0, 2.0]), math.pi), rho=1.0, clearance=0.3
    )
    assert free is not None and free.points[:, 1].min() < 1.0  # alone it loops round the bottom
    regions = {"far": Ball(np.array([10.0, 2.0]), 0.8), "off": Ball(np.array([1.0, 1.0]), 0.5)}
    world = World(np.array([[-2.0, 12.0], [-2.0, 6.0]]), [], regions)
    drawn = drivable_path(world, LANE, Pose(np.array([2.0, 2.0]), math.pi), rho=1.0, clearance=0.3)
    assert drawn is not None
    path = drawn.points
    assert path[:, 1].max() > 3.0
    assert not world.label_matrix(path)[:, world.region_names.index("off")].any()


def test_a_start_facing_away_in_a_narrow_lane_drives_off_to_turn_where_there_is_room() -> None:
    """The lane is 1.6 m wide, too narrow for a loop of radius 1 with 0.3 m of clearance; it
    opens behind the car into a hall where the car can turn."""
    walls = [
        Box(np.array([-0.5, -6.0]), np.array([12.0, 1.2])),
        Box(np.array([-0.5, 2.8]), np.array([12.0, 8.0])),
    ]
    world = World(np.array([[-6.0, 12.0], [-6.0, 8.0]]), walls, {})
    start = Pose(np.array([2.0, 2.0]), math.pi)
    drawn = drivable_path(world, LANE, start, rho=1.0, clearance=0.3)
    assert drawn is not None and drawn.cusp == 0
    path = drawn.points
    np.testing.assert_allclose(path[0], [2.0, 2.0])
    np.testing.assert_allclose(path[-1], [10.0, 2.0])
    assert path[:, 0].min() < -0.5  # it turned in the hall
    assert path[1, 0] < path[0, 0]  # driving off the way it faces
    assert _turns(path).max() <= 1.0 / 1.0 + 0.05
    assert not world.in_collision(path, 0.3).any()
    assert np.linalg.norm(np.diff(path, axis=0), axis=1).max() <= STEP + 1e-9


def test_a_start_facing_a_wall_backs_into_a_side_opening_to_turn() -> None:
    """A 1.6 m lane, a wall 1 m ahead of the car, facing away from the polyline: no forward
    piece fits; the car backs up into the hall that opens north of the lane (a three-point
    turn), then drives out along the lane."""
    walls = [
        Box(np.array([-0.5, -6.0]), np.array([12.0, 1.2])),
        Box(np.array([-0.5, 2.8]), np.array([3.5, 8.0])),
        Box(np.array([7.5, 2.8]), np.array([12.0, 8.0])),
        Box(np.array([-0.5, -6.0]), np.array([1.0, 8.0])),
    ]
    world = World(np.array([[-0.5, 12.0], [-6.0, 8.0]]), walls, {})
    drawn = drivable_path(world, LANE, Pose(np.array([2.0, 2.0]), math.pi), rho=1.0, clearance=0.3)
    assert drawn is not None and drawn.cusp > 0
    path, lead = drawn.points, drawn.points[: drawn.cusp + 1]
    assert lead[1, 0] > lead[0, 0]  # backing off: the car faces west and moves east
    assert lead[-1, 1] > 2.8  # into the hall
    np.testing.assert_allclose(path[-1], [10.0, 2.0])
    assert _turns(path[drawn.cusp :]).max() <= 1.0 / 1.0 + 0.05
    assert _turns(lead).max() <= 1.0 / 1.0 + 0.05
    assert not world.in_collision(path, 0.3).any()


def test_a_tight_spot_lowers_the_clearance_there_alone() -> None:
    """A box 0.55 m above the start, a wall inside the corner 8 m on: at 0.8 m no path fits;
    at 0.5 m alone the corner is cut to 0.63 m; with 0.5 m as the fallback of 0.8 m only the
    start keeps less, and the corner keeps its 0.8 m."""
    tight = Box(np.array([2.5, 2.55]), np.array([3.5, 4.0]))
    inside = Box(np.array([6.0, 3.0]), np.array([9.0, 12.0]))
    bounds = np.array([[0.0, 13.0], [0.0, 12.0]])
    world = World(bounds, [tight, inside], {})
    corner = World(bounds, [inside], {})
    poly = np.array([[2.0, 2.0], [10.5, 2.0], [10.5, 11.0]])
    start = Pose(np.array([2.0, 2.0]), 0.0)
    assert drivable_path(world, poly, start, rho=1.0, clearance=0.8) is None
    low = drivable_path(world, poly, start, rho=1.0, clearance=0.5)
    assert low is not None and corner.obstacle_distance(low.points).min() < 0.7
    mixed = drivable_path(world, poly, start, rho=1.0, clearance=0.8, fallback=(0.5,))
    assert mixed is not None
    assert world.obstacle_distance(mixed.points).min() >= 0.5
    assert corner.obstacle_distance(mixed.points).min() >= 0.8
    np.testing.assert_allclose(mixed.points[-1], [10.5, 11.0])


def test_a_door_with_centimetres_a_side_is_passed_through_its_middle() -> None:
    """A 0.8 m door in a wall, met at a slant, for a car of radius 0.3 m: with the clearances
    0.6, 0.45 and 0.3 m the piece through the door grazes a jamb (the door fits neither of the
    first two); with the finer steps of ``envs.drivable.clearances`` it keeps 0.09 m a side."""
    wall = [
        Box(np.array([0.0, 4.4]), np.array([4.05, 4.6])),
        Box(np.array([4.85, 4.4]), np.array([10.0, 4.6])),
    ]
    world = World(np.array([[0.0, 10.0], [0.0, 9.0]]), wall, {})
    poly = np.array([[7.0, 3.2], [4.6, 3.8], [4.45, 3.9], [4.45, 5.1], [8.0, 8.0]])
    start = Pose(poly[0], math.atan2(0.6, -2.4))
    coarse = drivable_path(world, poly, start, rho=0.9, clearance=0.6, fallback=(0.45, 0.3))
    fine = drivable_path(world, poly, start, 0.9, 0.6, fallback=(0.45, 0.375, 0.3375, 0.3))
    assert coarse is not None and fine is not None
    assert world.obstacle_distance(coarse.points).min() < 0.33
    assert world.obstacle_distance(fine.points).min() >= 0.3375


def test_a_region_the_plan_passes_close_by_is_kept_off_as_obstacles_are() -> None:
    """The lane passes 0.1 m from a region it may not meet: at the robot's radius alone the
    redraw keeps that; with room to spare it keeps what its clearance adds to the radius from
    the region too (a car following it within 0.1 m would stray in)."""
    near = Ball(np.array([6.0, 3.1]), 1.0)
    world = World(np.array([[0.0, 12.0], [-2.0, 6.0]]), [], {"near": near})
    start = Pose(LANE[0], 0.0)
    tight = drivable_path(world, LANE, start, rho=1.0, clearance=0.3)
    roomy = drivable_path(world, LANE, start, 1.0, 0.6, fallback=(0.45, 0.375, 0.3375, 0.3))
    assert tight is not None and roomy is not None
    assert np.linalg.norm(tight.points - near.center, axis=1).min() - near.radius < 0.11
    assert np.linalg.norm(roomy.points - near.center, axis=1).min() - near.radius >= 0.3


def test_no_room_to_turn_gives_none() -> None:
    narrow = World(np.array([[-2.0, 12.0], [1.0, 3.0]]), [], {})
    assert (
        drivable_path(narrow, LANE, Pose(np.array([2.0, 2.0]), math.pi), rho=1.5, clearance=0.3)
        is None
    )
    with pytest.raises(ValueError, match="turning radius"):
        drivable_path(narrow, LANE, Pose(np.array([2.0, 2.0]), 0.0), rho=0.0, clearance=0.3)


def test_waypoints_face_along_the_polyline_and_thin_keeps_the_ends() -> None:
    corner = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [2.0, 2.0]])
    points = waypoints(corner, 0.5)
    assert [round(w.along, 6) for w in points] == [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0]
    assert points[0].pose.heading == pytest.approx(0.0)
    assert points[4].pose.heading == pytest.approx(math.pi / 4)  # the corner: the bisector
    assert points[-1].pose.heading == pytest.approx(math.pi / 2)
    dense = np.stack([np.linspace(0, 3, 61), np.zeros(61)], axis=1)
    sparse = thin(dense, 1.0)
    np.testing.assert_allclose(sparse, [[0, 0], [1, 0], [2, 0], [3, 0]], atol=1e-12)
