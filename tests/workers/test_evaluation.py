"""Sub-task evaluation and whole-mission rollouts judged by the Büchi automaton, driven by a
scripted guide follower (succeeds), a parked robot (times out) and a crasher (collides)."""

from __future__ import annotations

import pickle
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from envs.mission_env import MissionEnv
from envs.nav_env import NavEnv
from planner.decompose import lasso_stages
from planner.plan import MissionPlan, plan_mission
from workers.evaluation import (
    LaneShare,
    MissionEvaluation,
    evaluate_subtask,
    lane_seed,
    lane_shares,
    merge_evaluations,
    rollout_mission,
    seed_lanes,
    stage_policies,
)
from workers.mission import MissionSpec
from workers.run import MissionRun, Spread

from .missions import tiny_mission


def follower(env: Callable[[], NavEnv]) -> Callable[[np.ndarray], np.ndarray]:
    """A PD controller of the point robot toward the first r-ball 0.3 m or more ahead of its
    progress, then the centre of the goal region (the guide ends on its boundary)."""

    def act(_obs: np.ndarray) -> np.ndarray:
        sub = env()
        centers = sub.legs[0].guide.centers
        state = np.asarray(sub.robot.state)
        d = len(centers[0])
        ahead = np.linalg.norm(centers - state[:d], axis=1) >= 0.3
        ahead[: sub.progress_index + 1] = False
        k = int(np.argmax(ahead)) if ahead.any() else len(centers) - 1
        target = centers[k]
        if k >= len(centers) - 2:
            goal = sub.world.regions[sub.legs[0].subtask.goal]
            target = np.mean(goal.bounding_box(), axis=0)
        return np.clip(2.0 * (target - state[:d]) - 2.0 * state[d:], -1, 1).astype(np.float32)

    return act


def test_subtask_evaluation_counts_successes_collisions_and_timeouts(
    mission: MissionSpec, plan: MissionPlan
) -> None:
    from workers.training import subtask_env

    env = subtask_env(mission, plan, mission.training, 0, evaluation=True)
    good = evaluate_subtask(follower(lambda: env), env, episodes=3, seed=0)
    assert good.success_rate == 1.0 and good.collision_rate == 0.0
    assert good.mean_steps_to_goal is not None and 5 < good.mean_steps_to_goal < env.max_steps
    parked = evaluate_subtask(lambda o: np.zeros(2, dtype=np.float32), env, episodes=2, seed=0)
    assert (parked.success_rate, parked.timeout_rate, parked.mean_steps_to_goal) == (0, 1, None)
    # the robot starts 0.5 m from the left wall of the world: push straight into it
    crash = evaluate_subtask(lambda o: np.array([-1, 0], dtype=np.float32), env, episodes=2, seed=0)
    assert crash.collision_rate == 1.0 and crash.success_rate == 0.0
    assert crash.rejected_rate == 0.0
    env.close()


def test_lanes_step_in_lockstep_with_one_batched_call_and_seeds_of_their_own(
    mission: MissionSpec, plan: MissionPlan
) -> None:
    """Lanes: one policy call per step for every running lane, the episodes shared out among
    them, each lane seeded apart; one lane gives the one-env evaluation's figures."""
    from workers.training import subtask_env

    lanes = [subtask_env(mission, plan, mission.training, 0, evaluation=True) for _ in range(3)]
    batches: list[int] = []

    def crash(observations: np.ndarray) -> np.ndarray:
        batches.append(len(observations))
        return np.tile(np.array([-1, 0], dtype=np.float32), (len(observations), 1))

    result = evaluate_subtask(crash, lanes, episodes=7, seed=4)
    assert (result.episodes, result.collision_rate) == (7, 1.0)
    assert batches[0] == 3 and max(batches) == 3 and min(batches) >= 1
    firsts = seed_lanes(lanes, 4)
    assert not np.allclose(firsts[0], firsts[1]) and not np.allclose(firsts[1], firsts[2])
    assert np.allclose(firsts[1], lanes[1].reset(seed=lane_seed(4, 1))[0])

    one = lanes[0]
    drive = follower(lambda: one)
    alone = evaluate_subtask(drive, one, episodes=3, seed=1)
    batched = evaluate_subtask(lambda rows: drive(rows[0])[None], [one], episodes=3, seed=1)
    assert batched == alone and alone.success_rate == 1.0
    for env in lanes:
        env.close()


