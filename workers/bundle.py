"""Write a mission's bundle: ``bundle.zip`` with everything needed to run it offline.

Members: ``manifest.json`` (schema ``workers.manifest.Manifest``: format and version, mission,
seeds, package versions, the automaton and the pruned one in HOA, the exact plan (its lasso
included), the ordered sub-tasks with their guides (a car's drawn paths too), model file names,
learning curves and evaluations, the mission evaluation), ``models/subtask_<k>.zip``
(stable-baselines3 archives), ``README.md`` (model card), ``plan.png``,
``learning_curves.png`` and ``rollout.png``. Read one back with ``ConcatenatedPolicy.load``
(re-exported here)."""

from __future__ import annotations

import datetime as dt
import importlib.metadata
import json
import tempfile
import zipfile
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from envs.factory import drawn_subtasks
from envs.options import EnvOptions
from envs.rays import ray_reach
from envs.robots import robot_params
from planner.decompose import SubTask
from planner.geometry.world import World
from planner.guidance import Guide
from planner.plan import MissionPlan
from planner.plot import plot_plan, shape_patch
from planner.serialize import plan_to_dict
from workers.bundle_reader import ConcatenatedPolicy, read_bundle
from workers.evaluation import MissionEvaluation
from workers.manifest import (
    FORMAT,
    FORMAT_VERSION,
    MANIFEST,
    BundleError,
    DrawnGuide,
    Manifest,
    SubtaskEntry,
)
from workers.mission import MissionSpec
from workers.policy_pick import kept_policy_text
from workers.train_result import TrainResult

__all__ = ["BundleError", "ConcatenatedPolicy", "read_bundle", "write_bundle"]

PACKAGES = ("ltlnav", "stable-baselines3", "torch", "gymnasium", "numpy", "pybullet")


def package_versions() -> dict[str, str]:
    """Installed versions of the packages a bundle depends on."""
    out: dict[str, str] = {}
    for name in PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def manifest_for(
    mission: MissionSpec,
    plan: MissionPlan,
    results: Sequence[TrainResult],
    evaluation: MissionEvaluation | None,
    seeds: Sequence[int],
    files: Sequence[str],
    guides: Sequence[Guide],
    drawn: Sequence[SubTask] | None = None,
) -> Manifest:
    """The manifest of a bundle of ``results`` (one per sub-task, in order, trained on
    ``guides``, a car's along the ``drawn`` paths)."""
    training = mission.training
    kwargs = training.policy_kwargs()
    if training.hyperparams.get("use_sde"):
        kwargs["use_sde"] = True
    records: Sequence[DrawnGuide | None] = (
        [drawn_guide(sub) for sub in drawn] if drawn is not None else [None] * len(plan.subtasks)
    )
    entries = [
        SubtaskEntry(
            index=sub.index,
            phase=sub.phase,
            goal=sub.goal,
            start=sub.start.tolist(),
            path=sub.path.tolist(),
            r_ball=guide.r,
            guide_centers=guide.centers.tolist(),
            drawn=record,
            model=f"models/subtask_{sub.index}.zip",
            algorithm=training.algorithm,
            policy_kwargs=kwargs,
            seed=seed,
            steps=result.steps,
            policy_steps=result.policy_steps,
            selection=result.selection,
            stopped=result.stopped,
            repairs=result.repairs,
            curve=result.curve,
            evaluation=result.final,
        )
        for sub, guide, result, seed, record in zip(
            plan.subtasks, guides, results, seeds, records, strict=True
        )
    ]
    return Manifest(
        format=FORMAT,
        format_version=FORMAT_VERSION,
        created=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        mission=mission.model_dump(mode="json"),
        seeds={"planner": mission.planner.seed, "training": training.seed, "subtasks": list(seeds)},
        packages=package_versions(),
        automaton_hoa=plan.nba.to_hoa(name=plan.formula),
        pruned_automaton_hoa=plan.pruned.to_hoa(name=plan.formula),
        plan=plan_to_dict(plan),
        subtasks=entries,
        cycles=training.cycles,
        mission_evaluation=evaluation.to_json() if evaluation is not None else None,
        eval_env=recorded_eval_env(mission),
        files=list(files),
    )


