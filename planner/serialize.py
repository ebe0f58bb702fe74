"""A ``MissionPlan`` and its automata as plain JSON, with an exact round trip.

Jobs, bundles and the service carry plans as JSON so that every sub-task trains on the very
same guide the planner produced (floats are kept exactly).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.decompose import SubTask
from planner.ltl.automaton import Buchi, Edge
from planner.ltl.guard import Cube, Guard
from planner.plan import MissionPlan
from planner.search.tl_rrt_star import Lasso


def buchi_to_dict(nba: Buchi) -> dict[str, Any]:
    """A Büchi automaton as JSON with its guards as cubes (exact round trip)."""
    return {
        "atoms": list(nba.atoms),
        "state_names": list(nba.state_names),
        "initial": nba.initial,
        "accepting": sorted(nba.accepting),
        "edges": [
            {
                "source": e.source,
                "target": e.target,
                "cubes": [[sorted(c.pos), sorted(c.neg)] for c in e.guard.sorted_cubes()],
            }
            for e in nba.edges
        ],
    }


def buchi_from_dict(doc: dict[str, Any]) -> Buchi:
    """The inverse of ``buchi_to_dict``."""
    edges = tuple(
        Edge(
            int(e["source"]),
            Guard(frozenset(Cube(frozenset(p), frozenset(n)) for p, n in e["cubes"])),
            int(e["target"]),
        )
        for e in doc["edges"]
    )
    return Buchi(
        atoms=tuple(doc["atoms"]),
        state_names=tuple(doc["state_names"]),
        initial=int(doc["initial"]),
        accepting=frozenset(int(q) for q in doc["accepting"]),
        edges=edges,
    )


def plan_to_dict(plan: MissionPlan) -> dict[str, Any]:
    """Everything of a ``MissionPlan`` as JSON: automata, lasso, sub-tasks, radii (exact floats,
    so a job rebuilt from it trains on the very same guide)."""
    lasso = plan.lasso
    doc: dict[str, Any] = {
        "formula": plan.formula,
        "start": plan.start.tolist(),
        "nba": buchi_to_dict(plan.nba),
        "pruned": buchi_to_dict(plan.pruned),
        "lasso": {
            "prefix": lasso.prefix.tolist(),
            "suffix": lasso.suffix.tolist(),
            "prefix_states": list(lasso.prefix_states),
            "suffix_states": list(lasso.suffix_states),
            "prefix_cost": lasso.prefix_cost,
            "suffix_cost": lasso.suffix_cost,
            "cost": lasso.cost,
        },
        "subtasks": [subtask_to_dict(s) for s in plan.subtasks],
        "eta": plan.eta,
        "r_ball": plan.r_ball,
        "seconds": plan.seconds,
        "translation_seconds": plan.translation_seconds,
        "clearance": plan.clearance,
        "hold": plan.hold,
    }
    if plan.drawn is not None:
        doc["drawn"] = [subtask_to_dict(s) for s in plan.drawn]
    return doc


def subtask_to_dict(sub: SubTask) -> dict[str, Any]:
    """One sub-task as JSON (``reverse`` only when a redrawn guide backs up)."""
    doc: dict[str, Any] = {
        "index": sub.index,
        "phase": sub.phase,
        "goal": sub.goal,
        "start": sub.start.tolist(),
        "path": sub.path.tolist(),
        "nba_state": sub.nba_state,
        "next_nba_state": sub.next_nba_state,
    }
    if sub.reverse:
        doc["reverse"] = sub.reverse
    return doc


def subtask_from_dict(doc: dict[str, Any]) -> SubTask:
    """The inverse of ``subtask_to_dict``."""
    return SubTask(
        index=int(doc["index"]),
        phase=doc["phase"],
        goal=str(doc["goal"]),
        start=np.asarray(doc["start"], dtype=float),
        path=np.asarray(doc["path"], dtype=float),
        nba_state=int(doc["nba_state"]),
        next_nba_state=int(doc["next_nba_state"]),
        reverse=int(doc.get("reverse", 0)),
    )


def plan_from_dict(doc: dict[str, Any]) -> MissionPlan:
    """The inverse of ``plan_to_dict`` (KeyError/ValueError/TypeError on a malformed one)."""
    lasso = doc["lasso"]
    return MissionPlan(
        formula=str(doc["formula"]),
        start=np.asarray(doc["start"], dtype=float),
        nba=buchi_from_dict(doc["nba"]),
        pruned=buchi_from_dict(doc["pruned"]),
        lasso=Lasso(
            prefix=np.asarray(lasso["prefix"], dtype=float),
            suffix=np.asarray(lasso["suffix"], dtype=float),
            prefix_states=[int(q) for q in lasso["prefix_states"]],
            suffix_states=[int(q) for q in lasso["suffix_states"]],
            prefix_cost=float(lasso["prefix_cost"]),
            suffix_cost=float(lasso["suffix_cost"]),
            cost=float(lasso["cost"]),
        ),
        subtasks=[subtask_from_dict(s) for s in doc["subtasks"]],
        eta=float(doc["eta"]),
        r_ball=float(doc["r_ball"]),
        seconds=float(doc["seconds"]),
        translation_seconds=float(doc["translation_seconds"]),
        clearance=float(doc.get("clearance", 0.0)),
        hold=float(doc.get("hold", doc.get("clearance", 0.0))),
        drawn=[subtask_from_dict(s) for s in doc["drawn"]] if "drawn" in doc else None,
    )
