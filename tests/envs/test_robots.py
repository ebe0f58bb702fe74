"""Robot dynamics: scripted drives to a goal, bad input, determinism, collisions."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import get_args

import numpy as np
import pytest

from envs.robots import (
    ROBOT_MODELS,
    PointCollider,
    QuadrotorParams,
    Robot,
    RobotConfigError,
    UnicycleParams,
    make_robot,
    robot_params,
)
from envs.robots.quadrotor import Quadrotor
from envs.robots.racecar import Racecar
from envs.robots.static_bodies import prism, triangulate
from envs.spec import RobotModel
from planner.geometry.shapes import Ball, Box, Polygon
from planner.geometry.world import World


def world_2d() -> World:
    return World(
        np.array([[0.0, 8.0], [0.0, 8.0]]),
        [
            Box(np.array([2.0, 0.0]), np.array([3.0, 5.0])),
            Box(np.array([5.0, 3.0]), np.array([6.0, 8.0])),
            Ball(np.array([7.0, 1.5]), 0.5),
            Polygon(np.array([[6.5, 5.0], [7.5, 5.0], [7.5, 7.0], [7.0, 6.0], [6.5, 7.0]])),
        ],
        {"goal": Ball(np.array([7.2, 2.8]), 0.4)},
    )


PATH_2D = np.array([[1.0, 1.0], [1.0, 6.2], [4.0, 6.2], [4.0, 1.5], [6.0, 2.2], [7.2, 2.8]])


def world_3d() -> World:
    return World(
        np.array([[0.0, 6.0], [0.0, 6.0], [0.0, 3.0]]),
        [
            Box(np.array([2.0, 0.0, 0.0]), np.array([3.0, 4.0, 3.0])),
            Ball(np.array([1.0, 3.0, 2.6]), 0.4),
            Box(np.array([4.0, 2.5, 0.0]), np.array([6.0, 3.0, 0.8])),
        ],
        {},
    )


PATH_3D = np.array([[1.0, 1.0, 1.0], [1.0, 5.0, 1.5], [4.0, 5.0, 2.0], [5.0, 1.0, 1.2]])


def lookahead(path: np.ndarray, x: np.ndarray, dist: float) -> np.ndarray:
    """The point ``dist`` further along ``path`` than the point of ``path`` closest to ``x``."""
    seg = path[1:] - path[:-1]
    lengths = np.linalg.norm(seg, axis=1)
    t = np.clip(((x - path[:-1]) * seg).sum(axis=1) / lengths**2, 0.0, 1.0)
    gaps = np.linalg.norm(path[:-1] + t[:, None] * seg - x, axis=1)
    k = int(np.argmin(gaps))
    s = float(np.concatenate([[0.0], np.cumsum(lengths)])[k] + t[k] * lengths[k]) + dist
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    if s >= cum[-1]:
        return path[-1].copy()
    j = int(np.searchsorted(cum, s, side="right") - 1)
    return path[j] + (s - cum[j]) / lengths[j] * seg[j]


def heading_error(robot: Robot, target: np.ndarray) -> float:
    theta = float(robot.state[2])
    d = target - robot.position()
    return (math.atan2(d[1], d[0]) - theta + math.pi) % (2 * math.pi) - math.pi


def unicycle_controller(robot: Robot, target: np.ndarray) -> np.ndarray:
    err = heading_error(robot, target)
    return np.array([0.8 * max(0.0, math.cos(err)), float(np.clip(2.0 * err, -1.0, 1.0))])


def racecar_controller(robot: Robot, target: np.ndarray) -> np.ndarray:
    err = heading_error(robot, target)
    return np.array([0.7, float(np.clip(2.5 * err, -1.0, 1.0))])


def point_controller(robot: Robot, target: np.ndarray) -> np.ndarray:
    d = robot.workspace_dim
    pos, vel = robot.state[:d], robot.state[d:]
    return np.clip(2.0 * (target - pos) - 2.5 * vel, -1.0, 1.0)


def quadrotor_controller(robot: Robot, target: np.ndarray) -> np.ndarray:
    return np.clip(1.5 * (target - robot.position()), -0.8, 0.8)


Controller = Callable[[Robot, np.ndarray], np.ndarray]
DRIVES: list[tuple[str, Callable[[], World], np.ndarray, float, Controller, int]] = [
    ("unicycle", world_2d, PATH_2D, 0.3, unicycle_controller, 500),
    ("racecar", world_2d, PATH_2D, 0.3, racecar_controller, 600),
    ("point", world_2d, PATH_2D, 0.3, point_controller, 600),
    ("point", world_3d, PATH_3D, 0.2, point_controller, 600),
    ("quadrotor", world_3d, PATH_3D, 0.15, quadrotor_controller, 600),
]


@pytest.fixture
def robots() -> Iterator[list[Robot]]:
    """Robots built by a test, closed afterwards."""
    built: list[Robot] = []
    yield built
    for r in built:
        r.close()


def build(robots: list[Robot], model: str, world: World, radius: float, **params: float) -> Robot:
    robot = make_robot(model, world, radius, params)
    robots.append(robot)
    return robot


@pytest.mark.parametrize(
    ("model", "make_world", "path", "radius", "controller", "limit"),
    DRIVES,
    ids=[f"{d[0]}-{d[1].__name__}" for d in DRIVES],
)
def test_scripted_drive_reaches_goal_without_collision(
    robots: list[Robot],
    model: str,
    make_world: Callable[[], World],
    path: np.ndarray,
    radius: float,
    controller: Controller,
    limit: int,
) -> None:
    world = make_world()
    assert world.segments_free(path[:-1], path[1:], radius + 0.2).all()
    robot = build(robots, model, world, radius)
    heading = math.atan2(*(path[1] - path[0])[1::-1])
    robot.reset(path[0], np.random.default_rng(0), heading=heading)
    assert not robot.collided()
    goal = path[-1]
    for step in range(limit):
        action = controller(robot, lookahead(path, robot.position(), 0.5))
        robot.step(action)
        obs = robot.observation()
        assert obs.dtype == np.float32 and obs.shape == (robot.state_dim,)
        assert np.all(obs >= robot.state_low) and np.all(obs <= robot.state_high)
        assert not robot.collided(), f"collided at step {step}, position {robot.position()}"
        assert not world.in_collision(robot.position()[None], radius)[0]
        if np.linalg.norm(robot.position() - goal) < 0.25:
            break
    else:
        pytest.fail(f"{model} did not reach {goal} in {limit} steps: at {robot.position()}")


@pytest.mark.parametrize("model", ["unicycle", "point", "racecar"])
def test_driving_into_a_box_collides(robots: list[Robot], model: str) -> None:
    world = World(np.array([[0.0, 10.0], [0.0, 4.0]]), [Box([5.0, 0.0], [6.0, 4.0])], {})
    radius = 0.0 if model == "racecar" else 0.2
    robot = build(robots, model, world, radius)
    robot.reset(np.array([2.0, 2.0]), np.random.default_rng(0), heading=0.0)
    for _ in range(200):
        robot.step(np.array([1.0, 0.0]))
        if robot.collided():
            break
    assert robot.collided()
    x = float(robot.position()[0])
    if model == "racecar":
        # Contact, not the centre point: the front of the car touches the wall first.
        assert 4.5 < x < 5.0
    else:
        assert 4.5 < x <= 5.3
        assert world.in_collision(robot.position()[None], radius)[0]


def test_leaving_the_bounds_collides(robots: list[Robot]) -> None:
    world = World(np.array([[0.0, 3.0], [0.0, 3.0]]), [], {})
    robot = build(robots, "unicycle", world, 0.25)
    robot.reset(np.array([1.5, 1.5]), np.random.default_rng(0), heading=math.pi / 2)
    steps = 0
    while not robot.collided():
        robot.step(np.array([1.0, 0.0]))
        steps += 1
    assert robot.position()[1] > 3.0 - 0.25 and steps == 13


@pytest.mark.parametrize(
    ("model", "make_world"),
    [("unicycle", world_2d), ("point", world_3d), ("quadrotor", world_3d), ("racecar", world_2d)],
)
def test_deterministic_for_a_seed(
    robots: list[Robot], model: str, make_world: Callable[[], World]
) -> None:
    world = make_world()
    start = PATH_2D[0] if world.dim == 2 else PATH_3D[0]

    def rollout(robot: Robot, seed: int) -> np.ndarray:
        rng = np.random.default_rng(seed)
        robot.reset(start, rng)
        states = []
        for _ in range(40):
            robot.step(rng.uniform(-1.0, 1.0, robot.action_dim))
            states.append(robot.state)
        return np.array(states)

    first = build(robots, model, world, 0.1)
    second = build(robots, model, world, 0.1)
    a, b, c = rollout(first, 3), rollout(second, 3), rollout(first, 3)
    assert np.array_equal(a, b) and np.array_equal(a, c)
    assert not np.array_equal(a, rollout(first, 4))


@pytest.mark.parametrize("model", sorted(ROBOT_MODELS))
def test_bad_actions_raise(robots: list[Robot], model: str) -> None:
    world = world_3d() if model == "quadrotor" else world_2d()
    robot = build(robots, model, world, 0.1)
    with pytest.raises(RuntimeError, match="reset"):
        robot.step(np.zeros(robot.action_dim))
    start = PATH_3D[0] if world.dim == 3 else PATH_2D[0]
    robot.reset(start, np.random.default_rng(0), heading=0.0)
    before = robot.state
    n = robot.action_dim
    with pytest.raises(ValueError, match=rf"shape \({n},\)"):
        robot.step(np.zeros(n + 1))
    with pytest.raises(ValueError, match=rf"shape \({n},\)"):
        robot.step(np.zeros((1, n)))
    with pytest.raises(ValueError, match="NaN"):
        robot.step(np.array([np.nan] + [0.0] * (n - 1)))
    with pytest.raises(ValueError, match=r"\[-1, 1\].*not clipped"):
        robot.step(np.array([1.5] + [0.0] * (n - 1)))
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        robot.step(np.array([0.0] * (n - 1) + [-1.0001]))
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        robot.step(np.array([np.inf] + [0.0] * (n - 1)))
    assert np.array_equal(robot.state, before)
    robot.step(np.ones(n, dtype=np.float32))
    robot.step(-np.ones(n))


def test_bad_start_raises(robots: list[Robot]) -> None:
    robot = build(robots, "unicycle", world_2d(), 0.1)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="2 coordinates"):
        robot.reset(np.array([1.0, 1.0, 0.0]), rng)
    with pytest.raises(ValueError, match="outside the world bounds"):
        robot.reset(np.array([-1.0, 1.0]), rng)
    with pytest.raises(ValueError, match="finite"):
        robot.reset(np.array([np.nan, 1.0]), rng)
    with pytest.raises(ValueError, match="heading"):
        robot.reset(np.array([1.0, 1.0]), rng, heading=math.inf)


def test_unknown_model_and_params_raise() -> None:
    with pytest.raises(RobotConfigError, match="unknown robot model 'tank'") as err:
        make_robot("tank", world_2d(), 0.1)
    assert err.value.field == "model"
    assert isinstance(err.value, ValueError)
    with pytest.raises(RobotConfigError, match="unknown parameter 'max_sped'") as err:
        robot_params("unicycle", {"max_sped": 2.0})
    assert err.value.field == "params.max_sped"
    assert "max_speed" in str(err.value)
    with pytest.raises(RobotConfigError, match="must be > 0") as err:
        robot_params("unicycle", {"max_speed": -1.0})
    assert err.value.field == "params.max_speed"
    with pytest.raises(RobotConfigError, match="integer") as err:
        robot_params("quadrotor", {"substeps": 2.5})
    assert err.value.field == "params.substeps"
    with pytest.raises(RobotConfigError, match="finite") as err:
        robot_params("point", {"dt": math.nan})
    with pytest.raises(RobotConfigError, match="number"):
        robot_params("point", {"dt": "fast"})  # type: ignore[dict-item]
    with pytest.raises(RobotConfigError) as err:
        make_robot("unicycle", world_2d(), -0.5)
    assert err.value.field == "radius"


def test_world_of_the_wrong_dimension_raises() -> None:
    for model in ("unicycle", "racecar"):
        with pytest.raises(RobotConfigError, match=f"a {model} robot moves in a 2D workspace"):
            make_robot(model, world_3d(), 0.1)
    with pytest.raises(RobotConfigError, match="3D workspace, but the world is 2D") as err:
        make_robot("quadrotor", world_2d(), 0.1)
    assert err.value.field == "model"


def test_params_defaults_and_overrides() -> None:
    assert robot_params("unicycle") == UnicycleParams()
    params = robot_params("quadrotor", {"max_speed": 2.0, "substeps": 8.0})
    assert isinstance(params, QuadrotorParams)
    assert params.max_speed == 2.0 and params.substeps == 8 and isinstance(params.substeps, int)
    assert params.mass == 0.027 and params.arm == 0.0397
    robot = make_robot("unicycle", world_2d(), 0.1, {"dt": 0.05})
    assert robot.dt == 0.05
    assert set(ROBOT_MODELS) == set(get_args(RobotModel))


def test_collider_agrees_with_world() -> None:
    rng = np.random.default_rng(1)
    for world in (world_2d(), world_3d()):
        for radius in (0.0, 0.3):
            collider = PointCollider(world, radius)
            lo, hi = world.bounds[:, 0] - 0.5, world.bounds[:, 1] + 0.5
            points = rng.uniform(lo, hi, (4000, world.dim))
            expected = world.in_collision(points, radius)
            got = np.array([collider.hits(p) for p in points.tolist()])
            assert 0.1 < expected.mean() < 0.9
            assert np.array_equal(got, expected)


def test_quadrotor_hovers_and_tracks_velocity(robots: list[Robot]) -> None:
    world = World(np.array([[-20.0, 20.0]] * 3), [], {})
    robot = build(robots, "quadrotor", world, 0.1)
    assert isinstance(robot, Quadrotor)
    robot.reset(np.array([0.0, 0.0, 10.0]), np.random.default_rng(0), heading=0.5)
    for _ in range(40):
        robot.step(np.zeros(3))
    assert np.allclose(robot.position(), [0.0, 0.0, 10.0], atol=1e-6)
    hover = math.sqrt(0.027 * 9.81 / (4 * 3.16e-10))
    assert np.allclose(robot.rpm, hover, rtol=1e-3)
    for _ in range(40):
        robot.step(np.array([0.5, -0.5, 0.2]))
    assert np.allclose(robot.state[3:6], [0.5, -0.5, 0.2], atol=0.05)
    roll, pitch, yaw = robot.attitude()
    assert abs(yaw - 0.5) < 0.01 and abs(roll) < 0.1 and abs(pitch) < 0.1


def test_racecar_groups_obstacles_and_touches_every_one(robots: list[Robot]) -> None:
    """Forty balls make three bodies of at most 16 shapes, and the car's geometry touches the
    last ball (where PyBullet would have dropped shapes past 16) while its 5 cm disc does not."""
    balls = [Ball(np.array([1.0 + 0.5 * (k % 20), 1.0 + 6.0 * (k // 20)]), 0.1) for k in range(40)]
    world = World(np.array([[0.0, 12.0], [0.0, 8.0]]), balls, {})
    robot = build(robots, "racecar", world, 0.05)
    assert isinstance(robot, Racecar)
    pb = pytest.importorskip("pybullet")
    shapes = [
        len(pb.getCollisionShapeData(body, -1, physicsClientId=robot.client))
        for body in robot.obstacle_bodies
    ]
    assert shapes == [16, 16, 8]
    last = balls[-1].center
    robot.reset(last - np.array([0.3, 0.0]), np.random.default_rng(0), heading=0.0)
    assert not robot.collided()
    robot.step(np.zeros(2))
    assert robot.collided()


def test_racecar_builds_polygons_and_closes(robots: list[Robot]) -> None:
    world = world_2d()
    poly = world.obstacles[3]
    assert isinstance(poly, Polygon)
    tris = triangulate(poly.vertices)
    v = poly.vertices
    area = sum(
        0.5 * abs(float(np.linalg.det(np.stack([v[j] - v[i], v[k] - v[i]])))) for i, j, k in tris
    )
    assert len(tris) == 3 and area == pytest.approx(poly.volume)
    verts, faces = prism([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], 0.0, 1.0)
    assert len(verts) == 6 and len(faces) == 3 * (2 + 2 * 3)
    robot = build(robots, "racecar", world, 0.1)
    # The boxes and the ball's cylinder share a body; one prism per triangle of the polygon.
    assert isinstance(robot, Racecar)
    assert len(robot.obstacle_bodies) == 1 + len(tris)
    robot.close()
    robot.close()
    with pytest.raises(RuntimeError, match="reset"):
        robot.step(np.zeros(2))
