"""Train one sub-task's agent: ``train_subtask(mission, plan, job, out_dir, hooks)``.

A plain function that both drivers of a mission run (``workers.run.MissionRun``: the local
pipeline and the service's Celery tasks) and the tests call the same way. It is idempotent:
``out_dir`` holds checkpoints (model and replay buffer), ``evaluations.npz``, the logs (CSV and
TensorBoard) and ``result.json``; a restarted job resumes from the newest checkpoint
(``num_timesteps`` restored, no step redone beyond the checkpoint) and a finished one returns
its stored result. What the driver hears and is asked goes through ``workers.hooks``.

Layout of ``out_dir``: ``checkpoints/model_<steps>_steps.zip`` (+ ``model_replay_buffer_...``),
``evaluations.npz``, ``logs/run_<steps>/`` (one folder per (re)start), ``model.zip`` (the final
policy) and ``result.json``.
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import configure
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from envs.factory import make_env
from envs.nav_env import NavEnv
from planner.geometry.pose import Pose
from planner.plan import MissionPlan
from workers.actor_average import AveragedActor
from workers.agents import (
    ALGORITHMS,
    TrainingError,
    algorithm_class,
    keep_best_policy,
    load_agent,
)
from workers.atomic import save_with, write_json
from workers.callbacks import (
    ActorBurnIn,
    PruneCheckpoints,
    ReportedCheckpoints,
    ReportProgress,
    ResumableEvalCallback,
    StopOnPlateau,
    StopOnRequest,
    StopOnSuccessRate,
    plateaued,
)
from workers.candidates import CandidateStore
from workers.checkpoints import prune_checkpoints, save_checkpoint
from workers.evaluation import (
    Act,
    SubtaskEvaluation,
    evaluate_subtask,
    seed_lanes,
    successes_needed,
)
from workers.hooks import CurvePoint, TrainingHooks
from workers.jobs import SubtaskJob
from workers.mission import MissionSpec
from workers.policy_act import deterministic_act
from workers.policy_pick import Trial, pick_policy
from workers.residual import StartCheck, recorded_start, start_check
from workers.stopwatch import Stopwatch
from workers.train_result import Confirmation, Stopped, TrainResult, stored_confirmation
from workers.training_spec import TrainingSpec

__all__ = ["ALGORITHMS", "TrainResult", "TrainingError", "subtask_env", "train_subtask"]


RESULT = "result.json"
"""A finished job's ``TrainResult`` in its folder."""

CONFIRMATIONS = "confirmations.json"
"""Every confirmation of the early stop so far, ``[[steps, success rate, episodes], ...]``: a
resumed job goes on with the next confirmation seed."""

PERIODIC_SEED, REPORT_SEED, CONFIRMATION_SEED, SELECTION_SEED = 1, 2, 3, 500
"""Offsets from a job's seed of its evaluations' seeds. The periodic evaluations (and the start
check's quick one), the confirmations (confirmation ``n`` at ``CONFIRMATION_SEED + n``) and the
pick's (``pick_candidates``, at ``SELECTION_SEED``, below hand-over repair's probe seeds)
decide: the early stop and the kept policy. The final evaluation at ``REPORT_SEED`` is run
once, after every decision, and decides nothing: it is the one reported."""


def subtask_env(
    mission: MissionSpec,
    plan: MissionPlan,
    training: TrainingSpec,
    subtask: int,
    evaluation: bool = False,
    starts: Sequence[Pose] | None = None,
) -> NavEnv:
    """The env of ``subtask`` as trained (or, with ``evaluation``, as evaluated: see
    ``TrainingSpec.eval_env_options``), from ``starts`` in place of the real starts when given;
    ``g-rrt`` drives the whole lasso whatever ``subtask``."""
    mode = training.reward.mode
    model = mission.robot.model
    options = training.eval_env_options(model) if evaluation else training.env_options(model)
    target = None if mode == "g-rrt" else plan.subtasks[subtask]
    world = mission.build_world()
    poses = None if starts is None else list(starts)
    return make_env(mission, target, mode, world=world, plan=plan, options=options, starts=poses)


