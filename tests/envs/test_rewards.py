"""Reward modes, their constants, the goal tests and the automaton judge."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pytest

from envs.errors import EnvConfigError
from envs.factory import make_env
from envs.judge import AutomatonTracker, Stage
from envs.options import EnvOptions
from envs.rewards import REWARD_MODES, PaperReward, RewardConfig, reward_config, reward_mode
from planner.geometry.region_test import RegionTest
from planner.geometry.shapes import Ball
from planner.guidance import Guide, ProgressTracker
from planner.ltl.translate import translate
from tests.envs.test_nav_env import mission, planned


def test_paper_reward_is_exactly_the_papers() -> None:
    mode = reward_mode("rrt-paper")
    assert (mode.crash, mode.goal, mode.constants["progress"]) == (-100.0, 200.0, 5.0)
    assert mode.step_reward(True, 0.3, [0.0, 0.0]) == 5.0
    assert mode.step_reward(False, 0.0, [0.0, 0.0]) == 0.0
    custom = reward_mode("rrt-paper", RewardConfig(crash=-200.0, progress=1.0))
    assert custom.crash == -200.0 and custom.step_reward(True, 9.0, [0.0]) == 1.0


def test_scaled_reward_pays_metres_gained_minus_a_step_cost() -> None:
    mode = reward_mode("rrt")
    assert (mode.crash, mode.goal) == (-10.0, 20.0)
    assert mode.step_reward(True, 1.0, [0.0, 0.0]) == pytest.approx(0.5 - 0.01)
    assert mode.step_reward(False, 0.0, [0.0, 0.0]) == pytest.approx(-0.01)
    tuned = reward_mode("rrt", RewardConfig(progress=0.1, step_cost=0.0))
    assert tuned.step_reward(True, 0.5, [0.0, 0.0]) == pytest.approx(0.05)
    # Parking never beats crashing: the discounted cost of standing still stays far above R-.
    assert -mode.constants["step_cost"] / (1 - 0.99) > 10 * mode.crash / 100
    assert reward_mode("g-rrt").constants == mode.constants


def test_ned_reward_is_the_scaled_distance_to_the_goal_region() -> None:
    mode = reward_mode("ned")
    mode.bind_goal(RegionTest(Ball(np.array([5.0, 0.0]), 1.0)), [5.0, 0.0])
    assert mode.step_reward(False, 0.0, [0.0, 0.0]) == pytest.approx(-0.005 * 4.0)
    assert mode.step_reward(True, 1.0, [5.5, 0.0]) == 0.0
    mode.bind_goal(None, [3.0, 4.0])
    assert mode.step_reward(False, 0.0, [0.0, 0.0]) == pytest.approx(-0.005 * 5.0)
    assert reward_mode("tl").step_reward(True, 3.0, [0.0, 0.0]) == 0.0


def test_reward_configuration_errors() -> None:
    with pytest.raises(EnvConfigError, match="unknown reward mode"):
        reward_mode("sparse")
    with pytest.raises(EnvConfigError, match="'ned' does not use 'progress'"):
        reward_mode("ned", RewardConfig(progress=1.0))
    with pytest.raises(EnvConfigError, match="'tl' does not use 'step_cost'"):
        reward_mode("tl", RewardConfig(step_cost=0.1))
    with pytest.raises(EnvConfigError, match=r"rewards\.crash: must be finite"):
        RewardConfig(crash=-math.inf)
    with pytest.raises(EnvConfigError, match=r"rewards\.step_cost: must be >= 0"):
        RewardConfig(step_cost=-0.1)
    with pytest.raises(EnvConfigError, match=r"rewards\.goal: must be a number"):
        RewardConfig(goal="big")  # type: ignore[arg-type]
    with pytest.raises(EnvConfigError, match=r"rewards\.bonus: unknown reward constant"):
        reward_config({"bonus": 1.0})
    assert reward_config({"crash": -2}) == RewardConfig(crash=-2)
    assert set(REWARD_MODES) == {"rrt", "rrt-paper", "g-rrt", "ned", "tl"}


def test_automaton_tracker_follows_stages_and_detects_violations() -> None:
    nba = translate("!g2 U g1")
    target = next(iter(nba.successors(nba.initial, frozenset({"g1"}))))
    tracker = AutomatonTracker(nba, [Stage(nba.initial, target, "g1")])
    assert tracker.read(frozenset(), False) == 0
    assert tracker.read(frozenset({"g1"}), False) == 1 and tracker.done
    tracker.reset()
    assert not tracker.done
    assert tracker.read(frozenset({"g2"}), False) == -1
    with pytest.raises(EnvConfigError, match="not in the automaton"):
        AutomatonTracker(nba, [Stage(nba.initial, 99, "g1")])
    # A stage that stays in one state ends on entering its goal (or at the guide's end).
    loop = AutomatonTracker(nba, [Stage(target, target, "g2"), Stage(target, target, "")])
    assert loop.read(frozenset({"g1"}), True) == 0
    assert loop.read(frozenset({"g2"}), False) == 1 and loop.stage == 1
    assert loop.read(frozenset(), False) == 0
    assert loop.read(frozenset(), True) == 1 and loop.done


def test_tl_env_ends_on_a_specification_violation() -> None:
    world, plan = planned(2, "!g2 U g1")
    env = make_env(mission("point", 2), plan.subtasks[0], "tl", world=world, plan=plan)
    env.reset(seed=0, options={"position": [1.75, 8.75]})  # inside g2
    _, reward, terminated, truncated, info = env.step(np.zeros(2))
    assert terminated and not truncated and reward == -10.0
    assert info["violation"] and not info["collision"] and info["is_success"] is False


@pytest.mark.parametrize("reward", ["rrt", "rrt-paper", "ned"])
def test_every_reward_mode_ends_on_a_violation_when_the_env_has_the_plan(reward: str) -> None:
    world, plan = planned(2, "!g2 U g1")
    env = make_env(mission("point", 2), plan.subtasks[0], reward, world=world, plan=plan)
    env.reset(seed=0, options={"position": [1.75, 8.75]})  # inside g2, which !g2 U g1 forbids
    _, reward_, terminated, truncated, info = env.step(np.zeros(2))
    assert terminated and not truncated and reward_ == env.mode.crash
    assert info["violation"] and not info["collision"] and info["is_success"] is False
    # Inside the goal the sub-task succeeds as before; outside both regions it runs on.
    goal = world.regions["g1"]
    assert isinstance(goal, Ball)
    env.reset(seed=0, options={"position": list(goal.center)})
    assert env.step(np.zeros(2))[4]["is_success"]
    env.reset(seed=0, options={"start": 0})
    _, _, terminated, _, info = env.step(np.zeros(2))
    assert not terminated and not info["violation"]


def test_without_the_plan_a_sub_task_env_judges_only_its_goal_region() -> None:
    world, plan = planned(2, "!g2 U g1")
    env = make_env(mission("point", 2), plan.subtasks[0], "rrt", world=world)
    env.reset(seed=0, options={"position": [1.75, 8.75]})
    _, _, terminated, _, info = env.step(np.zeros(2))
    assert not terminated and not info["violation"]


def test_ned_env_pays_the_distance_to_the_goal_region() -> None:
    world, plan = planned(2, "<>(g1 && <>g2)")
    sub = plan.subtasks[0]
    env = make_env(mission("point", 2), sub, "ned", world=world, plan=plan)
    env.reset(seed=0)
    _, reward, _, _, _ = env.step(np.zeros(2))
    expected = float(world.regions[sub.goal].distance(env.robot.position()[None])[0])
    assert reward == pytest.approx(-0.005 * expected)


def test_dense_progress_pays_the_change_of_a_potential_toward_the_next_ball() -> None:
    world, plan = planned(2, "<>(g1 && <>g2)")
    sub = plan.subtasks[0]
    options = EnvOptions(dense_progress=True)
    env = make_env(mission("point", 2), sub, "rrt", world=world, plan=plan, options=options)
    guide = env.legs[0].guide
    mode = reward_mode("rrt")
    per_metre, step_cost = mode.constants["progress"], mode.constants["step_cost"]

    def potential(x: np.ndarray, index: int) -> float:
        if index + 1 >= guide.num_balls:
            return 0.0
        return float(guide.dist_to_go[index + 1] + np.linalg.norm(x - guide.centers[index + 1]))

    _, info = env.reset(seed=0, options={"start": 0})
    x, index = env.robot.position().copy(), info["progress_index"]
    rng = np.random.default_rng(0)
    gained = 0.0
    for t in range(60):
        towards = guide.centers[min(index + 1, guide.num_balls - 1)] - x
        action = towards / max(float(np.linalg.norm(towards)), 1e-9)
        if t % 3 == 2:
            action = rng.uniform(-1.0, 1.0, 2)  # detours are paid back when they return
        _, reward, terminated, truncated, info = env.step(action.astype(np.float32))
        if terminated or truncated:
            break
        after, now = env.robot.position().copy(), info["progress_index"]
        expected = potential(x, index) - potential(after, now)
        assert reward == pytest.approx(per_metre * expected - step_cost, abs=1e-9)
        gained += expected
        x, index = after, now
    assert gained > 0.5  # the robot went along the guide, and was paid on the way
    ball_only = make_env(mission("point", 2), sub, "rrt", world=world, plan=plan)
    ball_only.reset(seed=0, options={"start": 0})
    _, reward, *_ = ball_only.step(np.zeros(2, dtype=np.float32))
    assert reward == pytest.approx(-step_cost)  # no new ball: only the step cost


Flags = Sequence[bool] | np.ndarray
"""One flag per step of a batch."""


def paper_rewards(
    mode: PaperReward, crashed: Flags, reached: Flags, improved: Flags
) -> list[float]:
    """The ``rrt-paper`` reward of each step of a batch (gain and position do not matter)."""
    return [
        mode.reward(bool(c), bool(r), bool(i), 0.0, [0.0, 0.0])
        for c, r, i in zip(crashed, reached, improved, strict=True)
    ]


def test_progress_and_reward_sequence_along_a_guide() -> None:
    """R+ on each new ball, nothing when going back or staying, R++ at the end, R- first."""
    mode = PaperReward(RewardConfig())
    guide = Guide.from_path(np.array([[0.0, 0.0], [1.0, 0.0]]), r=0.125)
    assert guide.num_balls == 5
    tracker = ProgressTracker(guide, num_envs=1)
    tracker.reset(points=np.array([[0.0, 0.0]]))
    assert tracker.index.tolist() == [0]
    xs = [0.26, 0.3, 0.1, 0.5, 0.5, 0.74, 0.9, 1.0]
    expected_index = [1, 1, 1, 2, 2, 3, 4, 4]
    expected_reward = [5.0, 0.0, 0.0, 5.0, 0.0, 5.0, 200.0, 200.0]
    for x, idx, rew in zip(xs, expected_index, expected_reward, strict=True):
        step = tracker.update(np.array([[x, 0.0]]))
        at_goal = step.at_end
        reward = paper_rewards(mode, [False], at_goal, step.improved)
        assert step.index.tolist() == [idx]
        assert reward == [rew]
    # leaving the guide: D = inf, no progress; an obstacle beats everything
    step = tracker.update(np.array([[0.5, 1.0]]))
    assert not step.improved[0] and step.d[0] == np.inf and step.index[0] == 4
    assert paper_rewards(mode, [True], [True], [True])[0] == -100.0


def test_reward_priorities_and_constants() -> None:
    mode = PaperReward(RewardConfig())
    obstacle = np.array([True, True, False, False, False])
    goal = np.array([True, False, True, True, False])
    improved = np.array([True, True, True, False, False])
    r = paper_rewards(mode, obstacle, goal, improved)
    assert r == [-100.0, -100.0, 200.0, 200.0, 0.0]
    c = PaperReward(RewardConfig(crash=-200.0, goal=50.0, progress=1.0))
    r = paper_rewards(c, [False, True], [False, False], [True, True])
    assert r == [1.0, -200.0]
    for o, g, i in zip(obstacle, goal, improved, strict=True):
        assert (
            mode.reward(bool(o), bool(g), bool(i), 0.0, [0.0, 0.0])
            == paper_rewards(mode, [o], [g], [i])[0]
        )
    assert c.reward(False, False, True, 0.0, [0.0, 0.0]) == 1.0
