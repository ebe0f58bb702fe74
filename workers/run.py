"""One mission run: the mission validated once, its plan made or loaded once, and its jobs.

``MissionRun.open(document, folder)`` validates the document (or takes a validated
``MissionSpec``), refuses what cannot be served, and plans the mission into
``folder/plan.json`` or loads the plan stored there for the same mission. The run then offers
everything a driver needs: ``jobs()`` (one per sub-task), ``train(job, hooks)``,
``evaluate(results)`` (whole-mission rollouts), the hand-over repair rounds
(``repair_jobs``/``judge``, or ``repair`` to loop over them) and ``finish`` (the bundle). The
local pipeline (``workers.pipeline``, ``ltlnav train``) and the service's Celery steps
(``service.jobs``) are thin drivers of it.

Folder layout: ``plan.json``, ``subtask_<k>/`` (a job's folder, ``workers.training``),
``subtask_<k>/handover_<r>/`` (its repair in round ``r``), ``handover_repair.json`` and
``bundle.zip``.
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import torch

from envs.mission_env import MissionEnv
from planner.decompose import lasso_stages
from planner.errors import PlanningError
from planner.plan import MissionPlan, verify_plan
from planner.serialize import plan_from_dict, plan_to_dict
from workers.admission import admitted_plan, servable_problems
from workers.atomic import write_json
from workers.evaluation import (
    LaneShare,
    MissionEvaluation,
    lane_shares,
    merge_evaluations,
    rollout_mission,
    stage_policies,
)
from workers.handover_repair import (
    RepairRound,
    candidate_results,
    judged_round,
    probe_seed,
    repair_jobs,
)
from workers.hooks import TrainingHooks
from workers.jobs import SubtaskJob, job_seed
from workers.limits import AdmissionLimits
from workers.mission import MissionError, MissionSpec, parse_mission
from workers.policy_act import deterministic_act
from workers.train_result import TrainResult
from workers.training import ALGORITHMS, train_subtask
from workers.training_spec import TrainingSpec

PLAN_FILE = "plan.json"
"""The run's plan and the planning part of the mission it was made for."""

REPAIR_RECORD = "handover_repair.json"
"""What ``finish`` kept: the repair rounds, the sub-task results and the mission's evaluation
(the bundle holds them too)."""

EVALUATION_SEED = 7
"""Offset of the reported mission rollouts' seed from ``training.seed``: measured once, by
``finish``, after every decision."""

SELECTION_SEED = 500
"""Offset of the seed of the mission rollouts that decide (whether to repair, whether a repair
round is kept) from ``training.seed``: apart from the reported ones and the probes."""

RunJobs = Callable[[Sequence[SubtaskJob]], list[TrainResult]]
"""Train these jobs (in parallel where the driver can) and return their results in order."""


@dataclass(frozen=True)
class Spread:
    """Processes the whole-mission rollouts may run on: ``map(function, items)`` runs the
    function on each item in them (``Executor.map``), ``processes`` is how many there are."""

    map: Callable[[Callable[[LaneShare], MissionEvaluation], Sequence[LaneShare]], Iterable[Any]]
    processes: int


def rollout_share(
    run: MissionRun, models: Sequence[str], seed: int, share: LaneShare
) -> MissionEvaluation:
    """``share`` of the whole-mission rollouts of the policies in ``models`` seeded ``seed``
    (in a pool process: the run and the model paths travel, the models load there)."""
    training, mission = run.training, run.mission
    torch.set_num_threads(training.torch_threads)
    cls = ALGORITHMS[training.algorithm]
    loaded = [cls.load(path, device="cpu") for path in models]
    policies = [deterministic_act(m.policy) for m in loaded]
    options = training.eval_env_options(mission.robot.model)
    envs = [MissionEnv(mission, run.plan, options, training.cycles) for _ in range(share.count)]
    try:
        act = stage_policies(envs[0].sequence, policies)
        return rollout_mission(act, envs, training.mission_episodes, seed=seed, share=share)
    finally:
        for env in envs:
            env.close()


@dataclass
class RunResult:
    """What a finished run produced."""

    bundle: Path
    plan: MissionPlan
    results: list[TrainResult]
    evaluation: MissionEvaluation
    repairs: list[RepairRound] = field(default_factory=list)
    """The rounds of hand-over repair run (``workers.handover_repair``)."""


