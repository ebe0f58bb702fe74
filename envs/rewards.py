"""Reward modes of the navigation env (the judges they rely on are ``envs.judge``).

Every mode shares the paper's priorities (Cai et al., RA-L 2023): a crash (the robot's disc or
sphere meets an obstacle or leaves the bounds) earns ``R-`` and ends the episode; reaching the
goal earns ``R++`` and ends it with success; otherwise the mode's step reward applies. What
"reaching the goal" means is decided by a *judge*:

* region judge (``rrt-paper``, ``rrt``, ``ned``): the sub-task's goal region contains the robot's
  workspace point (for a sub-task without a goal region, ``goal == ""``: the point lies in the
  guide's last r-ball, ``D = 0``);
* automaton judge (``tl``, ``g-rrt``): the Büchi automaton, run on the labels ``L(x)`` the robot
  visits, makes the sub-task's transition ``nba_state -> next_nba_state`` (``g-rrt``: every
  sub-task's transition in order). A label sequence that kills every run of the automaton (the
  specification is violated) ends the episode like a crash, with ``R-``.

The step rewards (a *gain* is the decrease of the guide distance-to-go ``D_min`` in metres this
step, see ``envs.nav_env``):

* ``rrt-paper``: exactly the paper: ``R+`` on a new minimum of ``D``, else 0.
* ``rrt`` (default) and ``g-rrt``: ``progress * gain - step_cost``: rewards scaled so critic values
  stay near 1, progress proportional to the metres of guide gained (not a constant per ball, so a
  long jump is worth what it covers), and a per-step cost well below the crash penalty so that
  standing still is worse than driving (the "parking" optimum measured in issue 4).
* ``ned``: ``-distance * dist(x, goal region)``: negative Euclidean distance, scaled.
* ``tl``: 0 (sparse: only ``R++`` on accepting progress and ``R-``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any, ClassVar

from envs.errors import EnvConfigError
from planner.geometry.region_test import RegionTest


@dataclass(frozen=True)
class RewardConfig:
    """Reward constants; ``None`` takes the mode's default. Setting a constant that the chosen
    mode does not use is an error (it would be silently ignored otherwise)."""

    crash: float | None = None
    """``R-``: reward of the step that crashes (or violates the automaton). Every mode."""
    goal: float | None = None
    """``R++``: reward of the step that reaches the goal. Every mode."""
    progress: float | None = None
    """``rrt-paper``: ``R+`` per new minimum of ``D``; ``rrt``/``g-rrt``: reward per metre of
    guide distance-to-go gained."""
    step_cost: float | None = None
    """``rrt``/``g-rrt``: cost subtracted on every non-terminal step (against parking)."""
    distance: float | None = None
    """``ned``: penalty per metre of Euclidean distance to the goal region, per step."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise EnvConfigError(f"rewards.{f.name}", f"must be a number, got {value!r}")
            if not math.isfinite(value):
                raise EnvConfigError(f"rewards.{f.name}", f"must be finite, got {value}")
        for name in ("step_cost", "distance", "progress"):
            value = getattr(self, name)
            if value is not None and value < 0:
                raise EnvConfigError(f"rewards.{name}", f"must be >= 0, got {value}")


class RewardMode(ABC):
    """One reward scheme: ``R-``/``R++`` plus the reward of an ordinary step.

    Subclasses declare their name, the constants they use with their defaults, whether they
    need the mission plan (automaton, whole lasso) and which judge decides success.
    """

    name: ClassVar[str]
    defaults: ClassVar[dict[str, float]]
    """Constants (``RewardConfig`` field names) this mode reads, with their defaults."""
    automaton: ClassVar[bool] = False
    """Success is judged by the automaton (needs ``plan``) instead of the goal region."""
    whole_lasso: ClassVar[bool] = False
    """One episode covers the whole lasso (every sub-task) instead of one sub-task."""

    def __init__(self, config: RewardConfig) -> None:
        values: dict[str, float] = dict(self.defaults)
        for f in fields(config):
            value = getattr(config, f.name)
            if value is None:
                continue
            if f.name not in self.defaults:
                used = ", ".join(sorted(self.defaults))
                raise EnvConfigError(
                    f"rewards.{f.name}",
                    f"reward mode {self.name!r} does not use {f.name!r} (it uses: {used})",
                )
            values[f.name] = float(value)
        self.constants = values
        self.crash = values["crash"]
        """``R-``."""
        self.goal = values["goal"]
        """``R++``."""
        self.goal_region: RegionTest | None = None
        """The current goal region (None: the end of the guide, ``goal_end``)."""
        self.goal_end: tuple[float, ...] = ()

    def bind_goal(self, goal: RegionTest | None, end: Sequence[float]) -> None:
        """Tell the mode the goal region (None: no region, the guide's end point ``end``)."""
        self.goal_region = goal
        self.goal_end = tuple(float(v) for v in end)

    def reward(
        self, crashed: bool, reached: bool, improved: bool, gain: float, x: Sequence[float]
    ) -> float:
        """The reward of a step, in the paper's priorities: ``R-`` on a crash (or an automaton
        violation), else ``R++`` when the goal is ``reached``, else :meth:`step_reward`."""
        if crashed:
            return self.crash
        if reached:
            return self.goal
        return self.step_reward(improved, gain, x)

    @abstractmethod
    def step_reward(self, improved: bool, gain: float, x: Sequence[float]) -> float:
        """Reward of a step that neither crashed nor reached the goal: ``improved`` is a new
        minimum of ``D``, ``gain`` the metres of distance-to-go gained, ``x`` the position."""


