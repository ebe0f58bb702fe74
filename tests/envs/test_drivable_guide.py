"""Drivable guides: a racecar's sub-task guides redrawn from its hand-over poses.

The mission drives east down a lane into region ``a``, then back west to ``b``: the second
sub-task starts facing into ``a`` with its polyline leaving the way the car came, a U-turn the
racecar (turning radius 0.62 m) can only make on a loop.
"""

from __future__ import annotations

import dataclasses
from functools import cache
from typing import Any

import numpy as np
import pytest

from envs.drivable import clearances, redraw_course
from envs.errors import EnvConfigError
from envs.factory import make_env
from envs.feedforward import PURSUIT_LOOKAHEAD, ActionShaping, pursuit_turn
from envs.handover import arrival_pose
from envs.options import EnvOptions
from envs.robots import make_robot, robot_params
from envs.spec import RobotSpec
from envs.track import Track, lead_target, pursuit_target
from planner.decompose import SubTask
from planner.geometry.drivable import thin
from planner.geometry.pose import Pose
from planner.geometry.shapes import Ball, Box
from planner.geometry.world import World
from planner.guidance import Guide
from planner.plan import MissionPlan, plan_mission
from planner.search.planner_spec import PlannerSpec
from tests.envs.test_nav_env import Mission, Prebuilt
from tests.envs.test_scripted import CONTROLLERS, Pursuit

RADIUS = 0.27
FACTOR = 1.45
START = [1.5, 1.5, 0.0]
PURSUIT_LAW: dict[str, Any] = {
    "guide_feedforward": 1.0,
    "feedforward_law": "pursuit",
    "min_forward": 0.2,
}
"""The racecar's pursuit feed-forward, as the env options that switch it on."""


@cache
def lane() -> tuple[World, MissionPlan]:
    world = World(
        np.array([[0.0, 12.0], [0.0, 5.0]]),
        [Box(np.array([4.0, 3.2]), np.array([8.0, 5.0]))],
        {"a": Ball(np.array([10.5, 2.0]), 0.8), "b": Ball(np.array([1.5, 3.8]), 0.6)},
    )
    options = PlannerSpec(seed=0, time_limit=20.0)
    plan = plan_mission(world, "<>(a && <>b)", np.array(START[:2]), 0.4, options)
    return world, plan


def racecar_mission(model: str = "racecar") -> Mission:
    world, _ = lane()
    return Mission(Prebuilt(world), RobotSpec(model=model, start=START, radius=RADIUS))


def course() -> list[SubTask]:
    world, plan = lane()
    rho = FACTOR * robot_params("racecar").min_turning_radius()
    steps = clearances(RADIUS, plan.hold)
    return redraw_course(world, plan.subtasks, Pose(np.array(START[:2]), 0.0), rho, steps)


def test_the_u_turn_guide_starts_at_the_hand_over_and_loops() -> None:
    world, plan = lane()
    assert [s.goal for s in plan.subtasks] == ["a", "b"]
    drawn = course()
    handover = arrival_pose(world, drawn[0])
    env = make_env(racecar_mission(), 1, "rrt", world=world, plan=plan, drivable_guide=FACTOR)
    try:
        (start,) = env.starts
        np.testing.assert_allclose(start.position, handover.position)
        assert start.heading == pytest.approx(handover.heading)
        guide = env.legs[0].guide
        np.testing.assert_allclose(guide.centers[0], handover.position)
        gaps = np.linalg.norm(np.diff(guide.centers, axis=0), axis=1)
        assert gaps.max() <= 2 * guide.r + 1e-9
        polyline = float(np.linalg.norm(np.diff(plan.subtasks[1].path, axis=0), axis=1).sum())
        assert guide.length > polyline + 1.0  # the loop
        assert not world.in_collision(drawn[1].path, RADIUS).any()
    finally:
        env.close()


def test_a_racecar_following_the_redrawn_guide_makes_the_u_turn() -> None:
    world, plan = lane()
    path = course()[1].path
    env = make_env(racecar_mission(), 1, "rrt", world=world, plan=plan, drivable_guide=FACTOR)
    try:
        for seed in range(3):
            env.reset(seed=seed)
            pursuit, info = Pursuit(path, 0.6), dict[str, Any]()
            for _ in range(env.max_steps):
                target = pursuit.target(env.robot.position())
                _, _, done, cut, info = env.step(CONTROLLERS["racecar"](env.robot, target))
                if done or cut:
                    break
            assert info["is_success"], info
    finally:
        env.close()


