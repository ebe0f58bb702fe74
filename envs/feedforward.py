"""The guide feed-forward of ``EnvOptions.guide_feedforward``: a command along the guide that
the policy's action corrects; :class:`ActionShaping` applies it, and
``EnvOptions.min_forward``, to every action of the env.

The quadrotor, commanded by a world-frame velocity, gets ``gain`` times the unit vector toward
the point of the guide ``QUADROTOR_LOOKAHEAD`` seconds of its top speed past its projection on
the guide, added to the policy's action. The point robot, commanded by an acceleration, gets
``gain`` times the command that brings its velocity toward ``max_speed`` in the direction of
the point one braking length ahead on the guide (the velocity error over ``max_speed``: full
acceleration from rest, none at top speed toward it, braking when it moves away). Robots
driven by (forward, turn) actions (unicycle, racecar) get ``gain`` times a turn command toward
the point of the guide ``HEADING_LOOKAHEAD`` seconds of their top speed ahead, on the turn
component (proportional to the heading error, full at 90 degrees or more), and with
``EnvOptions.feedforward_slowdown`` the forward command lowered by as much (the slowest forward
speed at a full turn, so the robot turns back on its tightest circle). Sums are clipped to
``[-1, 1]``. Following the guide is then what a zero action does; the policy learns the
correction around boxes and into the goal (residual policy learning, Silver et al. 2018;
Johannink et al. 2019), instead of first having to discover motion at all.

For robots with a minimum turning radius (racecar) ``EnvOptions.feedforward_law = "pursuit"``
replaces that turn by pure pursuit (Coulter 1992): the target is the point ``PURSUIT_LOOKAHEAD``
turning radii along the leg's :class:`Track` past the robot's projection on it, and the turn
command is the curvature of the arc through it in units of the tightest curvature. On a guide the
car can drive (``EnvOptions.drivable_guide``) the track is the dense redrawn path, and this tracks
the loops and curves that the heading law, or pursuit of the chords between the balls, cuts. Where
the track up to the target passes within ``TIGHT_SLACK`` turning radii of touching an obstacle (a
narrow door), ``EnvOptions.pursuit_tight_lookahead`` radii replace the usual lookahead: pursuit
begins a turn about a lookahead before the track does and cuts its inside, which a door leaves no
room for. Along a redrawn path's reversing lead (a three-point turn, ``Track.cusp``) the law drives
backwards, from entering the leg until the car's projection on the lead comes within
``CUSP_REACHED`` of its end: the forward command negated, the target on the lead or, near its end,
past the cusp along the lead's last direction (``envs.track.lead_target``), and the turn that of
pursuit facing the other way, negated (a car backing up turns the other way). Past the cusp, the
projection is kept off the lead.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from envs.errors import EnvConfigError
from envs.observation import HEADING_FEATURES
from envs.robots import nominal_speed
from envs.robots.base import Robot, wrap_angle
from envs.robots.point import PointParams
from envs.robots.quadrotor import QuadrotorParams
from envs.track import Track, lead_target, lead_togo, point_to_go, projected_togo, pursuit_target

if TYPE_CHECKING:
    from envs.options import EnvOptions

PURSUIT_LOOKAHEAD = 1.3
"""Pure-pursuit lookahead in minimum turning radii (0.8 m for the racecar, whose drivable
guides turn on 1.45 radii), ``EnvOptions.pursuit_lookahead`` unless set. First fitted on
``examples/racecar-phi2-fin.yaml``; then measured with the zero action on the generated worlds
of ``bench/zero_grid.py racecar --seeds 0 20 --env '{"pursuit_lookahead": L}'`` (tuning seeds,
20 starts a sub-task): 1.0 holds 47 of 52 sub-tasks, 1.3 48, 1.6 47, 2.0 38."""

HEADING_LOOKAHEAD = 0.2
"""Seconds of the robot's top speed that the heading law's target runs ahead on the guide (the
unicycle's feed-forward). Measured with the zero action on the generated 2D worlds of
``bench/zero_grid.py`` (tuning seeds 0-19, 20 starts a sub-task, planner margin 0.3 m): 0.2 s
holds 47 of 52 sub-tasks (15 of 20 worlds; 50 of 54 and 19 of 20 on seeds 20-39), 0.1 s 45,
0.3 s 44, 0.5 s 42, 1 s 35; the carrot two balls ahead, which it replaced, 16 (3 worlds): its
chord cuts corners into the obstacles."""

QUADROTOR_LOOKAHEAD = 0.5
"""Seconds of the quadrotor's top speed that its feed-forward target runs ahead on the guide.
Measured with the zero action on the generated 3D cities of ``bench/generality.py`` (tuning
seeds 0-19, 20 starts a sub-task, planner margin 0.3 m): 0.5 s holds 52 of 52 sub-tasks (54 of
54 on seeds 20-39), 1 s 51 of 52; the carrot two balls ahead, which it replaced, 35 of 52 (its
chord cuts the towers' corners where the r-balls are wide)."""


TIGHT_SLACK = 0.2
"""Room, in minimum turning radii (0.12 m for the racecar), between the robot and the
obstacles along the track ahead under which the pursuit law uses
``EnvOptions.pursuit_tight_lookahead``. A guide drawn at the robot's radius plus half the
margin or more keeps more (0.15 m for the racecar)."""

CUSP_REACHED = 0.05
"""Metres short of the end of a reversing lead (``Track.cusp``) from which the pursuit law
drives forwards again, until the car enters a leg anew."""


WORLD_FRAME_ROBOTS = frozenset({"point", "quadrotor"})
"""Robots whose action is a world-frame command, one component per workspace axis."""


def pursuit_direction(
    track: Track, index: int, x: Sequence[float] | np.ndarray, ahead: float
) -> np.ndarray:
    """Unit vector from ``x`` to the point ``ahead`` along ``track`` past its projection on it
    (:func:`pursuit_target`); zeros at that point."""
    return unit_toward(pursuit_target(track, index, x, ahead), x)


def unit_toward(target: np.ndarray, x: Sequence[float] | np.ndarray) -> np.ndarray:
    """Unit vector from ``x`` to ``target``; zeros at ``target``."""
    offset = np.asarray(target, dtype=float) - np.asarray(x, dtype=float)
    norm = float(np.linalg.norm(offset))
    return offset / norm if norm > 1e-9 else np.zeros_like(offset)


def with_feedforward(action: np.ndarray, gain: float, direction: np.ndarray) -> np.ndarray:
    """``action`` plus ``gain`` times ``direction``, clipped to ``[-1, 1]``."""
    return np.clip(np.asarray(action, dtype=float) + gain * direction, -1.0, 1.0)


def velocity_command(
    robot: Robot, track: Track, index: int, x: Sequence[float] | np.ndarray
) -> np.ndarray:
    """Acceleration command of a double integrator (the point robot) toward moving at its top
    speed at the point of ``track`` one braking length ahead (``max_speed^2 / max_accel``:
    twice its stopping distance, so it cuts no corner wider than it can brake): the velocity
    error over ``max_speed``."""
    params = robot.params
    assert isinstance(params, PointParams)
    top = params.max_speed
    direction = pursuit_direction(track, index, x, top * top / params.max_accel)
    velocity = np.asarray(robot.state, dtype=float)[len(direction) :]
    return np.asarray(direction - velocity / top)


def flight_direction(
    robot: Robot, track: Track, index: int, x: Sequence[float] | np.ndarray
) -> np.ndarray:
    """Velocity direction of the quadrotor: toward the point of ``track``
    ``QUADROTOR_LOOKAHEAD`` seconds of its top speed ahead."""
    params = robot.params
    assert isinstance(params, QuadrotorParams)
    return pursuit_direction(track, index, x, QUADROTOR_LOOKAHEAD * params.max_speed)


def heading_direction(
    robot: Robot, track: Track, index: int, x: Sequence[float] | np.ndarray
) -> np.ndarray:
    """Direction the heading law turns a (forward, turn) robot toward: the point of ``track``
    ``HEADING_LOOKAHEAD`` seconds of its top speed ahead."""
    return pursuit_direction(track, index, x, HEADING_LOOKAHEAD * nominal_speed(robot))


def steering_toward(heading: float, direction: np.ndarray) -> float:
    """Turn command in ``[-1, 1]`` from ``heading`` toward the planar ``direction``: the heading
    error over 90 degrees, clipped; 0 for a zero direction."""
    if not np.any(direction[:2]):
        return 0.0
    error = wrap_angle(math.atan2(float(direction[1]), float(direction[0])) - heading)
    return max(-1.0, min(1.0, error / (math.pi / 2)))


def pursuit_turn(
    heading: float, x: Sequence[float] | np.ndarray, target: np.ndarray, turning_radius: float
) -> float:
    """Turn command in ``[-1, 1]`` of the arc from ``x`` facing ``heading`` through
    ``target``: its curvature times ``turning_radius`` (1 at the tightest turn); a full turn
    toward a target behind."""
    dx, dy = float(target[0] - x[0]), float(target[1] - x[1])
    distance = math.hypot(dx, dy)
    if distance < 1e-9:
        return 0.0
    alpha = wrap_angle(math.atan2(dy, dx) - heading)
    if math.cos(alpha) < 0.0:
        return 1.0 if alpha > 0 else -1.0
    return max(-1.0, min(1.0, 2.0 * math.sin(alpha) / distance * turning_radius))


class ActionShaping:
    """``min_forward`` and ``guide_feedforward`` (with its ``feedforward_law``) of an env's
    options, checked against the robot at construction and applied to each action."""

    def __init__(self, robot: Robot, options: EnvOptions) -> None:
        self.robot = robot
        self.forward = options.min_forward
        if self.forward is not None and robot.name not in HEADING_FEATURES:
            raise EnvConfigError(
                "options.min_forward",
                f"only for robots driven by (forward, turn) actions, not a {robot.name}",
            )
        self.gain = options.guide_feedforward
        self.residual = options.residual_scale
        supported = WORLD_FRAME_ROBOTS | HEADING_FEATURES.keys()
        if self.gain is not None and robot.name not in supported:
            raise EnvConfigError(
                "options.guide_feedforward",
                f"only for {', '.join(sorted(supported))} robots, not a {robot.name}",
            )
        self.slowdown = options.feedforward_slowdown
        self.pursuit = 0.0
        """Turning radius of the pursuit law (0: the heading law)."""
        self.ahead = 0.0
        """How far ahead on the guide the pursuit law's point runs, metres."""
        self.tight_ahead = 0.0
        """How far it runs where the track ahead is tight, metres (0: as far)."""
        if options.feedforward_law == "pursuit":
            self.pursuit = robot.params.min_turning_radius()
            self.ahead = (options.pursuit_lookahead or PURSUIT_LOOKAHEAD) * self.pursuit
            self.tight_ahead = (options.pursuit_tight_lookahead or 0.0) * self.pursuit
            if self.pursuit <= 0 or robot.name not in HEADING_FEATURES:
                raise EnvConfigError(
                    "options.feedforward_law",
                    f"pursuit is for robots with a minimum turning radius, not a {robot.name}",
                )
        self.active = self.forward is not None or self.gain is not None
        """Whether actions change at all."""
        self._lead_of: Track | None = None
        """The track whose reversing lead the car has driven since it entered it."""

    def enter(self) -> None:
        """A leg begins (an episode, or the next leg of a course): its reversing lead, if it
        has one, is to be driven."""
        self._lead_of = None

    def _lookahead(self, track: Track, on: float) -> float:
        """The pursuit law's lookahead from ``on`` metres to go on ``track``: the tight one
        where the track up to the usual target passes within ``TIGHT_SLACK`` of touching."""
        if self.tight_ahead and track.least_slack(on, on - self.ahead) < TIGHT_SLACK * self.pursuit:
            return self.tight_ahead
        return self.ahead

    def apply(self, action: np.ndarray, track: Track, index: int) -> np.ndarray:
        """``action``, validated (a bad action must not be mapped into the box and slip
        through), with the feed-forward along the leg's ``track`` from progress index ``index``
        added and the forward command mapped."""
        robot = self.robot
        a = np.array(action, dtype=float)
        if a.shape != (robot.action_dim,) or not np.all(np.abs(a) <= 1.0):
            raise ValueError(
                f"action must have shape ({robot.action_dim},) with components in [-1, 1] "
                f"(actions are not clipped), got {np.asarray(action).tolist()}"
            )
        backwards = False
        if self.gain is not None and self.residual is not None:
            if robot.name in WORLD_FRAME_ROBOTS:
                a *= self.residual
            else:
                a[1] *= self.residual
        if self.gain is not None:
            x = robot.position()
            if self.pursuit:
                cusp = track.cusp_togo
                if cusp is not None and self._lead_of is not track:
                    on = lead_togo(track, x)
                    backwards = on > cusp + CUSP_REACHED
                    if not backwards:
                        self._lead_of = track
                if backwards:
                    assert cusp is not None
                    target = lead_target(track, on - self.ahead)
                    turn = -pursuit_turn(robot.heading() + math.pi, x, target, self.pursuit)
                else:
                    on = projected_togo(track, index, x)
                    on = on if cusp is None else min(on, cusp)
                    target = point_to_go(track, on - self._lookahead(track, on))
                    turn = pursuit_turn(robot.heading(), x, target, self.pursuit)
            else:
                if robot.name == "point":
                    toward = velocity_command(robot, track, index, x)
                elif robot.name == "quadrotor":
                    toward = flight_direction(robot, track, index, x)
                else:
                    toward = heading_direction(robot, track, index, x)
                if robot.name in WORLD_FRAME_ROBOTS:
                    return with_feedforward(a, self.gain, toward)
                turn = steering_toward(robot.heading(), toward)
                if self.slowdown:
                    slowest = -1.0 if self.forward is not None else 0.0
                    a[0] = min(a[0], max(slowest, a[0] - self.gain * abs(turn)))
            a[1] = min(1.0, max(-1.0, a[1] + self.gain * turn))
        if self.forward is not None:
            a[0] = self.forward + (1.0 - self.forward) * 0.5 * (a[0] + 1.0)
        if backwards:
            a[0] = -a[0]
        return a