class MissionRun:
    """A mission, its plan and its folder (see the module docstring)."""

    def __init__(self, mission: MissionSpec, plan: MissionPlan, folder: Path) -> None:
        self.mission, self.plan, self.folder = mission, plan, folder
        self.spread: Spread | None = None
        """Where ``evaluate`` runs its rollouts (None: here); set by the driver that owns
        the processes, and never sent to them."""

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "spread": None}

    @classmethod
    def open(
        cls,
        mission: MissionSpec | Mapping[str, Any],
        folder: str | Path,
        limits: AdmissionLimits | None = None,
    ) -> MissionRun:
        """Validate ``mission`` (unless already a spec), refuse what cannot be served
        (``MissionError``), and plan it (``PlanningError`` when infeasible) or load its plan;
        ``limits`` (default ``AdmissionLimits()``) bounds the automaton it plans in."""
        spec = mission if isinstance(mission, MissionSpec) else parse_mission(dict(mission))
        problems = servable_problems(spec)
        if problems:
            raise MissionError(problems)
        out = Path(folder)
        return cls(spec, stored_or_new_plan(spec, out, limits), out)

    @property
    def training(self) -> TrainingSpec:
        """The mission's training section."""
        return self.mission.training

    def stages(self, cycles: int | None = None) -> list[int]:
        """Sub-task indices in lasso order: the prefix once, the suffix ``cycles`` times
        (default ``training.cycles``)."""
        return lasso_stages(self.plan.subtasks, self.training.cycles if cycles is None else cycles)

    def jobs(self) -> list[SubtaskJob]:
        """One training job per sub-task, seeded ``job_seed``."""
        training = self.training
        return [
            SubtaskJob(subtask=k, training=training, seed=job_seed(training, k))
            for k in range(len(self.plan.subtasks))
        ]

    def job_folder(self, job: SubtaskJob) -> Path:
        return job.folder(self.folder)

    def train(self, job: SubtaskJob, hooks: TrainingHooks | None = None) -> TrainResult:
        """Train (or resume, or return the stored result of) ``job`` in its folder."""
        return train_subtask(self.mission, self.plan, job, self.job_folder(job), hooks)

    def evaluate(
        self, results: Sequence[TrainResult], seed: int | None = None
    ) -> MissionEvaluation:
        """Whole-mission rollouts of the trained models of ``results`` (one per sub-task),
        seeded ``seed`` (default: the deciding rollouts', ``training.seed +
        SELECTION_SEED``)."""
        training = self.training
        at = training.seed + SELECTION_SEED if seed is None else seed
        lanes = min(training.eval_lanes, training.mission_episodes)
        rollout = partial(rollout_share, self, [r.model_path for r in results], at)
        if self.spread is None:
            return rollout(LaneShare(0, lanes, lanes))
        shares = lane_shares(lanes, self.spread.processes)
        return merge_evaluations(list(self.spread.map(rollout, shares)))

    def needs_repair(self, evaluation: MissionEvaluation, rounds_done: int) -> bool:
        """Whether another round of hand-over repair is due: the mission is below
        ``mission_target`` and fewer than ``handover_rounds`` rounds ran."""
        training = self.training
        below = evaluation.success_rate < training.mission_target
        return below and rounds_done < training.handover_rounds

    def repair_jobs(self, results: Sequence[TrainResult], round_: int) -> list[SubtaskJob]:
        """The jobs of repair round ``round_``: probe rollouts (seeded apart from the reported
        evaluation) find the sub-tasks that fail and the poses they are handed over in."""
        probe = self.evaluate(results, probe_seed(self.training, round_))
        return repair_jobs(self.training, results, probe, round_)

    def judge(
        self,
        round_: int,
        results: list[TrainResult],
        evaluation: MissionEvaluation,
        repaired: Sequence[TrainResult],
        seconds: float,
    ) -> tuple[list[TrainResult], MissionEvaluation, RepairRound]:
        """Evaluate the mission with the repaired results merged in; the results and
        evaluation to keep (the candidate's only if the mission improved) and the round's
        record. ``seconds``: the round's time so far (probe and training)."""
        t0 = time.monotonic()
        candidate = candidate_results(results, repaired)
        after = self.evaluate(candidate)
        record = judged_round(
            round_,
            repaired,
            evaluation.success_rate,
            after.success_rate,
            seconds + time.monotonic() - t0,
        )
        if record.kept:
            return candidate, after, record
        return results, evaluation, record

    def repair(
        self, results: list[TrainResult], evaluation: MissionEvaluation, run_jobs: RunJobs
    ) -> tuple[list[TrainResult], MissionEvaluation, list[RepairRound]]:
        """Rounds of hand-over repair while ``needs_repair`` (``workers.handover_repair``),
        their jobs trained by ``run_jobs``; the results and evaluation to keep and the
        rounds."""
        rounds: list[RepairRound] = []
        while self.needs_repair(evaluation, len(rounds)):
            t0 = time.monotonic()
            jobs = self.repair_jobs(results, len(rounds) + 1)
            if not jobs:
                break
            repaired = run_jobs(jobs)
            seconds = time.monotonic() - t0
            results, evaluation, record = self.judge(
                len(rounds) + 1, results, evaluation, repaired, seconds
            )
            rounds.append(record)
            if not record.kept:
                break
        return results, evaluation, rounds

    def finish(
        self,
        results: Sequence[TrainResult],
        evaluation: MissionEvaluation,
        repairs: Sequence[RepairRound] = (),
    ) -> RunResult:
        """Measure the reported whole-mission rollouts of what was kept (``EVALUATION_SEED``;
        ``evaluation`` is the deciding one) and write ``handover_repair.json`` and
        ``bundle.zip`` with them."""
        from workers.bundle import write_bundle

        selection = evaluation
        evaluation = self.evaluate(results, self.training.seed + EVALUATION_SEED)
        record = {
            "rounds": [r.to_json() for r in repairs],
            "results": [r.to_json() for r in results],
            "mission_evaluation": evaluation.to_json(),
            "selection_evaluation": selection.to_json(),
        }
        write_json(self.folder / REPAIR_RECORD, record, durable=True)
        seeds = [r.seed for r in results]
        bundle = write_bundle(
            self.folder / "bundle.zip", self.mission, self.plan, results, evaluation, seeds
        )
        return RunResult(
            bundle=bundle,
            plan=self.plan,
            results=list(results),
            evaluation=evaluation,
            repairs=list(repairs),
        )