def test_g_rrt_chains_the_redrawn_legs() -> None:
    world, plan = lane()
    env = make_env(racecar_mission(), None, "g-rrt", world=world, plan=plan, drivable_guide=FACTOR)
    try:
        first, second = env.legs
        np.testing.assert_allclose(first.guide.centers[0], START[:2])
        arrival = arrival_pose(world, course()[0]).position
        np.testing.assert_allclose(second.guide.centers[0], arrival)
    finally:
        env.close()


def test_a_u_turn_with_no_room_for_the_loop_keeps_its_polyline() -> None:
    world, plan = lane()
    wide = redraw_course(world, plan.subtasks, Pose(np.array(START[:2]), 0.0), 20.0, [0.4])
    np.testing.assert_array_equal(wide[1].path, plan.subtasks[1].path)
    assert redraw_course(world, plan.subtasks, Pose(np.array(START[:2]), 0.0), 20.0, [0.4]) == wide


def test_only_robots_with_a_turning_radius_take_drivable_guides() -> None:
    world, plan = lane()
    with pytest.raises(EnvConfigError, match="minimum turning radius") as err:
        make_env(racecar_mission("unicycle"), 1, world=world, plan=plan, drivable_guide=FACTOR)
    assert err.value.field == "options.drivable_guide"
    with pytest.raises(EnvConfigError, match=">= 1"):
        EnvOptions(drivable_guide=0.5)


def test_pursuit_target_runs_ahead_of_the_projection_on_the_guide() -> None:
    centres = np.array([[float(i), 0.0] for i in range(6)])
    track = Track.of_guide(Guide.from_path(centres, 0.5))
    np.testing.assert_allclose(pursuit_target(track, 2, [2.3, 0.5], 1.0), [3.3, 0.0])
    np.testing.assert_allclose(pursuit_target(track, -1, [-1.0, 0.0], 0.5), [0.5, 0.0])
    np.testing.assert_allclose(pursuit_target(track, 5, [4.8, 0.0], 2.0), [5.0, 0.0])


def test_the_point_backed_towards_runs_on_past_the_cusp_along_the_lead() -> None:
    # backing east 2 m to the cusp at (2, 0), then forwards north 3 m
    lead = np.array([[0.1 * i, 0.0] for i in range(21)])
    onward = np.array([[2.0, 0.1 * i] for i in range(1, 31)])
    track = Track.dense(np.vstack([lead, onward]), 6, cusp=20)
    assert track.cusp_togo is not None
    np.testing.assert_allclose(lead_target(track, track.cusp_togo + 0.5), [1.5, 0.0], atol=1e-9)
    np.testing.assert_allclose(lead_target(track, track.cusp_togo - 0.7), [2.7, 0.0], atol=1e-9)


def test_pursuit_on_a_dense_track_follows_the_arc_the_balls_cut() -> None:
    rho = 0.9
    angles = np.linspace(0.0, np.pi, 200)  # a half circle, the turn of a U-turn loop
    arc = np.stack([rho * np.sin(angles), rho * (1.0 - np.cos(angles))], axis=1)
    balls = thin(arc, 1.42)
    track = Track.dense(arc, len(balls))
    np.testing.assert_allclose(track.ball_togo[[0, -1]], [np.pi * rho, 0.0], atol=1e-3)
    on_arc = pursuit_target(track, 0, arc[0], 0.5 * np.pi * rho)  # a quarter turn on
    np.testing.assert_allclose(on_arc, [rho, rho], atol=1e-3)
    on_chord = pursuit_target(Track.of_guide(Guide.from_path(balls, 0.71)), 0, arc[0], 0.64)
    assert np.hypot(*(on_chord - [0.0, rho])) < rho - 0.2  # the chord cuts inside the arc


def test_pursuit_turn_is_the_arc_curvature_in_units_of_the_tightest() -> None:
    radius, theta = 0.6, 0.8
    on_tightest_arc = np.array([radius * np.sin(theta), radius * (1 - np.cos(theta))])
    assert pursuit_turn(0.0, [0.0, 0.0], on_tightest_arc, radius) == pytest.approx(1.0)
    wider = np.array([2 * radius * np.sin(theta), -2 * radius * (1 - np.cos(theta))])
    assert pursuit_turn(0.0, [0.0, 0.0], wider, radius) == pytest.approx(-0.5)
    assert pursuit_turn(0.0, [0.0, 0.0], np.array([2.0, 0.0]), radius) == 0.0
    assert pursuit_turn(0.0, [0.0, 0.0], np.array([-1.0, 0.1]), radius) == 1.0