def train_subtask(
    mission: MissionSpec,
    plan: MissionPlan,
    job: SubtaskJob,
    out_dir: str | Path,
    hooks: TrainingHooks | None = None,
) -> TrainResult:
    """Train (or resume training) the agent of ``job`` into ``out_dir``.

    Stops early when a periodic evaluation reaches ``target_success`` and the final evaluation
    (``final_eval_episodes``), run then, confirms it, or after ``plateau_evals`` evaluations
    without a new best (when set); else training goes on to the budget. A
    ``hooks.should_stop()`` ends the job after a checkpoint (``stopped="cancelled"``).
    Deterministic for ``job.seed`` on one machine.
    """
    t0 = time.monotonic()
    out = Path(out_dir)
    done = stored_result(out)
    if done is not None and _finished(done, job.training):
        return done
    if not 0 <= job.subtask < len(plan.subtasks):
        raise TrainingError(
            f"sub-task {job.subtask} does not exist: the plan has {len(plan.subtasks)}"
        )
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(job.training.torch_threads)
    run = _SubtaskTraining(mission, plan, job, out, hooks or TrainingHooks())
    try:
        result = run.run()
    finally:
        run.close()
    result.seconds = time.monotonic() - t0
    result.parts = run.stopwatch.split(result.seconds)
    if result.stopped != "cancelled":
        write_json(out / RESULT, result.to_json(), durable=True)
    return result


def stored_result(folder: Path) -> TrainResult | None:
    """The result a finished job left in ``folder`` (None: none, or one that cannot be read,
    which the job then makes again)."""
    path = folder / RESULT
    if not path.is_file():
        return None
    try:
        return TrainResult.from_json(json.loads(path.read_text()))
    except (ValueError, TypeError, KeyError) as error:
        warnings.warn(f"ignoring unreadable {path}: {error}", stacklevel=2)
        return None


def _finished(result: TrainResult, training: TrainingSpec) -> bool:
    """Whether a stored result answers ``training``: its budget was spent, it stopped at the
    target and the confirmation that stopped it reaches it, or it stopped on a plateau that
    ``plateau_evals`` still calls one (a result below a raised target, short of a raised budget
    or of a raised patience trains on; the reported evaluation decides nothing)."""
    if result.steps >= training.n_timesteps:
        return True
    if result.stopped == "plateau":
        return plateaued(
            result.curve, training.plateau_evals, training.plateau_from, training.eval_episodes
        )
    passed = result.confirmations[-1][1] if result.confirmations else None
    return result.stopped == "target" and (passed is None or passed >= training.target_success)


def _stored_confirmations(folder: Path) -> list[Confirmation]:
    """The confirmations an earlier attempt recorded in ``folder`` (none if unreadable)."""
    path = folder / CONFIRMATIONS
    try:
        return [stored_confirmation(c) for c in json.loads(path.read_text())]
    except (OSError, ValueError, TypeError, IndexError):
        return []