def stored_or_new_plan(
    mission: MissionSpec, folder: Path, limits: AdmissionLimits | None = None
) -> MissionPlan:
    """The mission's plan: read from ``folder/plan.json`` when made for the same mission
    (training options aside), else planned, verified and stored there. A new plan is refused
    (``MissionError`` on ``task``) when the formula's automaton, pruned for the world, has more
    states than ``limits.max_automaton_states`` (default ``AdmissionLimits()``), or its
    translation outgrows ``translation_budget``, and when it has more sub-tasks than
    ``limits.max_subtasks`` (on ``planner.leg_length`` when legs made them)."""
    stored = folder / PLAN_FILE
    options = mission.planner_options()
    planning = mission.model_dump(mode="json", exclude={"training"})
    planning["planner"] = options.model_dump(mode="json")
    saved = _read_plan_file(stored)
    if saved is not None and saved.get("mission") == planning:
        try:
            return plan_from_dict(saved["plan"])
        except (KeyError, TypeError, ValueError) as error:
            warnings.warn(f"planning anew: {stored} holds no usable plan ({error!r})", stacklevel=2)
    world = mission.build_world()
    radius = mission.robot.radius
    plan = admitted_plan(mission, world, limits or AdmissionLimits(), options)
    problems = verify_plan(plan, world, radius)
    if problems:
        raise PlanningError("the plan failed its own check: " + "; ".join(problems))
    write_json(stored, {"mission": planning, "plan": plan_to_dict(plan)}, durable=True, indent=None)
    return plan


def _read_plan_file(path: Path) -> dict[str, Any] | None:
    """``plan.json``'s document (None: no file, or one cut short or damaged, which is planned
    anew: the plan of a mission and seed is the same every time)."""
    if not path.is_file():
        return None
    try:
        saved = json.loads(path.read_text())
    except ValueError as error:
        warnings.warn(f"planning anew: {path} is not valid JSON ({error})", stacklevel=2)
        return None
    return saved if isinstance(saved, dict) else None