def test_the_pursuit_feedforward_alone_makes_the_u_turn() -> None:
    world, plan = lane()
    options: dict[str, Any] = {
        "drivable_guide": FACTOR,
        "guide_feedforward": 1.0,
        "min_forward": 0.2,
    }
    env = make_env(
        racecar_mission(), 1, "rrt", world=world, plan=plan, feedforward_law="pursuit", **options
    )
    try:
        for seed in range(3):
            env.reset(seed=seed)
            info: dict[str, object] = {}
            for _ in range(env.max_steps):
                _, _, done, cut, info = env.step(np.zeros(2, dtype=np.float32))
                if done or cut:
                    break
            assert info["is_success"], info
    finally:
        env.close()
    with pytest.raises(EnvConfigError, match="minimum turning radius") as err:
        make_env(racecar_mission("unicycle"), 1, world=world, plan=plan, feedforward_law="pursuit")
    assert err.value.field == "options.feedforward_law"


def test_the_pursuit_lookahead_is_set_in_turning_radii() -> None:
    robot = make_robot("racecar", lane()[0], RADIUS)
    try:
        rho = robot.params.min_turning_radius()
        default = ActionShaping(robot, EnvOptions(guide_feedforward=1.0, feedforward_law="pursuit"))
        assert default.ahead == pytest.approx(PURSUIT_LOOKAHEAD * rho)
        longer = EnvOptions(guide_feedforward=1.0, feedforward_law="pursuit", pursuit_lookahead=2)
        assert ActionShaping(robot, longer).ahead == pytest.approx(2.0 * rho)
    finally:
        robot.close()
    with pytest.raises(EnvConfigError, match="> 0") as err:
        EnvOptions(pursuit_lookahead=0.0)
    assert err.value.field == "options.pursuit_lookahead"


def test_the_least_slack_is_read_over_the_stretch_asked() -> None:
    points = np.array([[0.1 * i, 0.0] for i in range(51)])  # 5 m east: 5 - x metres to go
    slack = np.where((points[:, 0] >= 3.0) & (points[:, 0] <= 3.5), 0.05, 0.5)
    track = Track.dense(points, 6, slack=slack)
    assert track.least_slack(5.0, 2.1) == pytest.approx(0.5)  # x from 0 to 2.9
    assert track.least_slack(5.0, 2.0) == pytest.approx(0.05)  # to 3.0
    assert track.least_slack(1.8, 1.7) == pytest.approx(0.05)  # within
    assert track.least_slack(1.4, 0.0) == pytest.approx(0.5)  # past it
    assert Track.dense(points, 6).least_slack(5.0, 0.0) == np.inf


def test_pursuit_takes_the_tight_lookahead_where_the_track_ahead_is_tight() -> None:
    points = np.array([[0.05 * i, 1.0] for i in range(201)])  # 10 m east along y = 1
    slack = np.where((points[:, 0] >= 5.0) & (points[:, 0] <= 5.5), 0.05, 0.5)
    world = World(np.array([[0.0, 12.0], [0.0, 5.0]]), [], {})
    robot = make_robot("racecar", world, RADIUS)
    try:
        rho = robot.params.min_turning_radius()
        usual = ActionShaping(robot, EnvOptions(**PURSUIT_LAW))
        tight = ActionShaping(robot, EnvOptions(**PURSUIT_LAW, pursuit_tight_lookahead=0.5))
        assert tight.ahead == usual.ahead == pytest.approx(PURSUIT_LOOKAHEAD * rho)
        assert tight.tight_ahead == pytest.approx(0.5 * rho)

        def turns(x: float) -> tuple[float, float]:
            robot.reset(np.array([x, 0.8]), np.random.default_rng(0), heading=0.0)
            track = Track.dense(points, 21, slack=slack)  # balls 0.5 m apart
            zero, ball = np.zeros(2), int(x / 0.5)
            return usual.apply(zero, track, ball)[1], tight.apply(zero, track, ball)[1]

        # 0.2 m right of the track: a nearer point ahead turns back harder
        near_usual, near_tight = turns(5.0 - 0.5 * PURSUIT_LOOKAHEAD * rho)
        assert 0 < near_usual < near_tight
        far_usual, far_tight = turns(5.0 - 1.5 * PURSUIT_LOOKAHEAD * rho)  # the door further
        assert far_tight == pytest.approx(far_usual)
        past_usual, past_tight = turns(6.0)
        assert past_tight == pytest.approx(past_usual)
    finally:
        robot.close()
    with pytest.raises(EnvConfigError, match="> 0") as err:
        EnvOptions(pursuit_tight_lookahead=-1.0)
    assert err.value.field == "options.pursuit_tight_lookahead"


