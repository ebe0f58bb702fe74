"""The product-state navigation env: a robot drives one sub-task's guide (or the whole lasso).

An episode starts at one of the sub-task's real starts (``envs.handover``: where the mission
hands the robot over to it; or, with the curriculum, at a random r-ball of its guide with the
progress index set to match) and ends when

* the robot crashes (``robot.collided()``: obstacle or out of bounds): terminated, ``R-``,
  ``is_success`` False; this has first priority;
* the judge of the reward mode says the goal is reached (the goal region contains the robot's
  point, or with ``goal_judge`` ``"guide_end"`` the guide's last r-ball does; ``tl``/``g-rrt``:
  the automaton made the sub-task's transition(s)): terminated, ``R++``, ``is_success`` True;
* the labels seen leave the sub-task's automaton stage (a region the formula forbids there, e.g.
  ``g2`` before ``g1`` in ``!g2 U g1``): terminated like a crash, ``R-``, ``violation`` True.
  Every reward mode is judged so when the env has the plan's automaton (``make_env`` with
  ``plan=``), as the whole mission is;
* optionally, no new r-ball was reached for ``stall_steps`` steps (``EnvOptions.stall_steps``
  or ``stall_spacings``);
* the step limit is hit: truncated, ``is_success`` False.

The progress index ``i_t`` and ``D_min`` come from ``planner.guidance.ProgressTracker``; the
distance-to-go ``D_min`` (metres of guide left, counted from the guide's start before any ball)
drives the ``rrt`` gain. ``g-rrt`` chains one guide per sub-task path into one course through
the whole lasso: the progress index is global (offset of the current leg plus its local
index), and the tracker moves to the next leg when the automaton completes the current leg's
transition. The lasso returns to where its suffix starts, so a single ``Guide`` over the
concatenated path would give the suffix's start the suffix end's ``D = 0``; tracking leg by leg
keeps ``D`` meaningful along the cycle.

``info`` on every step: ``is_success``, ``progress_index`` (global ``i_t``), ``d`` (``D(x_t)``,
inf outside every ball), ``distance_to_go`` (``D_min``), ``collision``, ``violation``,
``stalled``, ``stage`` (the current leg; sub-task order) and ``steps``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from envs.errors import EnvConfigError
from envs.feedforward import ActionShaping
from envs.judge import RUNNING, SUCCESS, VIOLATION, AutomatonTracker, Stage
from envs.leg import Leg
from envs.observation import ObservationBuilder
from envs.potential import GuidePotential
from envs.rays import RayCaster, ray_reach
from envs.rewards import RewardMode
from envs.robots import Robot
from planner.geometry.pose import Pose
from planner.geometry.world import World
from planner.ltl.automaton import Buchi

if TYPE_CHECKING:
    from envs.options import EnvOptions


class NavEnv(gym.Env[np.ndarray, np.ndarray]):
    """A robot in a world following r-ball guides under a reward mode; build with
    ``envs.make_env``. See the module docstring for episodes and ``envs.observation`` for the
    observation layout. Actions are the robot's, in ``[-1, 1]^action_dim``; an action of the
    wrong shape or outside that box raises ``ValueError`` (never clipped)."""

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 10}  # noqa: RUF012

    def __init__(
        self,
        world: World,
        robot: Robot,
        legs: Sequence[Leg],
        mode: RewardMode,
        options: EnvOptions,
        *,
        max_steps: int,
        stall_steps: int = 0,
        starts: Sequence[Pose],
        nba: Buchi | None = None,
        render_mode: str | None = None,
        owns_robot: bool = True,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise EnvConfigError("render_mode", f"must be None or 'rgb_array', got {render_mode!r}")
        if robot.workspace_dim != world.dim:
            raise EnvConfigError(
                "robot", f"the robot moves in {robot.workspace_dim}D but the world is {world.dim}D"
            )
        if not legs:
            raise EnvConfigError("subtask", "no sub-task to drive")
        if mode.automaton and nba is None:
            raise EnvConfigError("plan", f"reward mode {mode.name!r} needs the mission plan")
        self.world, self.robot, self.mode, self.options = world, robot, mode, options
        self.render_mode = render_mode
        self._owns_robot = owns_robot
        self.legs = list(legs)
        self.num_balls = sum(leg.guide.num_balls for leg in self.legs)
        self.guide_length = sum(leg.guide.length for leg in self.legs)
        self._labels = world.labeler.point_labels
        self._automaton: AutomatonTracker | None = None
        if nba is not None:
            stages = [
                Stage(leg.subtask.nba_state, leg.subtask.next_nba_state, leg.subtask.goal)
                for leg in self.legs
            ]
            self._automaton = AutomatonTracker(nba, stages)
        first = self.legs[0]
        mode.bind_goal(first.goal, first.guide.centers[-1].tolist())
        if not starts:
            raise EnvConfigError("starts", "no start pose")
        self.starts = list(starts)
        """The real starts (``envs.handover``): an episode without the curriculum begins at one
        of them, drawn uniformly."""
        centers = np.concatenate([leg.guide.centers for leg in self.legs])
        self.ray_caster: RayCaster | None = None
        if options.rays:
            self.ray_caster = RayCaster(world, options.rays, ray_reach(options, robot.params))
        r_ball = first.guide.r
        look = options.lookahead_range or 2.0 * r_ball * (options.lookahead + 1)
        self._obs = ObservationBuilder(
            robot, centers, options.observation, options.lookahead, look, self.ray_caster
        )
        self.observation_space = self._obs.space
        self.action_space = spaces.Box(-1.0, 1.0, shape=(robot.action_dim,), dtype=np.float32)
        self.max_steps = int(max_steps)
        self.stall_steps = int(stall_steps)
        """Steps without a new r-ball that end an episode (0: never; ``envs.factory``)."""
        self._shaping = ActionShaping(robot, options)
        self._leg = first
        self._leg_k = 0
        self._t = 0
        self._since = 0
        self._togo = first.guide.length + first.rest
        self._index = -1
        self._dense = options.dense_progress
        self._potential = 0.0
        self._guide_potential = GuidePotential(
            [leg.guide.centers for leg in self.legs],
            [leg.guide.dist_to_go for leg in self.legs],
            [leg.rest for leg in self.legs],
        )
        self.trail: list[list[float]] = []
        """Workspace points visited in this episode (recorded only for rendering)."""

    # ------------------------------------------------------------------------------ episode
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode. ``options`` (all optional): ``position`` and ``heading`` (an
        explicit start, no curriculum or noise), ``start`` (index into ``starts``: that real
        start, with the start noise, no curriculum), or ``keep_robot=True`` (track from where
        the robot stands, without resetting it: hand-over between sub-task envs sharing a
        robot)."""
        super().reset(seed=seed)
        rng = self.np_random
        opts = dict(options or {})
        unknown = set(opts) - {"position", "heading", "start", "keep_robot"}
        if unknown:
            raise ValueError(
                f"unknown reset options {sorted(unknown)}; known: position, heading, start, "
                "keep_robot"
            )
        chosen = opts.get("start")
        valid = isinstance(chosen, int) and not isinstance(chosen, bool)
        if chosen is not None and not (valid and 0 <= chosen < len(self.starts)):
            raise ValueError(f"reset option start must index one of {len(self.starts)} starts")
        leg_k, ball = 0, -1
        if opts.get("keep_robot"):
            start = self.robot.position()
        elif "position" in opts:
            start = np.asarray(opts["position"], dtype=float)
            heading = opts.get("heading")
            self.robot.reset(start, rng, None if heading is None else float(heading))
        else:
            o = self.options
            curriculum = chosen is None and o.curriculum > 0 and self.num_balls > 1
            if curriculum and rng.random() < o.curriculum:
                leg_k, ball = self._leg_of(int(rng.integers(0, self.num_balls - 1)))
                start = self.legs[leg_k].guide.centers[ball].copy()
                heading = self.legs[leg_k].headings[ball]
                keep: frozenset[str] | None = None
            else:
                if chosen is None:
                    chosen = 0 if len(self.starts) == 1 else int(rng.integers(len(self.starts)))
                pose = self.starts[chosen]
                start, heading = pose.position.copy(), pose.heading
                keep = self._labels(start.tolist())
            if o.start_noise > 0:
                start = self._perturb(start, keep, rng)
            if o.heading_noise > 0:
                heading += float(rng.uniform(-o.heading_noise, o.heading_noise))
            self.robot.reset(start, rng, heading)
        x = self.robot.position().tolist()
        self._enter_leg(leg_k, x, ball)
        if self._automaton is not None:
            self._automaton.reset(leg_k)
        self._t = 0
        self._since = 0
        self.trail = [x] if self.render_mode is not None else []
        if self._dense:
            self._potential = self._continuous_togo(x)
        obs = self._obs.build(self.robot.observation(), x, self._index)
        i = self._leg.tracker.locate(x, ball)
        d = float(self._leg.guide.dist_to_go[i]) if i >= 0 else math.inf
        return obs, self._info(d, False, self.robot.collided(), False, False)

    def _leg_of(self, ball: int) -> tuple[int, int]:
        for k, leg in enumerate(self.legs):
            if ball < leg.offset + leg.guide.num_balls:
                return k, ball - leg.offset
        raise AssertionError("ball index beyond the course")

    def _enter_leg(self, k: int, x: list[float], ball: int = -1) -> None:
        """Track leg ``k`` from point ``x``; ``ball`` >= 0 is a curriculum start ball."""
        leg = self.legs[k]
        self._leg, self._leg_k = leg, k
        self._shaping.enter()
        index = max(ball, leg.tracker.locate(x, ball))
        if index >= 0:
            leg.tracker.reset(0, start_index=index)
            self._togo = leg.rest + float(leg.guide.dist_to_go[index])
        else:
            leg.tracker.reset(0)
            self._togo = leg.rest + leg.guide.length
        self._index = leg.offset + index
        self.mode.bind_goal(leg.goal, leg.guide.centers[-1].tolist())

    def _perturb(
        self, start: np.ndarray, keep: frozenset[str] | None, rng: np.random.Generator
    ) -> np.ndarray:
        d, radius = self.world.dim, self.options.start_noise
        lo, hi = self.world.bounds[:, 0], self.world.bounds[:, 1]
        for _ in range(100):
            u = rng.normal(size=d)
            u *= radius * rng.uniform() ** (1.0 / d) / max(float(np.linalg.norm(u)), 1e-12)
            p = start + u
            if np.any(p < lo) or np.any(p > hi):
                continue
            if self.world.in_collision(p[None, :], self.robot.radius)[0]:
                continue
            if keep is not None and self._labels(p.tolist()) != keep:
                continue
            return p
        return start

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        robot = self.robot
        if self._shaping.active:
            leg = self._leg
            action = self._shaping.apply(action, leg.track, self._index - leg.offset)
        robot.step(action)
        self._t += 1
        raw = robot.observation()
        x = robot.position().tolist()
        leg = self._leg
        improved, local, d = leg.tracker.update_one(0, x)
        togo = self._togo
        if improved:
            self._togo = leg.rest + d
            self._since = 0
        else:
            self._since += 1
        self._index = leg.offset + local
        if self.render_mode is not None:
            self.trail.append(x)
        truncated = stalled = False
        crashed = robot.collided()
        if crashed:
            outcome = RUNNING
        elif self.mode.automaton:
            outcome = self._automaton_outcome(x, d)
        else:
            outcome = self._region_outcome(leg, x, d)
        success, violation = outcome == SUCCESS, outcome == VIOLATION
        terminated = crashed or outcome != RUNNING
        gain = 0.0
        if not terminated:
            # togo - _togo: the metres gained, including a move to the next leg (g-rrt).
            gain = togo - self._togo
            if self._dense:
                before, self._potential = self._potential, self._continuous_togo(x)
                gain = before - self._potential
        reward = self.mode.reward(crashed or violation, success, improved, gain, x)
        if not terminated:
            if self._t >= self.max_steps:
                truncated = True
            stall = self.stall_steps
            if stall and self._since >= stall:
                stalled = True
                if self.options.stall_penalty is None:
                    truncated = True
                else:
                    reward, terminated = self.options.stall_penalty, True
        obs = self._obs.build(raw, x, self._index)
        return (
            obs,
            reward,
            terminated,
            truncated,
            self._info(d, success, crashed, violation, stalled),
        )

    def _continuous_togo(self, x: list[float]) -> float:
        """``envs.potential``'s guide left from ``x`` (``dense_progress``)."""
        return self._guide_potential.value(self._leg_k, self._index - self._leg.offset, x)

    def _region_outcome(self, leg: Leg, x: list[float], d: float) -> int:
        """SUCCESS when the goal region (or the guide's last ball) holds ``x``; else VIOLATION
        when the labels seen so far leave the sub-task's automaton stage (given the plan), else
        RUNNING."""
        goal = leg.goal if self.options.goal_judge == "region" else None
        if goal.contains(x) if goal is not None else d == 0.0:
            return SUCCESS
        tracker = self._automaton
        if tracker is None or tracker.done:
            return RUNNING
        return VIOLATION if tracker.read(self._labels(x), d == 0.0) < 0 else RUNNING

    def _automaton_outcome(self, x: list[float], d: float) -> int:
        """Feed ``L(x)`` to the automaton: RUNNING (moving on to the next leg when a stage
        completes), SUCCESS after the last stage, or VIOLATION."""
        tracker = self._automaton
        assert tracker is not None
        moved = tracker.read(self._labels(x), d == 0.0)
        if moved < 0:
            return VIOLATION
        if moved == 0:
            return RUNNING
        if tracker.done:
            return SUCCESS
        self._enter_leg(tracker.stage, x)
        self._since = 0
        return RUNNING

    def _info(
        self, d: float, success: bool, crashed: bool, violation: bool, stalled: bool
    ) -> dict[str, Any]:
        return {
            "is_success": success,
            "progress_index": self._index,
            "d": d,
            "distance_to_go": self._togo,
            "collision": crashed,
            "violation": violation,
            "stalled": stalled,
            "stage": self._leg_k,
            "steps": self._t,
        }

    @property
    def progress_index(self) -> int:
        """The global progress index ``i_t`` (-1 before the first ball)."""
        return self._index

    @property
    def steps(self) -> int:
        """Steps taken in the current episode."""
        return self._t

    @property
    def steps_without_progress(self) -> int:
        """Steps since the last new r-ball (what ``stall_steps`` is compared with)."""
        return self._since

    # ------------------------------------------------------------------------------ output
    def render(self) -> np.ndarray | None:
        """An RGB image (H, W, 3) of the world, guide, r-balls, trail and robot."""
        if self.render_mode != "rgb_array":
            return None
        from envs.render import render_frame

        return render_frame(self)

    def close(self) -> None:
        """Release the robot's simulator (unless the robot is shared with another env)."""
        if self._owns_robot:
            self.robot.close()
        super().close()