def drawn_guide(sub: SubTask) -> DrawnGuide:
    """A redrawn sub-task's record in the manifest."""
    return DrawnGuide(start=sub.start.tolist(), path=sub.path.tolist(), reverse=sub.reverse)


def eval_env_document(options: EnvOptions) -> dict[str, Any]:
    """``options`` as the manifest's ``eval_env`` (every field but ``rewards``)."""
    return {f.name: getattr(options, f.name) for f in fields(options) if f.name != "rewards"}


def recorded_eval_env(mission: MissionSpec) -> dict[str, Any]:
    """The manifest's ``eval_env`` for ``mission``: its evaluation options with the rays' range
    resolved, so that a later default cannot change what the bundle's policies observe."""
    options = mission.training.eval_env_options(mission.robot.model)
    document = eval_env_document(options)
    if options.rays:
        spec = mission.robot
        document["ray_range"] = ray_reach(options, robot_params(spec.model, spec.params))
    return document


def write_bundle(
    out: str | Path,
    mission: MissionSpec,
    plan: MissionPlan,
    results: Sequence[TrainResult],
    evaluation: MissionEvaluation | None,
    seeds: Sequence[int],
) -> Path:
    """Write ``bundle.zip`` at ``out`` from the trained ``results`` (one per sub-task of
    ``plan``, ``model_path`` pointing at each final model)."""
    if len(results) != len(plan.subtasks):
        raise BundleError(f"{len(results)} trained models for {len(plan.subtasks)} sub-tasks")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    world = mission.build_world()
    guides = mission.trained_guides(plan)
    options = mission.training.eval_env_options(mission.robot.model)
    drawn = drawn_subtasks(mission, plan, options, world)
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        pictures = {
            "plan.png": lambda p: plot_plan(world, plan, p, title=mission.name, guides=guides),
            "learning_curves.png": lambda p: plot_curves(results, p),
            "rollout.png": lambda p: plot_rollouts(world, plan, evaluation, p),
        }
        for name, draw in pictures.items():
            draw(Path(tmp) / name)
        files = [*pictures, "README.md"]
        manifest = manifest_for(mission, plan, results, evaluation, seeds, files, guides, drawn)
        partial = out.with_name(out.name + ".partial")
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(MANIFEST, manifest.model_dump_json(indent=1, exclude={"lasso"}))
            archive.writestr("README.md", model_card(manifest))
            for name in pictures:
                archive.write(Path(tmp) / name, name)
            for entry, result in zip(manifest.subtasks, results, strict=True):
                archive.write(result.model_path, entry.model)
        partial.replace(out)
    return out


