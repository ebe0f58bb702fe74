"""Judges of an episode's end: their outcomes, and the automaton judge.

The region judge (the goal region contains the robot's point, or the guide's last r-ball
without a goal region) is a test of ``envs.nav_env``'s legs; the automaton judge
(:class:`AutomatonTracker`) runs the Büchi automaton on the labels ``L(x)`` the robot visits
through the sub-tasks' transitions (reward modes ``tl`` and ``g-rrt``, see ``envs.rewards``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from envs.errors import EnvConfigError
from planner.ltl.automaton import Buchi

RUNNING = 0
"""Judge outcome: the episode goes on."""
SUCCESS = 1
"""Judge outcome: the goal is reached (``R++``, terminated, ``is_success``)."""
VIOLATION = 2
"""Judge outcome: the automaton rejects the labels seen (``R-``, terminated, no success)."""


@dataclass(frozen=True)
class Stage:
    """One sub-task seen by the automaton: from ``source`` make the transition to ``target``; when
    ``source == target`` (a piece that stays in one state) the stage ends on entering ``goal``
    (or, without a goal region, at the end of its guide)."""

    source: int
    target: int
    goal: str


class AutomatonTracker:
    """The set of automaton states reachable on the labels read so far, through a sequence of
    stages (one per sub-task). Within a stage the set starts at the stage's ``source``; when it
    contains the ``target`` the stage is complete and the next starts at that target (the run
    commits to the plan's state). An empty set means the specification is violated.

    Transitions of a (state set, label) pair are memoised, so a step costs a dict lookup.
    """

    def __init__(self, nba: Buchi, stages: Sequence[Stage]) -> None:
        if not stages:
            raise EnvConfigError("plan", "the automaton judge needs at least one sub-task")
        for s in stages:
            for q in (s.source, s.target):
                if not 0 <= q < nba.num_states:
                    raise EnvConfigError("plan", f"automaton state {q} is not in the automaton")
        self.nba = nba
        self.stages = tuple(stages)
        self.stage = 0
        self.states: frozenset[int] = frozenset({stages[0].source})
        self._post: dict[tuple[frozenset[int], frozenset[str]], frozenset[int]] = {}

    def reset(self, stage: int = 0) -> None:
        """Start stage ``stage`` at its source state."""
        self.stage = stage
        self.states = frozenset({self.stages[stage].source})

    @property
    def done(self) -> bool:
        """Every stage is complete."""
        return self.stage >= len(self.stages)

    def read(self, label: frozenset[str], at_end: bool) -> int:
        """Read one label; ``at_end`` tells whether the robot is in its guide's last ball.
        Returns how many stages completed on this label (0 or 1), or -1 on a violation."""
        key = (self.states, label)
        nxt = self._post.get(key)
        if nxt is None:
            nxt = frozenset(q2 for q in self.states for q2 in self.nba.successors(q, label))
            self._post[key] = nxt
        if not nxt:
            self.states = nxt
            return -1
        self.states = nxt
        stage = self.stages[self.stage]
        if stage.source != stage.target:
            complete = stage.target in nxt
        else:
            complete = (stage.goal in label) if stage.goal else at_end
        if not complete:
            return 0
        self.stage += 1
        if self.stage < len(self.stages):
            self.states = frozenset({self.stages[self.stage].source})
        return 1