def test_an_evaluation_stops_once_its_target_is_out_of_reach_and_rates_what_it_ran(
    mission: MissionSpec, plan: MissionPlan
) -> None:
    from workers.training import subtask_env

    lanes = [subtask_env(mission, plan, mission.training, 0, evaluation=True) for _ in range(3)]

    def crash(observations: np.ndarray) -> np.ndarray:
        return np.tile(np.array([-1, 0], dtype=np.float32), (len(observations), 1))

    # 8 successes needed of 10: out of reach at the third failure
    hopeless = evaluate_subtask(crash, lanes, episodes=10, seed=4, needed=8)
    assert (hopeless.episodes, hopeless.collision_rate, hopeless.success_rate) == (3, 1.0, 0.0)
    assert evaluate_subtask(crash, lanes, episodes=10, seed=4).episodes == 10
    one = lanes[0]
    reached = evaluate_subtask(follower(lambda: one), one, episodes=3, seed=1, needed=3)
    assert (reached.episodes, reached.success_rate) == (3, 1.0)
    for env in lanes:
        env.close()


def test_mission_rollout_of_a_good_policy_is_accepted(
    mission: MissionSpec, plan: MissionPlan
) -> None:
    env = MissionEnv(
        mission, plan, mission.training.eval_env_options(mission.robot.model), cycles=2
    )
    assert env.sequence == lasso_stages(plan.subtasks, 2)
    assert len(env.sequence) == 2 + 2 * 2  # prefix a, b; suffix (a, b) twice
    act = follower(lambda: env.envs[env.sequence[env.stage]])
    result = rollout_mission(act, env, episodes=2, seed=0)
    assert result.success_rate == 1.0 and result.failures == {}
    assert result.mean_steps is not None and len(result.trails) == 2
    assert result.trails[0][0] != result.trails[1][0]  # evaluation start noise: two trials
    assert {"a", "b"} <= set().union(*env.trace)
    assert len(env.cycle_starts) == 2 and env.accepted()
    for k, poses in result.handovers.items():  # every stage begun, in both rollouts
        assert len(poses) == 2 * env.sequence.count(k)
    for (k, pose), prev in zip(env.handovers[1:], env.sequence, strict=False):
        goal = env.world.regions[plan.subtasks[prev].goal]  # handed over on entering it
        assert goal.contains(pose.position[None, :])[0], (k, pose)
    # the same positions without ever visiting b: the automaton rejects the trace
    env.trace = [lab for lab in env.trace if "b" not in lab]
    assert not env.accepted()
    env.close()


def test_mission_failures_are_located_by_subtask_and_kind(
    mission: MissionSpec, plan: MissionPlan
) -> None:
    env = MissionEnv(
        mission, plan, mission.training.eval_env_options(mission.robot.model), cycles=1
    )
    parked = rollout_mission(lambda o: np.zeros(2, dtype=np.float32), env, episodes=2)
    assert parked.timeout_rate == 1.0 and parked.failures == {"0": {"timeout": 2}}
    assert parked.to_json()["failures"] == {"0": {"timeout": 2}}
    assert "trails" not in parked.to_json()
    crash = rollout_mission(lambda o: np.array([-1, 0], dtype=np.float32), env, episodes=1)
    assert crash.collision_rate == 1.0 and crash.failures == {"0": {"collision": 1}}
    env.close()


