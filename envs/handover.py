"""Where the concatenated policy hands the robot to a sub-task: its handover poses, and so the
real starts of every sub-task env (``real_starts``, used by ``envs.factory``).

A mission rollout switches sub-policies in place: sub-task ``k`` takes over wherever the robot
stands when the previous sub-task's goal region is first entered, heading the way it came.
That is not the start of ``k``'s guide (the cut point of the lasso, inside the region) and,
when the lasso leaves a region the way it entered, it faces away from ``k``'s guide. Training
and evaluating ``k`` from its guide's start facing along it measures a state the mission never
produces; these poses are the states it does produce, read from the plan alone (so sub-tasks
still train in parallel): the point where each predecessor's guide enters its goal region and
the guide's direction there.

Predecessors follow the lasso order (``planner.decompose.lasso_stages``: the prefix, then the
suffix cycled): the sub-task before in the sequence; the first suffix sub-task also follows the
last suffix one (the cycle closes); the first sub-task of the sequence follows the mission
start.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from envs.errors import EnvConfigError
from planner.decompose import SubTask, lasso_stages, phases
from planner.geometry.pose import Pose, final_heading, heading_along, yaw
from planner.geometry.region_test import RegionTest
from planner.geometry.world import World

STEP = 0.02
"""Spacing (m) of the points tried along a guide for the first one inside its goal region."""
INSIDE = 0.05
"""How far (m) past the region's boundary the arrival point is taken, so it is inside."""


def predecessors(subtasks: Sequence[SubTask], k: int) -> list[int | None]:
    """Indices of the sub-tasks the rollout hands sub-task ``k`` over from (None: the mission
    start), in lasso order."""
    suffix = phases(subtasks)[1]
    sequence = lasso_stages(subtasks, 1)
    at = sequence.index(k)
    found: list[int | None] = [None] if at == 0 else [sequence[at - 1]]
    if suffix and k == suffix[0] and suffix[-1] not in found:
        found.append(suffix[-1])
    return found


def arrival_pose(world: World, subtask: SubTask) -> Pose:
    """Where a robot following ``subtask``'s guide first enters its goal region (a little
    inside), facing along the guide; the guide's end for a sub-task without a goal region."""
    path = np.asarray(subtask.path, dtype=float)
    goal = RegionTest(world.regions[subtask.goal]) if subtask.goal else None
    travelled_inside = -1.0
    for a, b in itertools.pairwise(path):
        length = float(np.linalg.norm(b - a))
        if length < 1e-12:
            continue
        count = max(1, math.ceil(length / STEP))
        for t in np.linspace(0.0, 1.0, count + 1)[1:]:
            p = a + t * (b - a)
            if goal is not None and goal.contains(p.tolist()):
                entered = travelled_inside >= 0.0
                travelled_inside = travelled_inside + length / count if entered else 0.0
                if travelled_inside >= INSIDE:
                    return Pose(p, yaw(b - a))
            elif travelled_inside >= 0.0:
                travelled_inside = -1.0
    if goal is not None and travelled_inside < 0.0 and not goal.contains(path[-1].tolist()):
        raise EnvConfigError(
            "subtask.path", f"sub-task {subtask.index}'s guide never enters region {subtask.goal!r}"
        )
    return Pose(path[-1].copy(), final_heading(path))


def opening_pose(pool: Sequence[SubTask], robot: np.ndarray, heading: float | None) -> Pose:
    """The pose a rollout of ``pool`` begins in: the first sub-task's start, facing the robot's
    given ``heading`` when the robot (standing at ``robot``) is there, else along the guide."""
    first = np.asarray(pool[0].start, dtype=float)
    if heading is not None and np.allclose(first, robot):
        return Pose(first, heading)
    return Pose(first, heading_along(np.asarray(pool[0].path, dtype=float)))


def real_starts(
    world: World,
    pool: Sequence[SubTask],
    subtask: SubTask,
    handover_of: int | None,
    opening: Pose,
    robot: np.ndarray,
    heading: float | None,
    guide_heading: float,
) -> list[Pose]:
    """The real starts of an env whose first sub-task is ``subtask``, in the course ``pool``
    that ``opening`` begins (``opening_pose``).

    With ``handover_of`` (``subtask``'s position in ``pool``): the poses the mission hands it
    over in, the mission starting where the robot stands (``robot``), facing its ``heading`` or
    else as ``opening``. Otherwise ``subtask``'s start, facing as ``opening`` when it begins the
    course, the robot's ``heading`` when the robot stands there, else ``guide_heading``."""
    if handover_of is not None:
        mission_start = Pose(robot, heading if heading is not None else opening.heading)
        return handover_poses(world, pool, handover_of, mission_start)
    facing = guide_heading
    if subtask is pool[0]:
        facing = opening.heading
    elif heading is not None and np.allclose(subtask.start, robot):
        facing = heading
    return [Pose(np.asarray(subtask.start, dtype=float), facing)]


def handover_poses(
    world: World, subtasks: Sequence[SubTask], k: int, mission_start: Pose
) -> list[Pose]:
    """The poses sub-task ``k`` takes the robot over in (``mission_start`` first when it is
    one of them)."""
    return [
        mission_start if p is None else arrival_pose(world, subtasks[p])
        for p in predecessors(subtasks, k)
    ]


def checked_starts(starts: Sequence[Pose], world: World) -> list[Pose]:
    """``starts`` given in place of the real ones, checked: at least one, each a finite point of
    the world's dimension inside its bounds with a finite heading."""
    checked = list(starts)
    if not checked:
        raise EnvConfigError("starts", "no start pose given")
    lo, hi = world.bounds[:, 0], world.bounds[:, 1]
    for i, pose in enumerate(checked):
        p = np.asarray(pose.position, dtype=float)
        if p.shape != (world.dim,) or not np.all(np.isfinite(p)):
            raise EnvConfigError(f"starts.{i}", f"must be a finite {world.dim}D point")
        if np.any(p < lo) or np.any(p > hi):
            raise EnvConfigError(f"starts.{i}", f"{p.tolist()} is outside the world bounds")
        if not math.isfinite(pose.heading):
            raise EnvConfigError(f"starts.{i}", f"heading must be finite, got {pose.heading}")
    return checked