class _SubtaskTraining:
    """One call of ``train_subtask``: the envs and the agent, the start check, ``learn`` with
    its callbacks, and the result."""

    def __init__(
        self,
        mission: MissionSpec,
        plan: MissionPlan,
        job: SubtaskJob,
        out: Path,
        hooks: TrainingHooks,
    ) -> None:
        self.job, self.out, self.hooks = job, out, hooks
        training, k, starts = job.training, job.subtask, job.starts

        def env(evaluation: bool) -> NavEnv:
            return subtask_env(mission, plan, training, k, evaluation, starts)

        self.env = DummyVecEnv([lambda: Monitor(env(False))] * training.n_envs)
        self.env.seed(job.seed)
        self.eval_env = DummyVecEnv([lambda: Monitor(env(True))] * training.eval_lanes)
        seed_lanes(self.eval_env.envs, job.seed + PERIODIC_SEED)
        self.folder = out / "checkpoints"
        self.residual = training.env_options(mission.robot.model).guide_feedforward is not None
        self.model, self.resumed = load_agent(
            training, self.env, self.folder, job.seed, job.warm_start, self.residual
        )
        self.model.set_logger(
            configure(str(out / "logs" / f"run_{self.resumed}"), ["csv", "tensorboard"])
        )
        hooks.resumed(self.resumed)
        self.confirmations = [c for c in _stored_confirmations(out) if c[0] <= self.resumed]
        self.act = deterministic_act(self.model.policy)
        """The policy's deterministic actions for a batch of observations."""
        self.stopwatch = Stopwatch()

    def final_evaluation(self) -> SubtaskEvaluation:
        """The reported evaluation (``final_eval_episodes`` from the real starts)."""
        episodes = self.job.training.final_eval_episodes
        self.hooks.evaluating(f"final evaluation: {episodes} trials")
        with self.stopwatch.part("final evaluation"):
            return self.evaluation(episodes, self.job.seed + REPORT_SEED)

    def confirmation(self) -> SubtaskEvaluation:
        """The next confirmation of the early stop (``final_eval_episodes``, a seed of its
        own each, stopped once the target is out of reach), recorded in ``confirmations``."""
        seed = self.job.seed + CONFIRMATION_SEED + len(self.confirmations)
        episodes = self.job.training.final_eval_episodes
        needed = successes_needed(episodes, self.job.training.target_success)
        with self.stopwatch.part("confirmations"):
            check = self.evaluation(episodes, seed, needed)
        steps = int(self.model.num_timesteps)
        self.confirmations.append((steps, check.success_rate, check.episodes))
        if self.hooks.may_write():
            write_json(self.out / CONFIRMATIONS, [list(c) for c in self.confirmations])
        return check

    def quick_evaluation(self) -> SubtaskEvaluation:
        """An evaluation of a periodic evaluation's size (the start check's)."""
        episodes = self.job.training.eval_episodes
        with self.stopwatch.part("start check"):
            return self.evaluation(episodes, self.job.seed + PERIODIC_SEED)

    def evaluation(
        self, episodes: int, seed: int, needed: int = 0, act: Act | None = None
    ) -> SubtaskEvaluation:
        """``evaluate_subtask`` of ``act`` (None: the current policy's) in the job's lanes."""
        return evaluate_subtask(act or self.act, self.eval_env.envs, episodes, seed, needed)

    def candidates(self) -> CandidateStore | None:
        """The store of the best evaluations' policies for the pick (None: no pick)."""
        keep = self.job.training.pick_candidates
        return None if keep is None else CandidateStore(self.out / "candidates", keep)

    def start_check(self) -> StartCheck | None:
        """A fresh residual agent is its feed-forward: measure it before any update (None: not
        such an agent); the measurement is the curve's step-0 point."""
        if not self.residual or self.resumed != 0 or self.job.warm_start is not None:
            return None
        target = self.job.training.target_success
        check = start_check(self.quick_evaluation, self.confirmation, target, self.out)
        episodes = self.job.training.eval_episodes
        self.hooks.curve_point(CurvePoint(0, episodes, check.success_rate))
        return check

    def run(self) -> TrainResult:
        training, hooks, model = self.job.training, self.hooks, self.model
        start = self.start_check()
        begun = recorded_start(self.out)
        stopper = StopOnSuccessRate(training.target_success, self.confirmation)
        averaged = (
            None
            if training.actor_average_steps is None
            else AveragedActor(training.actor_average_steps)
        )
        evaluation = ResumableEvalCallback(
            self.eval_env,
            n_eval_episodes=training.eval_episodes,
            eval_freq=training.eval_freq // training.n_envs,  # in steps of all the envs
            log_path=str(self.out),
            best_model_save_path=None,
            deterministic=True,
            warn=False,
            verbose=0,
            callback_after_eval=stopper,
            best_path=None if training.pick_candidates else self.out / "best_model.zip",
            start_rate=None if begun is None else begun.success_rate,
            hooks=hooks,
            averaged=averaged,
            stopwatch=self.stopwatch,
            candidates=self.candidates(),
        )
        evaluation.restore(self.resumed)
        if start is not None:
            evaluation.offer(model, 0, start.success_rate)
        every = (training.checkpoint_freq or training.eval_freq) // training.n_envs
        cancel = StopOnRequest(hooks.should_stop)
        checkpointer = ReportedCheckpoints(every, self.folder, hooks, self.stopwatch)
        patience, floor = training.plateau_evals, training.plateau_from
        plateau = StopOnPlateau(evaluation, patience, floor, training.eval_episodes)
        callbacks: list[BaseCallback] = [
            evaluation,
            plateau,
            checkpointer,
            PruneCheckpoints(self.folder, every),
            cancel,
            ReportProgress(hooks.progress, training.n_timesteps, evaluation),
        ]
        if training.actor_burn_in > self.resumed:
            callbacks.append(ActorBurnIn(training.actor_burn_in))
        if averaged is not None:
            callbacks.append(averaged)
        hooks.progress(self.resumed, evaluation.last_success_rate, training.n_timesteps)
        met_at_start = start is not None and start.confirmed is not None
        flat = plateaued(evaluation.success_curve, patience, floor, training.eval_episodes)
        cancelled = hooks.should_stop()
        remaining = training.n_timesteps - self.resumed
        if remaining > 0 and not cancelled and not met_at_start and not flat:
            model.learn(remaining, callback=CallbackList(callbacks), reset_num_timesteps=False)
            cancelled = cancel.stopped or checkpointer.fenced or evaluation.fenced
        steps = int(model.num_timesteps)
        owned = hooks.may_write()
        if owned:
            with self.stopwatch.part("checkpoints"):
                hooks.checkpoint(steps, save_checkpoint(model, self.folder, steps))
            prune_checkpoints(self.folder)
        cancelled = cancelled or not owned
        if averaged is not None and not cancelled:
            averaged.commit()
        stopped: Stopped = "budget"
        if cancelled:
            stopped = "cancelled"
        elif stopper.reached or met_at_start:
            stopped = "target"
        elif (flat or plateau.plateaued) and steps < training.n_timesteps:
            stopped = "plateau"
        result = TrainResult(
            subtask=self.job.subtask,
            seed=self.job.seed,
            model_path=str(self.folder / f"model_{steps}_steps.zip"),
            steps=steps,
            resumed_from=self.resumed,
            stopped=stopped,
            curve=evaluation.success_curve,
            confirmations=list(self.confirmations),
        )
        if stopped in ("budget", "plateau"):
            model, result.policy_steps, result.selection = self.kept_policy(evaluation)
            self.model, self.act = model, deterministic_act(model.policy)
        if stopped != "cancelled" and not hooks.may_write():
            result.stopped = stopped = "cancelled"
        if stopped != "cancelled":
            final = self.out / "model.zip"
            save_with(final, model.save)
            result.final = self.final_evaluation().to_json()
            result.model_path = str(final)
        hooks.progress(steps, evaluation.last_success_rate, training.n_timesteps)
        return result

    def kept_policy(
        self, evaluation: ResumableEvalCallback
    ) -> tuple[BaseAlgorithm, int | None, list[Trial]]:
        """The policy to keep after the budget or a plateau, its steps (None: the last) and
        the pick's trials: ``workers.policy_pick`` with ``pick_candidates``, else the best
        periodic evaluation's when it beat the last."""
        training, model = self.job.training, self.model
        if evaluation.candidates is None:
            return (*keep_best_policy(model, evaluation, training, self.env), [])
        episodes, seed = training.final_eval_episodes, self.job.seed + SELECTION_SEED

        def load(path: Path) -> BaseAlgorithm:
            return algorithm_class(training).load(path, env=self.env, device="cpu")

        def evaluate(policy: BaseAlgorithm, needed: int) -> SubtaskEvaluation:
            return self.evaluation(episodes, seed, needed, deterministic_act(policy.policy))

        with self.stopwatch.part("pick"):
            last = int(model.num_timesteps)
            ranked = evaluation.candidates.ranked()
            return pick_policy(model, last, ranked, load, evaluate, self.announce_pick)

    def announce_pick(self, number: int, of: int) -> None:
        self.hooks.evaluating(f"picking the kept policy: {number} of {of}")

    def close(self) -> None:
        self.env.close()
        self.eval_env.close()
