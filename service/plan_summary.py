"""What ``ltlnav plan`` prints about a plan: the automaton, the lasso, the clearance it keeps and
each sub-task."""

from __future__ import annotations

from planner.geometry.polyline import path_length
from planner.plan import MissionPlan

_SLACK = 1e-9


def clearance_line(clearance: float, radius: float, margin: float) -> str:
    """The clearance a plan keeps from obstacles, and whether the robot's margin fitted."""
    if margin <= 0:
        return f"clearance: {clearance:.2f} m (the robot's radius; no margin asked)"
    if clearance >= radius + margin - _SLACK:
        return f"clearance: {clearance:.2f} m (radius {radius:.2f} + margin {margin:.2f})"
    kept = clearance - radius
    if kept > _SLACK:
        held = f"radius {radius:.2f} + {kept:.2f} of the {margin:.2f} m margin, which"
    else:
        held = f"radius {radius:.2f} alone: the {margin:.2f} m margin"
    return (
        f"clearance: {clearance:.2f} m at the narrowest ({held} does not fit everywhere; "
        "the path is pushed out toward the whole margin wherever there is room)"
    )


def summary_lines(plan: MissionPlan, radius: float, margin: float) -> list[str]:
    """The lines ``ltlnav plan`` prints for ``plan`` of a robot of ``radius`` and ``margin``."""
    lasso = plan.lasso
    lines = [
        f"automaton: {plan.nba.num_states} states / {plan.nba.num_transitions} transitions, "
        f"pruned {plan.pruned.num_states} / {plan.pruned.num_transitions} "
        f"({plan.translation_seconds * 1000:.0f} ms)",
        f"lasso: prefix {lasso.prefix_cost:.2f} ({len(lasso.prefix)} waypoints), "
        f"suffix {lasso.suffix_cost:.2f} ({len(lasso.suffix)} waypoints), "
        f"cost {lasso.cost:.2f}, found in {plan.seconds:.2f} s",
        clearance_line(plan.clearance, radius, margin),
    ]
    for sub in plan.subtasks:
        lines.append(
            f"  sub-task {sub.index} [{sub.phase}] -> {sub.goal or '(end of guide)'}: "
            f"{path_length(sub.path):.2f} long"
        )
    return lines