def _until_b_forbidden() -> tuple[MissionSpec, MissionPlan]:
    """The tiny mission with ``b`` forbidden until ``a`` is reached, and its plan."""
    until = tiny_mission().model_copy(update={"task": "[]!obstacle && (!b U a) && <>b"})
    world = until.build_world()
    return until, plan_mission(world, until.task, until.robot.position(), until.robot.radius)


def test_a_sub_task_that_enters_a_forbidden_region_is_rejected_under_its_index() -> None:
    until, plan = _until_b_forbidden()
    env = MissionEnv(until, plan, until.training.eval_env_options(until.robot.model), cycles=1)
    toward_b = rollout_mission(lambda o: np.array([0, 1], dtype=np.float32), env, episodes=2)
    assert toward_b.rejected_rate == 1.0 and toward_b.collision_rate == 0.0
    assert toward_b.failures == {"0": {"rejected": 2}}
    env.close()


def test_a_sub_task_episode_that_enters_a_forbidden_region_is_rejected_not_a_collision() -> None:
    from workers.training import subtask_env

    until, plan = _until_b_forbidden()
    env = subtask_env(until, plan, until.training, 0, evaluation=True)
    toward_b = evaluate_subtask(lambda o: np.array([0, 1], dtype=np.float32), env, 2, seed=0)
    assert (toward_b.rejected_rate, toward_b.collision_rate, toward_b.success_rate) == (1, 0, 0)
    assert toward_b.to_json()["rejected_rate"] == 1.0
    env.close()


def test_stage_policies_pick_the_stage_sub_policy() -> None:
    calls: list[int] = []

    def policy(k: int) -> Callable[[np.ndarray], np.ndarray]:
        def act(obs: np.ndarray) -> np.ndarray:
            calls.append(k)
            assert obs.shape == (3,)
            return np.zeros(2)

        return act

    act = stage_policies([0, 1, 2, 3, 2, 3], [policy(k) for k in range(4)])
    for stage in range(6):
        act(np.array([0.0, 0.0, 0.0, float(stage)]))
    assert calls == [0, 1, 2, 3, 2, 3]


def test_stage_policies_call_each_sub_policy_once_on_its_rows_of_a_batch() -> None:
    calls: list[tuple[int, int]] = []

    def policy(k: int) -> Callable[[np.ndarray], np.ndarray]:
        def act(obs: np.ndarray) -> np.ndarray:
            calls.append((k, len(obs)))
            assert obs.shape[1:] == (3,)
            return np.full((len(obs), 2), float(k))

        return act

    act = stage_policies([0, 1, 0], [policy(k) for k in range(2)])
    batch = np.array([[0.0, 0, 0, s] for s in (0, 1, 2, 1, 5)])
    assert act(batch)[:, 0].tolist() == [0.0, 1.0, 0.0, 1.0, 0.0]  # stage 5: the last one
    assert sorted(calls) == [(0, 3), (1, 2)]


def test_mission_rollouts_in_lanes_count_every_episode_and_keep_every_hand_over(
    mission: MissionSpec, plan: MissionPlan
) -> None:
    options = mission.training.eval_env_options(mission.robot.model)
    lanes = [MissionEnv(mission, plan, options, cycles=1) for _ in range(3)]
    parked = stage_policies(lanes[0].sequence, [lambda o: np.zeros((len(o), 2))] * 2)
    result = rollout_mission(parked, lanes, episodes=5, seed=2, keep_trails=4)
    assert (result.episodes, result.timeout_rate) == (5, 1.0)
    assert result.failures == {"0": {"timeout": 5}} and len(result.trails) == 4
    assert len(result.handovers[0]) == 5  # sub-task 0 begun once per rollout
    starts = {tuple(trail[0]) for trail in result.trails}
    assert len(starts) == 4  # lanes seeded apart, episodes of a lane go on from its seed
    for env in lanes:
        env.close()