def model_card(manifest: Manifest) -> str:
    """The bundle's README: what it does, how it was trained, how well it works."""
    mission = manifest.mission
    training = mission.get("training", {})
    lines = [
        f"# {mission['name']}: trained concatenated policy",
        "",
        f"Task (LTL): `{mission['task']}`  ",
        f"Robot: {mission['robot']['model']}, start {mission['robot']['start']}  ",
        f"Algorithm: {training.get('algorithm')}, reward mode "
        f"{training.get('reward', {}).get('mode')}, budget {training.get('n_timesteps')} steps "
        "per sub-task  ",
        f"Seeds: {json.dumps(manifest.seeds)}  ",
        f"Packages: {', '.join(f'{k} {v}' for k, v in manifest.packages.items())}",
        "",
        "The policy runs the prefix sub-policies once, then the suffix sub-policies in a cycle:",
        "each sub-policy drives until its goal region is reached. Load it with",
        "`workers.bundle.ConcatenatedPolicy.load('bundle.zip')`; each `models/*.zip` is a plain",
        "stable-baselines3 archive.",
        "",
        "| sub-task | phase | goal | steps | stopped | success | collisions | rejected "
        "| mean steps |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for s in manifest.subtasks:
        ev: dict[str, Any] = s.evaluation or {}
        lines.append(
            f"| {s.index} | {s.phase} | {s.goal or '(end of guide)'} | {_steps(s)} | {s.stopped} | "
            f"{_pct(ev.get('success_rate'))} | {_pct(ev.get('collision_rate'))} | "
            f"{_pct(ev.get('rejected_rate'))} | {ev.get('mean_steps_to_goal') or '-'} |"
        )
    whole = manifest.mission_evaluation
    lines.append("")
    if whole is not None:
        lines.append(
            f"Whole mission ({whole['episodes']} rollouts, {whole['cycles']} suffix cycles, "
            f"judged by the Büchi automaton): success {_pct(whole['success_rate'])}, collisions "
            f"{_pct(whole['collision_rate'])}, timeouts {_pct(whole['timeout_rate'])}, rejected "
            f"{_pct(whole['rejected_rate'])}; failures "
            f"by sub-task: {json.dumps(whole['failures'])}."
        )
    else:
        lines.append("The whole mission was not evaluated.")
    return "\n".join(lines) + "\n"


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def _steps(entry: SubtaskEntry) -> str:
    shown = str(entry.steps)
    if entry.policy_steps is not None:
        shown += f" ({kept_policy_text(entry.policy_steps, entry.selection)})"
    if entry.repairs:
        shown += (
            f" (incl. {entry.repairs} hand-over repair round(s): success measured from the "
            "poses the mission rollouts handed it over in)"
        )
    return shown


def plot_curves(results: Sequence[TrainResult], out: Path) -> None:
    """Success rate of the periodic evaluations against env steps, one line per sub-task."""
    figure, axes = plt.subplots(figsize=(7, 4))
    for r in results:
        if r.curve:
            steps, rates = zip(*r.curve, strict=True)
            axes.plot(steps, rates, marker=".", label=f"sub-task {r.subtask}")
    axes.set_xlabel("env steps")
    axes.set_ylabel("success rate")
    axes.set_ylim(-0.05, 1.05)
    axes.grid(alpha=0.3)
    if any(r.curve for r in results):
        axes.legend(fontsize=8)
    figure.savefig(out, dpi=100, bbox_inches="tight")
    plt.close(figure)


def plot_rollouts(
    world: World, plan: MissionPlan, evaluation: MissionEvaluation | None, out: Path
) -> None:
    """The world (2D: obstacles and regions) with the lasso and the recorded rollout trails."""
    three = world.dim == 3
    figure = plt.figure(figsize=(7, 7))
    axes: Any = figure.add_subplot(projection="3d" if three else None)
    if not three:
        axes.set_aspect("equal")
        for shape in world.obstacles:
            axes.add_patch(shape_patch(shape, "#555555", 0.7))
        for name, shape in world.regions.items():
            axes.add_patch(shape_patch(shape, "#7fbf7f", 0.7))
            axes.annotate(name, tuple(shape.bounding_box()[0][:2]), fontsize=8)
    axes.set_xlim(*world.bounds[0])
    axes.set_ylim(*world.bounds[1])
    lasso = [plan.lasso.prefix, plan.lasso.suffix]
    for path, style in zip(lasso, ("k:", "k--"), strict=True):
        axes.plot(*(path[:, j] for j in range(world.dim)), style, lw=1)
    for trail in evaluation.trails if evaluation is not None else []:
        if trail:
            points = list(zip(*trail, strict=True))
            axes.plot(*points, lw=1.2, alpha=0.8)
    if evaluation is not None:
        axes.set_title(f"mission success {100 * evaluation.success_rate:.0f} %")
    figure.savefig(out, dpi=100, bbox_inches="tight")
    plt.close(figure)
