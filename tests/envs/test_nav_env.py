"""The navigation env: Gymnasium conformance, episodes, observation layout, bad input.

The helpers at the top (worlds, missions, planned missions) are shared with
``test_scripted.py`` and ``test_rewards.py``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env

from envs.errors import EnvConfigError
from envs.factory import ENV_ID, make_env
from envs.nav_env import NavEnv
from envs.options import EnvOptions
from envs.rays import RAY_SECONDS, RayCaster, default_ray_range
from envs.rewards import REWARD_MODES
from envs.robots import RobotConfigError, make_robot
from envs.robots.unicycle import UnicycleParams
from envs.spec import RobotSpec
from planner.decompose import SubTask, split_subtask
from planner.geometry.shapes import Ball, Box, Polygon
from planner.geometry.world import World
from planner.plan import MissionPlan, plan_mission
from planner.search.planner_spec import PlannerSpec

# ------------------------------------------------------------------------------ shared helpers
CLEARANCE = 0.35
"""Planning clearance: wider than the robots (0.1-0.3) so scripted controllers have slack."""


def world_2d() -> World:
    return World(
        np.array([[0.0, 10.0], [0.0, 10.0]]),
        [
            Box(np.array([4.0, 0.0]), np.array([5.0, 5.5])),
            Ball(np.array([7.5, 8.2]), 0.7),
            Polygon(np.array([[1.5, 4.0], [3.0, 4.0], [2.2, 5.2]])),
        ],
        {
            "g1": Ball(np.array([8.5, 2.0]), 0.8),
            "g2": Box(np.array([1.0, 8.0]), np.array([2.5, 9.5])),
        },
    )


def world_3d() -> World:
    return World(
        np.array([[0.0, 6.0], [0.0, 6.0], [0.0, 3.0]]),
        [
            Box(np.array([2.5, 0.0, 0.0]), np.array([3.5, 4.0, 3.0])),
            Ball(np.array([4.5, 4.7, 1.5]), 0.5),
        ],
        {"g1": Ball(np.array([5.0, 1.0, 1.5]), 0.5), "g2": Ball(np.array([1.0, 5.0, 1.5]), 0.5)},
    )


START_2D = [1.0, 1.0]
START_3D = [1.0, 1.0, 1.0]


@dataclass(frozen=True)
class Prebuilt:
    """A world section handing back a prebuilt world (``build`` is what ``make_env`` calls)."""

    world: World

    def build(self, keep_clear: Sequence[np.ndarray] = ()) -> World:
        return self.world


@dataclass(frozen=True)
class Mission:
    """The two sections ``make_env`` reads of a mission."""

    world: Prebuilt
    robot: RobotSpec


@cache
def planned(dim: int, task: str, clearance: float = CLEARANCE) -> tuple[World, MissionPlan]:
    """A world and a real plan of ``task`` in it (cached: with the default 1000 refining
    iterations a plan takes up to about a second)."""
    world = world_2d() if dim == 2 else world_3d()
    start = np.array(START_2D if dim == 2 else START_3D)
    options = PlannerSpec(seed=0, time_limit=20.0)
    return world, plan_mission(world, task, start, clearance, options)


FINITE = "<>(g1 && <>g2)"
INFINITE = "[]<>g1 && []<>g2"

ROBOTS = [("unicycle", 2, 0.2), ("point", 2, 0.2), ("point", 3, 0.2), ("quadrotor", 3, 0.15)]
ROBOTS += [("racecar", 2, 0.3)]
ROBOT_IDS = [f"{m}-{d}D" for m, d, _ in ROBOTS]


def mission(model: str, dim: int, radius: float = 0.2, heading: float | None = None) -> Mission:
    world = world_2d() if dim == 2 else world_3d()
    start = list(START_2D if dim == 2 else START_3D)
    if heading is not None:
        start.append(heading)
    return Mission(Prebuilt(world), RobotSpec(model=model, start=start, radius=radius))


def build_env(
    model: str,
    dim: int,
    reward: str = "rrt",
    radius: float = 0.2,
    task: str = INFINITE,
    **kw: Any,
) -> NavEnv:
    """The env of sub-task 0 (the whole lasso for g-rrt) of ``task`` for ``model``."""
    world, plan = planned(dim, task)
    sub = None if reward == "g-rrt" else plan.subtasks[0]
    return make_env(mission(model, dim, radius), sub, reward, world=world, plan=plan, **kw)


@pytest.fixture
def envs() -> Iterator[list[NavEnv]]:
    """Envs built by a test, closed afterwards (the racecar holds a PyBullet server)."""
    built: list[NavEnv] = []
    yield built
    for env in built:
        env.close()


# ------------------------------------------------------------------------------ conformance
@pytest.mark.parametrize(("model", "dim", "radius"), ROBOTS, ids=ROBOT_IDS)
@pytest.mark.parametrize("reward", list(REWARD_MODES))
def test_check_env_every_robot_and_reward(
    envs: list[NavEnv], model: str, dim: int, radius: float, reward: str
) -> None:
    env = build_env(model, dim, reward, radius, rays=4 if model == "unicycle" else 0)
    envs.append(env)
    check_env(env, warn=True)


@pytest.mark.parametrize(
    ("model", "dim", "options"),
    [
        ("unicycle", 2, {"observation": "paper", "rays": 5}),
        ("quadrotor", 3, {"rays": 6, "lookahead": 5}),
        ("unicycle", 2, {"curriculum": 0.7, "start_noise": 0.4, "heading_noise": math.pi}),
        ("racecar", 2, {"min_forward": 0.1, "stall_steps": 3, "stall_penalty": -0.2}),
    ],
)
def test_check_env_with_options(
    envs: list[NavEnv], model: str, dim: int, options: dict[str, Any]
) -> None:
    env = build_env(model, dim, "rrt", 0.15 if model == "quadrotor" else 0.2, **options)
    envs.append(env)
    check_env(env, warn=True)


def test_gymnasium_make_builds_the_registered_env() -> None:
    world, plan = planned(2, INFINITE)
    env = gym.make(
        ENV_ID, mission=mission("unicycle", 2), subtask=1, reward="rrt", world=world, plan=plan
    )
    try:
        obs, info = env.reset(seed=3)
        assert env.observation_space.contains(obs)
        assert isinstance(env.unwrapped, NavEnv) and info["is_success"] is False
        obs, _, _, _, info = env.step(env.action_space.sample())
        assert "is_success" in info and "progress_index" in info
    finally:
        env.close()


# ------------------------------------------------------------------------------ episodes
def drive_straight(
    env: NavEnv, action: np.ndarray, limit: int
) -> list[tuple[float, bool, bool, dict]]:
    out = []
    for _ in range(limit):
        _, reward, terminated, truncated, info = env.step(action)
        out.append((reward, terminated, truncated, info))
        if terminated or truncated:
            break
    return out


def test_crash_ends_with_r_minus_before_goal_and_progress(envs: list[NavEnv]) -> None:
    """A goal region overlapping an obstacle: the step that enters both is a crash (R- first)."""
    world = World(
        np.array([[0.0, 10.0], [0.0, 4.0]]),
        [Box(np.array([6.0, 0.0]), np.array([7.0, 4.0]))],
        {"g": Box(np.array([5.5, 1.0]), np.array([8.0, 3.0]))},
    )
    path = np.array([[1.0, 2.0], [6.5, 2.0]])
    sub = SubTask(0, "prefix", "g", path[0], path, 0, 0)
    spec = RobotSpec(model="unicycle", start=[1.0, 2.0, 0.0], radius=0.6)
    for reward in ("rrt-paper", "rrt"):
        env = make_env(Mission(Prebuilt(world), spec), sub, reward, world=world)
        envs.append(env)
        env.reset(seed=0)
        steps = drive_straight(env, np.array([1.0, 0.0]), 200)
        r, terminated, truncated, info = steps[-1]
        assert terminated and not truncated
        assert info["collision"] and info["is_success"] is False
        assert r == env.mode.crash
        # The robot earned progress on the way.
        assert any(s[0] > 0 for s in steps[:-1])


@pytest.mark.parametrize(("judge", "met_beyond"), [("region", 5.0), ("guide_end", 7.5)])
def test_the_goal_judge_decides_where_a_sub_task_is_met(
    envs: list[NavEnv], judge: str, met_beyond: float
) -> None:
    """A wide goal region whose guide ends deep inside it: the region judge meets the sub-task
    on entering the region, the paper's ``D = 0`` only in the guide's last r-ball."""
    world = World(
        np.array([[0.0, 10.0], [0.0, 4.0]]),
        [],
        {"g": Box(np.array([5.0, 1.0]), np.array([9.5, 3.0]))},
    )
    path = np.array([[1.0, 2.0], [8.0, 2.0]])
    sub = SubTask(0, "prefix", "g", path[0], path, 0, 0)
    spec = RobotSpec(model="unicycle", start=[1.0, 2.0, 0.0], radius=0.1)
    env = make_env(Mission(Prebuilt(world), spec), sub, "rrt", world=world, goal_judge=judge)
    envs.append(env)
    env.reset(seed=0)
    steps = drive_straight(env, np.array([1.0, 0.0]), 400)
    _, terminated, _, info = steps[-1]
    assert terminated and info["is_success"] is True
    x = float(env.robot.position()[0])
    assert met_beyond <= x < met_beyond + 0.5, x
    assert (info["d"] == 0.0) == (judge == "guide_end")


def test_step_limit_truncates_without_success(envs: list[NavEnv]) -> None:
    env = build_env("unicycle", 2, max_steps=7)
    envs.append(env)
    env.reset(seed=0)
    steps = drive_straight(env, np.zeros(2), 50)
    assert len(steps) == 7
    r, terminated, truncated, info = steps[-1]
    assert truncated and not terminated and info["is_success"] is False
    assert r == pytest.approx(-0.01)


def test_default_step_limit_is_three_times_the_guide_time() -> None:
    env = build_env("point", 2)
    speed_steps = env.guide_length / (1.0 * 0.1)
    assert env.max_steps == max(50, math.ceil(3.0 * speed_steps))
    racecar = build_env("racecar", 2, radius=0.3)
    try:
        assert racecar.max_steps == max(50, math.ceil(3.0 * racecar.guide_length / (1.0 * 0.1)))
    finally:
        racecar.close()


@pytest.mark.parametrize("penalty", [None, -0.5])
def test_stall_ends_the_episode(envs: list[NavEnv], penalty: float | None) -> None:
    env = build_env("point", 2, stall_steps=5, stall_penalty=penalty)
    envs.append(env)
    env.reset(seed=0)
    steps = drive_straight(env, np.zeros(2), 50)
    assert len(steps) == 5
    r, terminated, truncated, info = steps[-1]
    assert info["stalled"] and info["is_success"] is False
    if penalty is None:
        assert truncated and not terminated and r == pytest.approx(-0.01)
    else:
        assert terminated and not truncated and r == penalty


def test_stall_window_follows_the_ball_spacing_and_the_robot(envs: list[NavEnv]) -> None:
    wide = build_env("point", 2, r_ball=2.0, stall_spacings=4.0)
    narrow = build_env("point", 2, r_ball=0.25, stall_spacings=4.0)
    slow = build_env("point", 2, r_ball=2.0, stall_spacings=2.0)
    quad = build_env("quadrotor", 3, r_ball=0.25, stall_spacings=4.0)
    fixed = build_env("point", 2, r_ball=2.0, stall_steps=7)
    envs.extend([wide, narrow, slow, quad, fixed])
    assert wide.stall_steps == 160  # 4 spacings of 4 m at 1 m/s, steps of 0.1 s
    assert slow.stall_steps == 80
    assert narrow.stall_steps == 30  # 2 m take 2 s: the 3 s floor
    assert quad.stall_steps == 60  # the floor in the quadrotor's 0.05 s steps
    assert fixed.stall_steps == 7
    wide.reset(seed=0)
    steps = drive_straight(wide, np.zeros(2), 400)
    assert len(steps) == 160 and steps[-1][3]["stalled"]
    assert wide.steps_without_progress == 160


def test_stall_is_set_once() -> None:
    with pytest.raises(EnvConfigError, match=r"stall_spacings.*not both"):
        EnvOptions(stall_steps=30, stall_spacings=4.0)
    with pytest.raises(EnvConfigError, match=r"stall_spacings.*> 0"):
        EnvOptions(stall_spacings=0.0)


def test_curriculum_starts_at_a_ball_with_the_matching_index(envs: list[NavEnv]) -> None:
    env = build_env("unicycle", 2, curriculum=1.0)
    envs.append(env)
    guide = env.legs[0].guide
    seen = set()
    for seed in range(25):
        obs, info = env.reset(seed=seed)
        x = env.robot.position()
        ball = int(np.argmin(np.linalg.norm(guide.centers - x, axis=1)))
        assert np.allclose(guide.centers[ball], x)
        assert ball < guide.num_balls - 1
        assert info["progress_index"] == max(ball, guide.locate(x)) >= ball
        assert obs[env.robot.state_dim] == pytest.approx(
            (info["progress_index"] + 1) / guide.num_balls
        )
        assert info["distance_to_go"] == pytest.approx(guide.dist_to_go[info["progress_index"]])
        seen.add(ball)
    assert len(seen) > 5
    plain = build_env("unicycle", 2)
    envs.append(plain)
    for seed in range(3):
        plain.reset(seed=seed)
        assert np.allclose(plain.robot.position(), plain.legs[0].subtask.start)


def test_curriculum_on_the_whole_lasso_sets_the_stage(envs: list[NavEnv]) -> None:
    env = build_env("point", 2, "g-rrt", curriculum=1.0)
    envs.append(env)
    stages = set()
    for seed in range(30):
        _, info = env.reset(seed=seed)
        leg = env.legs[info["stage"]]
        assert leg.offset <= info["progress_index"] < leg.offset + leg.guide.num_balls
        assert env._automaton is not None and env._automaton.stage == info["stage"]
        stages.add(info["stage"])
    assert len(stages) >= 3


def test_start_noise_stays_free_and_in_the_start_regions(envs: list[NavEnv]) -> None:
    world, plan = planned(2, INFINITE)
    sub = plan.subtasks[1]  # starts inside g1
    env = make_env(mission("point", 2), sub, world=world, plan=plan, start_noise=0.5)
    envs.append(env)
    regions = world.labels(sub.start)
    assert regions
    moved = 0
    for seed in range(10):
        env.reset(seed=seed)
        x = env.robot.position()
        assert np.linalg.norm(x - sub.start) <= 0.5 + 1e-9
        assert not world.in_collision(x[None], 0.2)[0]
        assert world.labels(x) == regions
        moved += not np.allclose(x, sub.start)
    assert moved >= 8


def test_deterministic_for_a_seed() -> None:
    runs = []
    for _ in range(2):
        env = build_env("unicycle", 2, curriculum=0.5, start_noise=0.3, heading_noise=1.0)
        actions = np.random.default_rng(5).uniform(-1, 1, size=(120, 2))
        trace = []
        obs, _ = env.reset(seed=11)
        trace.append(obs)
        for a in actions:
            obs, r, te, tr, _ = env.step(a)
            trace.append(np.append(obs, r))
            if te or tr:
                obs, _ = env.reset()
                trace.append(obs)
        runs.append(trace)
    first, second = runs
    assert len(first) == len(second)
    assert all(np.array_equal(a, b) for a, b in zip(first, second, strict=True))
    other = build_env("unicycle", 2, curriculum=0.5, start_noise=0.3, heading_noise=1.0)
    starts = {tuple(other.reset(seed=s)[0].tolist()) for s in range(5)}
    assert len(starts) == 5


def test_reset_options_explicit_start_and_keep_robot(envs: list[NavEnv]) -> None:
    env = build_env("unicycle", 2)
    envs.append(env)
    env.reset(seed=0, options={"position": [2.0, 2.0], "heading": 0.5})
    assert np.allclose(env.robot.position(), [2.0, 2.0])
    assert env.robot.state[2] == pytest.approx(0.5)
    env.step(np.array([1.0, 0.0]))
    here = env.robot.position()
    _, info = env.reset(options={"keep_robot": True})
    assert np.allclose(env.robot.position(), here) and info["steps"] == 0
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"teleport": True})
    with pytest.raises(ValueError, match="coordinates"):
        env.reset(options={"position": [1.0, 2.0, 3.0]})


# ------------------------------------------------------------------------------ observation
def test_guided_observation_layout_in_the_robot_frame(envs: list[NavEnv]) -> None:
    env = build_env("unicycle", 2, lookahead=2)
    envs.append(env)
    guide = env.legs[0].guide
    n = env.robot.state_dim
    assert env.observation_space.shape == (n + 1 + 2 * 2,)
    heading = math.atan2(*(guide.centers[1] - guide.centers[0])[::-1])
    obs, info = env.reset(seed=0, options={"position": guide.centers[0], "heading": heading})
    assert info["progress_index"] == guide.locate(guide.centers[0])
    lo, hi = env.robot.state_low, env.robot.state_high
    raw = env.robot.observation()
    assert np.allclose(obs[:n], 2 * (raw - lo) / (hi - lo) - 1, atol=1e-6)
    i = info["progress_index"]
    ahead = guide.centers[min(i + 1, guide.num_balls - 1)] - guide.centers[0]
    c, s = math.cos(heading), math.sin(heading)
    scale = 2 * guide.r * 3
    expected = np.clip(
        [(c * ahead[0] + s * ahead[1]) / scale, (c * ahead[1] - s * ahead[0]) / scale], -1, 1
    )
    assert np.allclose(obs[n + 1 : n + 3], expected, atol=1e-5)


def test_world_frame_offsets_and_paper_layout(envs: list[NavEnv]) -> None:
    env = build_env("quadrotor", 3, radius=0.15, lookahead=1, lookahead_range=2.0)
    envs.append(env)
    obs, info = env.reset(seed=0)
    guide, n = env.legs[0].guide, env.robot.state_dim
    nxt = guide.centers[min(info["progress_index"] + 1, guide.num_balls - 1)]
    assert np.allclose(obs[n + 1 :], np.clip((nxt - env.robot.position()) / 2.0, -1, 1), atol=1e-5)
    paper = build_env("unicycle", 2, observation="paper", rays=3)
    envs.append(paper)
    assert paper.observation_space.shape == (4 + 1 + 3,)


def brute_force_ray(world: World, x: np.ndarray, u: np.ndarray, max_range: float) -> float:
    t = np.linspace(0.0, max_range, 20001)
    pts = x + t[:, None] * u
    hit = world.in_collision(pts, 0.0)
    return float(t[np.argmax(hit)]) if hit.any() else max_range


@pytest.mark.parametrize("dim", [2, 3])
def test_rays_match_a_brute_force_march(dim: int) -> None:
    world = world_2d() if dim == 2 else world_3d()
    caster = RayCaster(world, 12, 4.0)
    rng = np.random.default_rng(dim)
    for x in world.sample_free(rng, 8, 0.1):
        theta = float(rng.uniform(-math.pi, math.pi)) if dim == 2 else 0.0
        rotation = (math.cos(theta), math.sin(theta)) if dim == 2 else None
        got = caster.cast(x.tolist(), rotation)
        for k in range(12):
            u = caster.directions[k]
            if dim == 2:
                u = np.array(
                    [
                        math.cos(theta) * u[0] - math.sin(theta) * u[1],
                        math.sin(theta) * u[0] + math.cos(theta) * u[1],
                    ]
                )
            assert got[k] == pytest.approx(brute_force_ray(world, x, u, 4.0), abs=2e-3)


def test_render_returns_an_rgb_array(envs: list[NavEnv]) -> None:
    for dim in (2, 3):
        env = build_env("point", dim, render_mode="rgb_array")
        envs.append(env)
        env.reset(seed=0)
        for _ in range(5):
            env.step(env.action_space.sample())
        frame = env.render()
        assert frame is not None and frame.dtype == np.uint8 and frame.ndim == 3
        assert frame.shape[2] == 3 and frame.shape[1] >= frame.shape[0] >= 300
        assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 5
        assert len(env.trail) == 6


# ------------------------------------------------------------------------------ bad input
def test_bad_input_fails_at_construction_with_clear_errors() -> None:
    world, plan = planned(2, INFINITE)
    m, sub = mission("unicycle", 2), plan.subtasks[0]
    with pytest.raises(EnvConfigError, match="unknown reward mode 'dense'"):
        make_env(m, sub, "dense", world=world)
    tank = Mission(
        Prebuilt(world),
        RobotSpec.model_construct(model="tank", start=[1.0, 1.0], radius=0.2, params={}),  # type: ignore[arg-type]
    )
    with pytest.raises(RobotConfigError, match="unknown robot model 'tank'"):
        make_env(tank, sub, world=world)
    with pytest.raises(EnvConfigError, match=r"robot\.start.*3D position but the world is 2D"):
        make_env(
            Mission(Prebuilt(world), RobotSpec(model="point", start=[1, 1, 1])), sub, world=world
        )
    bad_sub = SubTask(0, "prefix", "g1", np.array([1.0, 1.0, 0.0]), sub.path, 0, 1)
    with pytest.raises(EnvConfigError, match=r"subtask\.start"):
        make_env(m, bad_sub, world=world)
    w3 = world_3d()
    flat = Mission(Prebuilt(w3), RobotSpec(model="unicycle", start=[1, 1]))
    with pytest.raises(RobotConfigError, match="2D workspace, but the world is 3D"):
        make_env(flat, bad3d(), world=w3)
    for reward in ("tl", "g-rrt"):
        with pytest.raises(EnvConfigError, match="needs the mission plan"):
            make_env(m, sub if reward == "tl" else None, reward, world=world)
    with pytest.raises(EnvConfigError, match="pass subtask=None"):
        make_env(m, sub, "g-rrt", world=world, plan=plan)
    with pytest.raises(EnvConfigError, match="unknown env option"):
        make_env(m, sub, world=world, lookahed=2)
    with pytest.raises(EnvConfigError, match=r"options\.curriculum"):
        make_env(m, sub, world=world, curriculum=1.5)
    with pytest.raises(EnvConfigError, match="does not use 'step_cost'"):
        make_env(m, sub, "rrt-paper", world=world, rewards={"step_cost": 0.1})
    with pytest.raises(EnvConfigError, match="in collision"):
        blocked = SubTask(
            0, "prefix", "g1", np.array([4.5, 1.0]), np.array([[4.5, 1.0], [8.5, 2.0]]), 0, 1
        )
        make_env(m, blocked, world=world)
    with pytest.raises(EnvConfigError, match="index 9 out of range"):
        make_env(m, 9, world=world, plan=plan)
    with pytest.raises(EnvConfigError, match="no region 'g9'"):
        make_env(m, SubTask(0, "prefix", "g9", sub.start, sub.path, 0, 1), world=world)


def bad3d() -> SubTask:
    path = np.array([[1.0, 1.0, 1.0], [2.0, 1.0, 1.0]])
    return SubTask(0, "prefix", "", path[0], path, 0, 0)


@pytest.mark.parametrize(
    "action",
    [
        np.array([1.5, 0.0]),
        np.array([0.0, -1.01]),
        np.array([0.1, 0.2, 0.3]),
        np.array([np.nan, 0.0]),
        np.zeros((1, 2)),
    ],
)
def test_bad_actions_raise_instead_of_clipping(envs: list[NavEnv], action: np.ndarray) -> None:
    env = build_env("unicycle", 2)
    envs.append(env)
    env.reset(seed=0)
    before = env.robot.state
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    assert np.array_equal(env.robot.state, before)


def test_min_forward_maps_the_forward_command(envs: list[NavEnv]) -> None:
    env = build_env("unicycle", 2, min_forward=0.5)
    envs.append(env)
    env.reset(seed=0, options={"position": [1.0, 1.0], "heading": 0.0})
    env.step(np.array([-1.0, 0.0]))  # the slowest command still drives at half speed
    assert env.robot.position()[0] == pytest.approx(1.0 + 0.5 * 1.0 * 0.1)
    with pytest.raises(ValueError, match="not clipped"):
        env.step(np.array([-1.5, 0.0]))
    with pytest.raises(EnvConfigError, match="min_forward"):
        build_env("point", 2, min_forward=0.2)


def test_guide_feedforward_drives_along_the_guide_and_the_policy_corrects_it(
    envs: list[NavEnv],
) -> None:
    from envs.feedforward import pursuit_direction
    from envs.track import pursuit_target

    env = build_env("point", 2, guide_feedforward=0.5)
    envs.append(env)
    env.reset(seed=0, options={"position": START_2D})
    track = env.legs[0].track
    end = track.points[-1]
    assert np.array_equal(pursuit_direction(track, len(track.points), end, 0.5), np.zeros(2))
    # the point robot (an acceleration command) heads for the point of the guide one braking
    # length ahead (max_speed^2 / max_accel = 0.5 m), from rest at full acceleration
    target = pursuit_target(env.legs[0].track, -1, START_2D, 0.5)
    direction = (target - START_2D) / np.linalg.norm(target - START_2D)
    env.step(np.zeros(2))  # a zero action accelerates along the feed-forward
    velocity = env.robot.state[2:]
    assert np.allclose(velocity / np.linalg.norm(velocity), direction, atol=1e-6)
    env.reset(seed=0, options={"position": START_2D})
    env.step(-0.5 * direction)  # the policy can cancel it
    assert np.allclose(env.robot.state[2:], 0.0)
    with pytest.raises(EnvConfigError, match=r"guide_feedforward: must be in \(0, 1\]"):
        build_env("point", 2, guide_feedforward=0.0)


def test_guide_feedforward_steers_a_heading_robot_toward_the_guide_ahead(
    envs: list[NavEnv],
) -> None:
    from envs.feedforward import HEADING_LOOKAHEAD, heading_direction, steering_toward
    from envs.robots import nominal_speed
    from envs.track import pursuit_target

    env = build_env("unicycle", 2, guide_feedforward=1.0, min_forward=0.2)
    envs.append(env)
    track = env.legs[0].track
    toward = heading_direction(env.robot, track, -1, START_2D)
    ahead = HEADING_LOOKAHEAD * nominal_speed(env.robot)
    target = pursuit_target(track, -1, START_2D, ahead)
    assert np.allclose(toward, (target - START_2D) / np.linalg.norm(target - START_2D))
    away = math.atan2(-toward[1], -toward[0])  # facing straight away: a full turn
    env.reset(seed=0, options={"position": START_2D, "heading": away + 0.1})
    assert abs(steering_toward(away + 0.1, toward)) == 1.0
    before = env.robot.heading()
    env.step(np.zeros(2))
    turned = math.remainder(env.robot.heading() - before, math.tau)
    # the error is pi - 0.1 (to the left): a full left turn, at any forward command
    params = env.robot.params
    assert isinstance(params, UnicycleParams)
    assert turned == pytest.approx(params.max_turn_rate * env.robot.dt)
    heading = math.atan2(toward[1], toward[0])
    assert steering_toward(heading + 0.2, toward) == pytest.approx(-0.2 / (math.pi / 2))
    assert steering_toward(heading, np.zeros(2)) == 0.0


def test_feedforward_slowdown_turns_back_on_the_tightest_circle(envs: list[NavEnv]) -> None:
    from envs.feedforward import heading_direction

    def speed_after_zero_action(heading_error: float, **options: Any) -> float:
        env = build_env("unicycle", 2, guide_feedforward=1.0, min_forward=0.2, **options)
        envs.append(env)
        toward = heading_direction(env.robot, env.legs[0].track, -1, START_2D)
        facing = math.atan2(toward[1], toward[0]) + heading_error
        env.reset(seed=0, options={"position": START_2D, "heading": facing})
        env.step(np.zeros(2))
        moved = np.linalg.norm(env.robot.position() - np.asarray(START_2D))
        return float(moved / env.robot.dt)

    # speeds in units of the unicycle's max_speed (1 m/s); the zero action's forward command
    # maps to 0.2 + 0.8 * 0.5 = 0.6, the slowest to min_forward; a chord of the turned arc is
    # within 0.2 % of its length
    slowdown = {"feedforward_slowdown": True}
    # facing away: a full turn at the slowest forward speed, not at the zero action's
    assert speed_after_zero_action(math.pi - 0.1, **slowdown) == pytest.approx(0.2, rel=3e-3)
    assert speed_after_zero_action(math.pi - 0.1) == pytest.approx(0.6, rel=3e-3)
    # facing along the guide: no slowdown; at 45 degrees a half turn, half the way down
    assert speed_after_zero_action(0.0, **slowdown) == pytest.approx(0.6, rel=1e-6)
    assert speed_after_zero_action(math.pi / 4, **slowdown) == pytest.approx(0.4, rel=3e-3)
    with pytest.raises(EnvConfigError, match="feedforward_slowdown"):
        build_env("unicycle", 2, guide_feedforward=1.0, feedforward_slowdown=1)


def test_options_dataclass_documents_every_field() -> None:
    import ast
    import inspect

    import envs.options as module

    tree = ast.parse(inspect.getsource(module))
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "EnvOptions")
    documented = {
        cls.body[i].target.id  # type: ignore[attr-defined]
        for i in range(len(cls.body) - 1)
        if isinstance(cls.body[i], ast.AnnAssign)
        and isinstance(cls.body[i + 1], ast.Expr)
        and isinstance(cls.body[i + 1].value, ast.Constant)  # type: ignore[attr-defined]
    }
    assert documented == set(EnvOptions.field_names())


def test_split_subtask_into_shorter_legs(envs: list[NavEnv]) -> None:
    world, plan = planned(2, FINITE)
    sub = plan.subtasks[0]
    pieces = split_subtask(sub, 3.0)
    length = float(np.linalg.norm(np.diff(sub.path, axis=0), axis=1).sum())
    assert len(pieces) == math.ceil(length / 3.0) >= 2
    assert np.array_equal(pieces[0].start, sub.start) and np.array_equal(
        pieces[-1].path[-1], sub.path[-1]
    )
    for a, b in itertools.pairwise(pieces):
        assert (
            np.array_equal(a.path[-1], b.start) and a.goal == "" and a.next_nba_state == a.nba_state
        )
    for p in pieces:
        piece_length = float(np.linalg.norm(np.diff(p.path, axis=0), axis=1).sum())
        assert piece_length == pytest.approx(length / len(pieces))
    assert (pieces[-1].goal, pieces[-1].next_nba_state) == (sub.goal, sub.next_nba_state)
    # A piece without a goal region succeeds in the last ball of its guide.
    env = make_env(mission("point", 2), pieces[0], world=world, plan=plan)
    envs.append(env)
    end = pieces[0].path[-1]
    env.reset(seed=0, options={"position": end - 0.05 * (end - pieces[0].path[-2])})
    _, reward, terminated, _, info = env.step(np.zeros(2))
    assert terminated and info["is_success"] is True and reward == 20.0 and info["d"] == 0.0
    with pytest.raises(ValueError, match="max_length"):
        split_subtask(sub, 0.0)


def test_r_ball_within_clearance_keeps_every_ball_clear_of_obstacles(envs: list[NavEnv]) -> None:
    # r-balls of 1 m around a guide 0.35 m clear of the obstacles: wide ones must reach into them
    world = world_2d()
    options = PlannerSpec(seed=0, time_limit=20.0, r_ball=1.0)
    plan = plan_mission(world, FINITE, np.array(START_2D), CLEARANCE, options)
    assert plan.r_ball == 1.0 and plan.clearance == CLEARANCE

    def env(**kw: Any) -> NavEnv:
        built = make_env(mission("unicycle", 2), plan.subtasks[0], world=world, plan=plan, **kw)
        envs.append(built)
        return built

    wide = env()
    held = env(r_ball_within_clearance=True)
    given = env(r_ball_within_clearance=True, r_ball=1.5)
    assert {leg.guide.r for leg in wide.legs} == {plan.r_ball}
    assert {leg.guide.r for leg in held.legs} == {plan.clearance}
    assert {leg.guide.r for leg in given.legs} == {1.5}
    for leg in held.legs:
        assert not world.in_collision(leg.guide.centers, plan.clearance - 1e-6).any()
    assert any(world.in_collision(leg.guide.centers, plan.r_ball).any() for leg in wide.legs)
    with pytest.raises(EnvConfigError, match="r_ball_within_clearance"):
        EnvOptions(r_ball_within_clearance=1)  # type: ignore[arg-type]


def square_world(side: float, dim: int = 2) -> World:
    return World(np.array([[0.0, side]] * dim), [], {})


@pytest.mark.parametrize(
    ("model", "dim"), [("point", 2), ("point", 3), ("unicycle", 2), ("quadrotor", 3)]
)
def test_rays_see_in_the_robot_s_terms_whatever_the_world_s_size(model: str, dim: int) -> None:
    for side in (10.0, 60.0):
        robot = make_robot(model, square_world(side, dim), 0.2)
        try:
            assert default_ray_range(robot.params) == pytest.approx(RAY_SECONDS * 1.0)
        finally:
            robot.close()
    fast = make_robot(model, square_world(20.0, dim), 0.2, {"max_speed": 2.0})
    try:
        assert default_ray_range(fast.params) == pytest.approx(RAY_SECONDS * 2.0)
    finally:
        fast.close()


def test_a_car_that_turns_wide_sees_two_turning_radii_ahead() -> None:
    world = square_world(20.0)
    default, wide = (
        make_robot("racecar", world, 0.27),
        make_robot("racecar", world, 0.27, {"max_steering": 0.1}),
    )
    try:
        assert default_ray_range(default.params) == pytest.approx(RAY_SECONDS)
        rho = wide.params.min_turning_radius()
        assert 2.0 * rho > RAY_SECONDS
        assert default_ray_range(wide.params) == pytest.approx(2.0 * rho)
    finally:
        default.close()
        wide.close()


def test_an_env_s_rays_default_to_the_robot_s_range_and_obey_ray_range(envs: list[NavEnv]) -> None:
    default = build_env("unicycle", 2, rays=8)
    set_range = build_env("unicycle", 2, rays=8, ray_range=1.5)
    envs.extend([default, set_range])
    assert default.ray_caster is not None and set_range.ray_caster is not None
    assert default.ray_caster.max_range == pytest.approx(RAY_SECONDS)
    assert set_range.ray_caster.max_range == pytest.approx(1.5)