class PaperReward(RewardMode):
    """``rrt-paper``: ``R-`` = -100 in an obstacle (first priority), ``R++`` = 200 at the goal,
    ``R+`` = 5 on a new minimum of ``D`` (a ball closer to the end than any before), else 0."""

    name = "rrt-paper"
    defaults: ClassVar[dict[str, float]] = {"crash": -100.0, "goal": 200.0, "progress": 5.0}

    def __init__(self, config: RewardConfig) -> None:
        super().__init__(config)
        self._plus = self.constants["progress"]

    def step_reward(self, improved: bool, gain: float, x: Sequence[float]) -> float:
        return self._plus if improved else 0.0


class ScaledReward(RewardMode):
    """``rrt`` (default): ``R-`` = -10, ``R++`` = +20, else ``0.5 * gain - 0.01`` where ``gain``
    is the metres of guide distance-to-go gained this step (entering the first ball counts from
    the guide's start). At 1 m/s and 10 Hz a robot following the guide earns +0.04 a step, a
    parked one -0.01 (about -1 over a 0.99-discounted horizon, well above the crash value -10,
    so crashing on purpose never pays).

    Measured on the car example (``bench/LEARNING.md``): the same shape at a tenth of this scale
    (-1 / +2 / 0.05 per metre / 0.001 a step) trained to 0 % success in 30k steps with every
    other lever on, this scale to a median 100 % on every sub-task; the paper's constants
    (``rrt-paper``) park the agent unless ``min_forward`` forbids standing still, and with it
    still fail the U-turn sub-tasks. Training adds a stall failure (``workers.training_spec``)."""

    name = "rrt"
    defaults: ClassVar[dict[str, float]] = {
        "crash": -10.0,
        "goal": 20.0,
        "progress": 0.5,
        "step_cost": 0.01,
    }

    def __init__(self, config: RewardConfig) -> None:
        super().__init__(config)
        self._per_metre = self.constants["progress"]
        self._cost = self.constants["step_cost"]

    def step_reward(self, improved: bool, gain: float, x: Sequence[float]) -> float:
        return self._per_metre * gain - self._cost


class GlobalReward(ScaledReward):
    """``g-rrt``: the ``rrt`` reward and constants on one guide through the whole lasso (the
    prefix and one suffix cycle, every sub-task path end to end) with one agent; success when
    the automaton has made every sub-task's transition in order (see ``envs.nav_env``)."""

    name = "g-rrt"
    automaton = True
    whole_lasso = True


class DistanceReward(RewardMode):
    """``ned``: ``R-`` = -10, ``R++`` = +20, else ``-0.005 * dist(x, goal region)`` per step
    (at 10 m that is -0.05 a step, about -5 over a 0.99-discounted horizon). The terminal
    values match ``rrt``'s so the baselines differ from it only in the step reward."""

    name = "ned"
    defaults: ClassVar[dict[str, float]] = {"crash": -10.0, "goal": 20.0, "distance": 0.005}

    def __init__(self, config: RewardConfig) -> None:
        super().__init__(config)
        self._scale = self.constants["distance"]

    def step_reward(self, improved: bool, gain: float, x: Sequence[float]) -> float:
        if self.goal_region is not None:
            return -self._scale * self.goal_region.distance(x)
        return -self._scale * math.dist(x, self.goal_end)


class AutomatonReward(RewardMode):
    """``tl``: sparse: ``R++`` = +20 when the automaton makes the sub-task's transition
    ``nba_state -> next_nba_state`` (accepting progress), ``R-`` = -10 on a crash or when the
    labels violate the specification, else 0 (terminal values as ``rrt``'s)."""

    name = "tl"
    defaults: ClassVar[dict[str, float]] = {"crash": -10.0, "goal": 20.0}
    automaton = True

    def step_reward(self, improved: bool, gain: float, x: Sequence[float]) -> float:
        return 0.0


REWARD_MODES: dict[str, type[RewardMode]] = {
    cls.name: cls
    for cls in (ScaledReward, PaperReward, GlobalReward, DistanceReward, AutomatonReward)
}
"""Every reward mode by name; ``rrt`` is the default."""


def reward_mode(name: str, config: RewardConfig | None = None) -> RewardMode:
    """The reward mode ``name`` with ``config`` over its defaults (``EnvConfigError`` for an
    unknown name or a constant the mode does not use)."""
    cls = REWARD_MODES.get(name) if isinstance(name, str) else None
    if cls is None:
        known = ", ".join(REWARD_MODES)
        raise EnvConfigError("reward", f"unknown reward mode {name!r}; known: {known}")
    return cls(config if config is not None else RewardConfig())


def reward_config(value: RewardConfig | dict[str, Any] | None) -> RewardConfig:
    """A ``RewardConfig`` from itself, a mapping of its field names, or None (all defaults)."""
    if value is None:
        return RewardConfig()
    if isinstance(value, RewardConfig):
        return value
    if isinstance(value, dict):
        known = [f.name for f in fields(RewardConfig)]
        for key in value:
            if key not in known:
                raise EnvConfigError(
                    f"rewards.{key}", f"unknown reward constant; known: {', '.join(known)}"
                )
        return RewardConfig(**value)
    raise EnvConfigError("rewards", f"expected a RewardConfig or a mapping, got {value!r}")