def test_evaluation_options_start_at_the_real_start_with_noise() -> None:
    spec = tiny_mission(env={"curriculum": 0.7, "stall_steps": 30}, eval_start_noise=0.1)
    options = spec.training.eval_env_options(spec.robot.model)
    assert (options.curriculum, options.stall_steps, options.start_noise) == (0.0, 0, 0.1)
    assert options.stall_spacings is None
    assert options.heading_noise == 0.4
    assert spec.training.env_options(spec.robot.model).curriculum == 0.7


def test_training_starts_are_spread_like_the_evaluation_s() -> None:
    for protocol in ("shaped", "paper"):
        training = tiny_mission(eval_start_noise=0.3, protocol=protocol).training
        for model in ("point", "racecar"):
            trained, evaluated = training.env_options(model), training.eval_env_options(model)
            assert (trained.start_noise, trained.heading_noise) == (0.3, 0.4)
            assert (evaluated.start_noise, evaluated.heading_noise) == (0.3, 0.4)
    exact = tiny_mission(env={"start_noise": 0.0}, eval_start_noise=0.3).training
    assert (
        exact.env_options("point").start_noise,
        exact.eval_env_options("point").start_noise,
    ) == (
        0.0,
        0.3,
    )


def test_every_mode_ends_a_stall_with_its_crash_reward_and_sees_rays() -> None:
    ours = tiny_mission().training
    trained, evaluated = ours.env_options("point"), ours.eval_env_options("point")
    assert (trained.stall_steps, trained.stall_penalty, trained.rays) == (30, -10.0, 16)
    assert trained.stall_spacings is None
    assert (evaluated.stall_steps, evaluated.stall_spacings, evaluated.rays) == (0, None, 16)
    harsher = tiny_mission(reward={"constants": {"crash": -5.0}}).training
    assert harsher.env_options("point").stall_penalty == -5.0
    crashes = {"rrt-paper": -100.0, "ned": -10.0, "tl": -10.0}
    for mode, crash in crashes.items():  # the shaped protocol: only the reward differs
        other = tiny_mission(reward={"mode": mode}).training.env_options("point")
        assert (other.stall_steps, other.stall_penalty, other.rays) == (30, crash, 16)
    chosen = tiny_mission(env={"stall_steps": 0, "rays": 0}).training.env_options("point")
    assert (chosen.stall_steps, chosen.stall_spacings, chosen.rays) == (0, None, 0)
    spacings = tiny_mission(env={"stall_spacings": 4.0}).training.env_options("point")
    assert (spacings.stall_steps, spacings.stall_spacings) == (0, 4.0)


def test_measured_training_defaults_apply_by_robot_and_yield_to_the_mission() -> None:
    training = tiny_mission().training.model_copy(update={"env": {}})  # every default
    car, point = training.env_options("unicycle"), training.env_options("point")
    assert (car.curriculum, car.min_forward) == (0.7, 0.2)
    assert (point.curriculum, point.min_forward) == (0.7, None)
    evaluated = training.eval_env_options("unicycle")
    assert (evaluated.curriculum, evaluated.min_forward) == (0.0, 0.2)  # same action meaning
    chosen = tiny_mission(env={"curriculum": 0.0, "min_forward": None}).training
    assert (
        chosen.env_options("unicycle").curriculum,
        chosen.env_options("unicycle").min_forward,
    ) == (0.0, None)
    quad = training.env_options("quadrotor")
    assert quad.guide_feedforward == 1.0
    assert point.guide_feedforward == 1.0 and car.guide_feedforward == 1.0
    racecar = training.eval_env_options("racecar")  # evaluated as trained: same meaning
    assert (racecar.drivable_guide, racecar.guide_feedforward) == (1.45, 1.0)
    assert (racecar.feedforward_law, racecar.progress_window) == ("pursuit", 2)
    assert training.eval_env_options("quadrotor").guide_feedforward == 1.0  # same meaning
    off = tiny_mission(env={"guide_feedforward": None}).training.env_options("quadrotor")
    assert off.guide_feedforward is None
    for mode in ("rrt-paper", "ned", "tl"):  # the baselines get the same env as ours
        baseline = tiny_mission(reward={"mode": mode}).training.model_copy(update={"env": {}})
        for model in ("point", "unicycle", "racecar", "quadrotor"):
            theirs, ours = baseline.env_options(model), training.env_options(model)
            reward_only = replace(ours, stall_penalty=theirs.stall_penalty, rewards=theirs.rewards)
            assert theirs == reward_only


