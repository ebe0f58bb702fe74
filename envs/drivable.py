"""Drivable guides (``EnvOptions.drivable_guide``): a car's sub-task guides redrawn as paths it
can follow.

:func:`planner.geometry.drivable.drivable_path` redraws one polyline from one pose. Here a mission's
sub-tasks are redrawn in the order a rollout drives them (the prefix, then the suffix once):
the first from the mission start, every other one from where the previous *redrawn* guide
enters its goal region, facing along it (``envs.handover.arrival_pose``), which is also where
``envs.handover`` starts it. So a U-turn at a hand-over becomes a loop the car can drive. Each
guide is redrawn keeping the largest of :func:`clearances` each of its pieces fits (a piece
keeps less only where nothing keeps more); a sub-task that fits none keeps its polyline (the env
still trains, on the guide a point robot would follow).

The redrawn paths are dense (``planner.geometry.drivable.STEP`` apart);
``envs.factory.build_course`` thins them to the guide's ball spacing. Redrawing every sub-task
costs about 0.1 s each, and every sub-task env of a mission redraws the same course, so results
are cached per world."""

from __future__ import annotations

import dataclasses
from collections import OrderedDict
from collections.abc import Sequence
from typing import Any

import numpy as np

from envs.handover import arrival_pose
from planner.decompose import SubTask, lasso_stages
from planner.geometry.drivable import drivable_path
from planner.geometry.pose import Pose
from planner.geometry.world import World

CACHE_SIZE = 16
"""Redrawn courses kept (each entry holds its world, so the world's id stays unique)."""

_cache: OrderedDict[tuple[Any, ...], tuple[World, list[SubTask]]] = OrderedDict()


CLEARANCE_SHARES = (1.0, 0.5, 0.25, 0.125, 0.0)
"""The redraw's clearances: the robot's radius plus these shares of the room the plan sought
beyond it. Each halving of the room is a step down, which costs a piece
``planner.geometry.drivable.TIGHT_COST`` times its length more: halving down to an eighth, a
door that leaves the car a few centimetres a side still tells the piece through its middle from
one that grazes a jamb."""


def clearances(radius: float, sought: float) -> list[float]:
    """Clearances to redraw at, largest first: ``CLEARANCE_SHARES`` of the way from the robot's
    ``radius`` to what the plan ``sought`` (its ``hold``: the radius plus the whole margin, even
    where it fell back to less)."""
    top = max(radius, sought)
    return sorted({radius + share * (top - radius) for share in CLEARANCE_SHARES}, reverse=True)


def redraw_course(
    world: World,
    subtasks: Sequence[SubTask],
    start: Pose,
    rho: float,
    clearance_steps: Sequence[float],
) -> list[SubTask]:
    """``subtasks`` (same order and indices) with their paths redrawn as drivable paths of
    turning radius ``rho`` (see the module docstring); ``start`` is the mission start pose."""
    key = (
        id(world),
        round(rho, 9),
        tuple(round(c, 9) for c in clearance_steps),
        tuple(np.round(start.position, 9).tolist()),
        round(start.heading, 9),
        tuple((s.phase, s.goal, np.asarray(s.path, dtype=float).tobytes()) for s in subtasks),
    )
    hit = _cache.get(key)
    if hit is not None:
        _cache.move_to_end(key)
        return list(hit[1])
    drawn: list[SubTask] = list(subtasks)
    pose = start
    first, *rest = clearance_steps
    for k in lasso_stages(subtasks, 1):
        sub = subtasks[k]
        polyline = np.asarray(sub.path, dtype=float)
        path = drivable_path(world, polyline, pose, rho, first, fallback=rest)
        if path is not None:
            points = path.points
            drawn[k] = dataclasses.replace(
                sub, start=points[0].copy(), path=points, reverse=path.cusp
            )
        pose = arrival_pose(world, drawn[k])
    _cache[key] = (world, drawn)
    while len(_cache) > CACHE_SIZE:
        _cache.popitem(last=False)
    return list(drawn)