def test_the_redraw_steps_down_from_what_the_plan_sought_halving_the_room() -> None:
    assert clearances(0.3, 0.6) == pytest.approx([0.6, 0.45, 0.375, 0.3375, 0.3])
    # a plan that fell back to the radius (a narrow door) still seeks room where there is some
    fallen = dataclasses.replace(lane()[1], clearance=0.3, hold=0.6)
    assert clearances(0.3, fallen.hold) == pytest.approx([0.6, 0.45, 0.375, 0.3375, 0.3])
    assert dataclasses.replace(fallen, hold=0.0).hold == 0.3  # never less than it keeps
    assert clearances(0.3, 0.3) == [0.3]


def test_a_redrawn_track_knows_the_room_around_it() -> None:
    world, plan = lane()
    env = make_env(
        racecar_mission(), 1, "rrt", world=world, plan=plan, drivable_guide=FACTOR,
        guide_feedforward=1.0, feedforward_law="pursuit",
    )  # fmt: skip
    try:
        track = env.legs[0].track
        assert track.slack is not None
        expected = world.obstacle_distance(track.points) - RADIUS
        np.testing.assert_allclose(track.slack, expected)
        assert track.slack.min() >= -1e-9  # the redraw keeps at least the robot's radius
    finally:
        env.close()


def test_a_scaled_residual_corrects_the_pursuit_without_overriding_it() -> None:
    points = np.array([[0.05 * i, 1.0] for i in range(201)])  # 10 m east along y = 1
    world = World(np.array([[0.0, 12.0], [0.0, 5.0]]), [], {})
    robot = make_robot("racecar", world, RADIUS)
    try:
        full = ActionShaping(robot, EnvOptions(**PURSUIT_LAW))
        scaled = ActionShaping(robot, EnvOptions(**PURSUIT_LAW, residual_scale=0.3))
        robot.reset(np.array([2.0, 1.3]), np.random.default_rng(0), heading=0.0)
        track = Track.dense(points, 21)
        pursuit = full.apply(np.zeros(2), track, 4)
        assert pursuit[1] < -0.1  # 0.3 m left of the track: it turns right, back to it
        np.testing.assert_allclose(scaled.apply(np.zeros(2), track, 4), pursuit)
        hard_left = np.array([0.0, 1.0])
        overridden = full.apply(hard_left, track, 4)[1]
        corrected = scaled.apply(hard_left, track, 4)[1]
        assert overridden == pytest.approx(pursuit[1] + 1.0) and overridden > 0  # turns away
        assert corrected == pytest.approx(pursuit[1] + 0.3) and corrected < 0  # still back
        assert scaled.apply(hard_left, track, 4)[0] == full.apply(hard_left, track, 4)[0]
    finally:
        robot.close()
    with pytest.raises(EnvConfigError, match="<= 1") as err:
        EnvOptions(residual_scale=1.5)
    assert err.value.field == "options.residual_scale"


def test_a_world_frame_robot_s_whole_correction_is_scaled() -> None:
    points = np.array([[0.05 * i, 1.0] for i in range(201)])
    world = World(np.array([[0.0, 12.0], [0.0, 5.0]]), [], {})
    robot = make_robot("point", world, 0.1)
    try:
        law: dict[str, Any] = {"guide_feedforward": 0.5}
        full = ActionShaping(robot, EnvOptions(**law))
        scaled = ActionShaping(robot, EnvOptions(**law, residual_scale=0.3))
        robot.reset(np.array([2.0, 1.0]), np.random.default_rng(0))
        track, nudge = Track.dense(points, 21), np.array([0.2, -0.2])
        base = full.apply(np.zeros(2), track, 4)
        assert np.all(np.abs(base) < 0.7)
        np.testing.assert_allclose(full.apply(nudge, track, 4) - base, nudge)
        np.testing.assert_allclose(scaled.apply(nudge, track, 4) - base, 0.3 * nudge)
    finally:
        robot.close()