def test_the_paper_protocol_is_the_published_env_for_every_mode() -> None:
    for mode in ("rrt", "rrt-paper", "ned", "tl"):
        training = tiny_mission(reward={"mode": mode}, protocol="paper").training
        training = training.model_copy(update={"env": {}})
        for model in ("point", "unicycle", "racecar", "quadrotor"):
            trained, evaluated = training.env_options(model), training.eval_env_options(model)
            for options in (trained, evaluated):
                assert (options.observation, options.rays, options.curriculum) == ("paper", 0, 0)
                assert (options.stall_steps, options.min_forward) == (0, None)
                assert options.stall_spacings is None
                assert (options.guide_feedforward, options.drivable_guide) == (None, None)
                assert options.goal_judge == "guide_end"
    chosen = tiny_mission(protocol="paper", env={"rays": 8}).training.env_options("point")
    assert (chosen.rays, chosen.observation) == (8, "paper")


def test_mission_rollouts_cut_into_lane_shares_are_the_whole_rollout(
    mission: MissionSpec, plan: MissionPlan
) -> None:
    """Shares of an evaluation's lanes run apart (in other processes) and merged give what the
    lanes give together: the same episodes, outcomes, starts and hand-overs."""
    options = mission.training.eval_env_options(mission.robot.model)

    def drift(obs: np.ndarray) -> np.ndarray:
        return np.tanh(3.0 * obs[:, :2]).astype(np.float32)

    def rollouts(share: LaneShare) -> MissionEvaluation:
        lanes = [MissionEnv(mission, plan, options, cycles=1) for _ in range(share.count)]
        act = stage_policies(lanes[0].sequence, [drift] * 2)
        try:
            return rollout_mission(act, lanes, episodes=7, seed=3, keep_trails=7, share=share)
        finally:
            for env in lanes:
                env.close()

    whole = rollouts(LaneShare(0, 3, 3))
    shares = lane_shares(3, 2)
    assert [(s.first, s.count, s.total) for s in shares] == [(0, 1, 3), (1, 2, 3)]
    assert [s.episodes(7) for s in shares] == [[2], [2, 3]]
    merged = merge_evaluations([rollouts(s) for s in shares], keep_trails=7)
    assert merged.to_json() == whole.to_json() and merged.episodes == 7

    def starts(evaluation: MissionEvaluation) -> list[tuple[float, ...]]:
        return sorted(tuple(trail[0]) for trail in evaluation.trails)

    def handed_over(evaluation: MissionEvaluation) -> dict[int, list[tuple[float, ...]]]:
        return {
            k: sorted(tuple(np.round(pose.position, 9)) for pose in poses)
            for k, poses in evaluation.handovers.items()
        }

    assert starts(merged) == starts(whole) and len(starts(whole)) == 7
    assert handed_over(merged) == handed_over(whole)
    assert lane_shares(3, 8) == [LaneShare(0, 1, 3), LaneShare(1, 1, 3), LaneShare(2, 1, 3)]


def test_a_run_sent_to_another_process_leaves_its_spread_behind(
    mission: MissionSpec, plan: MissionPlan, tmp_path: Path
) -> None:
    run = MissionRun(mission, plan, tmp_path)
    run.spread = Spread(map, 2)
    copy = pickle.loads(pickle.dumps(run))
    assert copy.spread is None and run.spread is not None
    assert copy.folder == run.folder and copy.mission == run.mission
