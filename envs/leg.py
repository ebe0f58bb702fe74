"""One leg of the env's course (``envs.nav_env.NavEnv``): a sub-task path with its guide,
tracker, goal and pursuit track (built by ``envs.factory.build_course``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from envs.track import Track
from planner.geometry.region_test import RegionTest
from planner.guidance import Guide, ProgressTracker

if TYPE_CHECKING:
    from planner.decompose import SubTask


@dataclass(eq=False)
class Leg:
    """One sub-task path of the course: its guide and tracker, where its balls start in the
    global progress index, and how much guide follows it."""

    subtask: SubTask
    guide: Guide
    tracker: ProgressTracker
    offset: int
    """Global progress index of the leg's first ball."""
    rest: float
    """Guide length of the legs after this one."""
    goal: RegionTest | None
    """The goal region (None: the end of the guide)."""
    headings: list[float]
    """Yaw from each ball's centre toward the guide ahead (curriculum starts)."""
    track: Track
    """The path the pursuit feed-forward follows (``envs.track.Track``)."""
