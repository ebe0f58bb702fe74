"""One mission run: the mission validated once, its plan made or loaded once, and its jobs.

Work in progress of issue 15: ``servable_problems`` is the rule both drivers (``ltlnav
train`` and the service) apply before anything runs.
"""

from __future__ import annotations

from workers.mission import MissionSpec


def servable_problems(mission: MissionSpec) -> list[tuple[str, str]]:
    """Why ltlnav cannot train and bundle ``mission`` as ``(field, reason)`` pairs (none: it
    can). The bundle concatenates one agent per sub-task, so a mode that trains one agent for
    the whole lasso is refused before anything is stored."""
    if mission.training.reward.mode == "g-rrt":
        return [
            (
                "training.reward.mode",
                "g-rrt trains one agent for the whole lasso; ltlnav trains and bundles one "
                "agent per sub-task: use rrt, rrt-paper, ned or tl",
            )
        ]
    return []
