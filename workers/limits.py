"""Admission limits: how big a mission ltlnav agrees to plan and train.

A mission document can ask for anything its schema allows: a trillion training steps, a
planner running for days, a replay buffer of terabytes, a network of ten billion weights, a
checkpoint every step, a polygon of fifty thousand vertices. ``AdmissionLimits`` holds the
largest (or smallest) values one machine is sized for, and the checks here refuse the rest
with located problems ``(dotted path, message)`` that name the value, the limit and the
setting that raises it (``LTLNAV_`` + the field name in upper case, read by
``service.settings.Settings``; workers never read the environment).

The checks of a document are ``workers.admission``'s (``admit``: the CLI's and the API's one
entry point). The Büchi automaton's size is only known at planning time:
``workers.run.stored_or_new_plan`` translates within ``translation_budget`` and checks
``automaton_problems`` right after.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

Problem = tuple[str, str]


@dataclass(frozen=True)
class AdmissionLimits:
    """The limits a mission must keep; defaults sized for one 2-core machine."""

    max_world_vertices: int = 2_000
    """Polygon vertices of a world, all obstacles and regions together (the simplicity
    check, every collision test and every label test grow with them)."""

    max_obstacles: int = 500
    """Obstacles of a world: the listed ones plus ``random_obstacles.count``."""

    max_regions: int = 64
    """Labelled regions of a world."""

    max_formula_chars: int = 1_000
    """Characters of the task formula."""

    max_temporal_operators: int = 64
    """Temporal operators (U R W G F X) of the task formula."""

    max_automaton_states: int = 500
    """States of the task's Büchi automaton pruned for the world, checked when the mission
    is planned (TL-RRT* searches the product of the world and this automaton)."""

    max_subtasks: int = 200
    """Sub-tasks of a plan (legs of ``planner.leg_length`` included), one training job each;
    checked when the mission is planned."""

    max_timesteps: int = 2_000_000
    """``training.n_timesteps`` and ``training.handover_steps``: env steps per sub-task."""

    max_episodes: int = 1_000
    """``training.eval_episodes``, ``final_eval_episodes`` and ``mission_episodes``."""

    max_evaluations: int = 1_000
    """Periodic evaluations per training run: ``eval_freq`` at least
    ``n_timesteps / max_evaluations``."""

    max_checkpoints: int = 1_000
    """Checkpoints (model and replay buffer) per training run: ``checkpoint_freq`` at least
    ``n_timesteps / max_checkpoints``."""

    max_handover_rounds: int = 5
    """``training.handover_rounds``: rounds of hand-over repair."""

    max_cycles: int = 20
    """``training.cycles``: suffix cycles of a whole-mission rollout."""

    max_episode_steps: int = 10_000
    """``training.env.max_steps``: steps of one episode."""

    max_rays: int = 256
    """``training.env.rays``: lidar rays in the observation."""

    max_planner_seconds: float = 600.0
    """``planner.time_limit`` and ``planner.refine_seconds`` (CPU seconds)."""

    max_planner_iterations: int = 1_000_000
    """``planner.max_iterations`` and ``planner.refine_iterations``."""

    max_net_width: int = 1_024
    """Units of one layer of ``policy_kwargs.net_arch`` (list or ``{pi, qf, vf}`` form)."""

    max_net_depth: int = 8
    """Layers of one network of ``policy_kwargs.net_arch``."""

    max_critics: int = 10
    """``policy_kwargs.n_critics`` (SAC, TD3): critic networks."""

    max_batch_size: int = 4_096
    """``hyperparams.batch_size``: samples of one gradient step."""

    max_gradient_steps: int = 16
    """``hyperparams.gradient_steps`` (off-policy): gradient steps per rollout."""

    max_epochs: int = 50
    """``hyperparams.n_epochs`` (PPO): passes over each rollout."""

    @staticmethod
    def setting(name: str) -> str:
        """The environment variable of limit ``name`` (``LTLNAV_MAX_TIMESTEPS``)."""
        return f"LTLNAV_{name.upper()}"

    @classmethod
    def names(cls) -> list[str]:
        """Every limit's field name."""
        return [f.name for f in fields(cls)]


def number(value: float) -> str:
    """A value as a message shows it (an integer in full, a float short)."""
    if isinstance(value, float) and not value.is_integer():
        return f"{value:g}"
    return f"{int(value)}" if abs(value) < 1e16 else f"{value:g}"


def over(value: float, name: str, limits: AdmissionLimits) -> str | None:
    """``"<value> is over the limit <limit> (LTLNAV_...)"`` when ``value`` exceeds limit
    ``name``, else None."""
    limit = getattr(limits, name)
    if value <= limit:
        return None
    return f"{number(value)} is over the limit {number(limit)} ({limits.setting(name)})"


def count_over(count: int, noun: str, name: str, limits: AdmissionLimits) -> str | None:
    """``"has <count> <noun>, over the limit <limit> (LTLNAV_...)"``, or None."""
    limit = getattr(limits, name)
    if count <= limit:
        return None
    return f"has {count} {noun}, over the limit {limit} ({limits.setting(name)})"


TRANSLATION_FACTOR = 4
"""The translation of a task stops once its automaton, before reduction and pruning (which
only shrink it), has this many times ``max_automaton_states`` states: reduction shrinks some
formulas' automata threefold (``<>a && <>b && <>(a && <>b)``: 9 states to 3), and 1,500 states
translate in 10 s, where ``<>g1 && ... && <>g12`` (4,096) ran over two minutes and 660 MB
before it was stopped; with the budget it is refused in 0.1 s."""


def translation_budget(limits: AdmissionLimits) -> int:
    """States the translation of a task may build (``TRANSLATION_FACTOR`` times the limit)."""
    return TRANSLATION_FACTOR * limits.max_automaton_states


def translation_problems(limits: AdmissionLimits) -> list[Problem]:
    """Why a task whose translation outgrew ``translation_budget`` is refused."""
    name = "max_automaton_states"
    return [
        (
            "task",
            f"its Büchi automaton grows past {translation_budget(limits)} states while "
            f"translating ({TRANSLATION_FACTOR} times the limit {limits.max_automaton_states}, "
            f"{limits.setting(name)}): split the mission or simplify the formula",
        )
    ]


def automaton_problems(states: int, pruned: int, limits: AdmissionLimits) -> list[Problem]:
    """Why an automaton of ``states`` states (``pruned`` once pruned for the world) is too
    large to plan in; checked on the pruned one, which TL-RRT* searches."""
    name = "max_automaton_states"
    if pruned <= limits.max_automaton_states:
        return []
    return [
        (
            "task",
            f"its Büchi automaton has {pruned} states once pruned for the world ({states} "
            f"before), over the limit {limits.max_automaton_states} ({limits.setting(name)}): "
            "split the mission or simplify the formula",
        )
    ]


def subtask_problems(
    count: int, leg_length: float | None, limits: AdmissionLimits
) -> list[Problem]:
    """Why a plan of ``count`` sub-tasks (cut into legs of ``leg_length``) is too many to train."""
    message = count_over(count, "sub-tasks", "max_subtasks", limits)
    if message is None:
        return []
    if leg_length is not None:
        return [("planner.leg_length", f"its plan {message}: longer legs make fewer")]
    return [("task", f"its plan {message}: split the mission")]
