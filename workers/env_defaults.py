"""The env options each protocol of ``workers.training_spec.TrainingSpec`` starts from: what
the ``shaped`` protocol gives every reward mode (measured defaults, per robot) and the
``paper`` protocol's env as published."""

from __future__ import annotations

from typing import Any, Literal

TRAINING_ENV_DEFAULTS: dict[str, Any] = {
    "curriculum": 0.7,
    "rays": 16,
    "r_ball_within_clearance": True,
}
"""Env options the ``shaped`` protocol uses unless ``env`` sets them (measured in
``bench/LEARNING.md``): 70 % of training episodes start at a random r-ball of the guide with
the progress index to match, so the far end of a long guide is trained from the start
(evaluations always use 0); 16 lidar-like rays in the observation (training and evaluation
alike), so that keeping off a box is a function of what the robot senses, not of a memorised
map; r-balls no wider than the plan's clearance, so none reaches through a wall (in a 54 m
world the plan's 1.9 m ball past a door held the robot before the wall): the zero action on the
tuning worlds of ``bench/zero_grid.py ROBOT --seeds 0 40`` (20 starts a sub-task) holds 106 of
106 sub-tasks for every robot with it, against 105 (point, racecar) and 106 (point in 3D,
quadrotor) without it; the unicycle 266 of 266 on seeds 0-99 against 261. Its effect on what
SAC learns is measured on the racecar's report missions only: rooms 1002's three trained
sub-tasks met their targets with it; 1001's first fails either way (8 % of the missions with it,
26 % without, one seed on one machine)."""

STALL_ENV_DEFAULTS: dict[str, Any] = {"stall_steps": 30}
"""Training defaults of the ``shaped`` protocol: an episode that reaches no new r-ball for 30
steps ends as a failure with the mode's crash reward (``stall_penalty``), so leaving the guide
costs what a crash costs and the off-guide wandering never fills the replay buffer. A mission's
``stall_steps`` or ``stall_spacings`` (the window in the robot's terms) replaces it. The
window in the robot's terms (``stall_spacings`` 4) cut none of the robots' own controllers
short where 30 steps cut a third (``bench/stall_window.py``), but trained worse on the only
report sub-task that needed training (racecar 1001, seeds 0 and 1: 36.5 and 25 % against 63
and 35 %, ``bench/LEARNING.md``), so it is not the default. Evaluations never stop a stalled
episode."""

Protocol = Literal["shaped", "paper"]
"""The env every reward mode trains and is evaluated in (``TrainingSpec.protocol``)."""

PAPER_ENV: dict[str, Any] = {
    "observation": "paper",
    "rays": 0,
    "curriculum": 0.0,
    "goal_judge": "guide_end",
}
"""The ``paper`` protocol, Cai et al.'s env as published: the observation is the robot's state
and the product state ``(s_t, i_t)`` (no ball offsets, no rays), episodes start at the real
start (no curriculum), nothing ends an episode early but a crash or the goal, no action
shaping (no stall, ``min_forward``, feed-forward or redrawn guide), and a sub-task is met at
``D = 0`` (the guide's last r-ball)."""

HEADING_ENV_DEFAULTS: dict[str, Any] = {"min_forward": 0.2}
"""Defaults for robots driven by (forward, turn) actions, in training and evaluation alike (it
changes what an action means): the forward command maps onto [0.2, 1] of the top speed, which
removes the parking optimum; without it every measured agent learned to stand still."""


GUIDE_ENV_DEFAULTS: dict[str, dict[str, Any]] = {
    "point": {"guide_feedforward": 1.0},
    "quadrotor": {"guide_feedforward": 1.0},
    "unicycle": {"guide_feedforward": 1.0, "feedforward_slowdown": True},
    "racecar": {
        "drivable_guide": 1.45,
        "guide_feedforward": 1.0,
        "feedforward_law": "pursuit",
        "pursuit_tight_lookahead": 0.6,
        "progress_window": 2,
    },
}
"""Defaults per robot of the ``shaped`` protocol, in training and evaluation alike (they change
what an action means and which guide the reward follows). Measured in ``bench/LEARNING.md``:

* point: the acceleration that brings it to top speed toward the guide's point one braking
  length ahead (``envs.feedforward.velocity_command``): on generated 21 x 21 m mazes of 0.3 m
  walls (``<>(g1 && <>g2)``, guides up to 64 m), tuned on maze seed 1 and reported on seeds
  100-104, the zero action alone meets 100 % of 50 trials on all ten sub-tasks; without it a
  61 m guide stayed at 0 % to 55k steps (the agent learned to stop short of the goal).
* quadrotor: the full velocity command toward the guide's carrot is added to the policy's
  action (``envs.feedforward``), which then learns the correction: phi_1,inf sub-task 0 from
  0 % at 40k steps to 100 % at 5k; the feed-forward alone (a zero policy) crashes there.
* racecar: every guide is redrawn as Dubins arcs of 1.45 times its turning radius (0.9 m)
  from the hand-over pose (``envs.drivable``), so the U-turns at g2 and g3 become loops it can
  drive; the feed-forward turn is pure pursuit along that guide; a ball counts only two past
  the progress index, so the start of a loop is not taken for its end. Without them the
  U-turn sub-tasks stayed at 0-69 % up to 150k steps; with them the zero action makes every
  sub-task of racecar phi_2,fin and 100 % of its missions, and each needs all three. The
  factor was fitted on that example; on the generated tuning worlds of ``bench/zero_grid.py
  racecar --env '{"drivable_guide": F}'`` the zero action holds 48 of 52 sub-tasks at F = 1.2,
  1.45 and 1.7, and 46 at 2.0. Where the track ahead passes within 0.12 m of touching (a
  narrow door), pursuit aims 0.6 turning radii ahead instead of 1.3, so it starts a turn past
  the door later and cuts less of it: on tuning seeds 0-69 (20 starts a sub-task) 182 -> 185 of
  186 sub-tasks held, 68 -> 69 of 70 worlds (seeds 42 and 66, 0.77 and 0.88 m doors; 0.6 and
  0.9 were tried on those two alone, 0.6 kept before the whole grid ran); on seeds 70-99,
  measured once after the choice, 76 -> 78 of 80 and 27 -> 28 of 30 worlds.

* unicycle: the turn toward the guide's point ``HEADING_LOOKAHEAD`` seconds ahead
  (``envs.feedforward.heading_direction``): on the tuning worlds of ``bench/zero_grid.py`` the
  zero action alone holds 47 of 52 sub-tasks (the carrot two balls ahead, no default: 16), and
  every sub-task of ``examples/car-phi2-fin.yaml``. With ``feedforward_slowdown`` it also
  slows down as it turns, so a guide that turns back at a hand-over becomes a tight U-turn:
  ``bench/zero_grid.py unicycle --seeds 0 40`` 102 -> 106 of 106 sub-tasks held (36 -> 40 of
  40 worlds); on seeds 40-99, not looked at while choosing it, 154 -> 155 of 160 (seed 66
  loses a sub-task that cuts the corner behind a door, four others gain)."""
