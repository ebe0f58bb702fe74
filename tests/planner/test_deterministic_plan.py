"""Plans depend on the mission and the seed only: not on the machine's speed or its load.

The default anytime budget counts iterations, not CPU seconds, so a plan made while another
thread of the same process and another process burn CPU is byte for byte the plan made on an
idle machine (timing fields aside).
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from planner.geometry.shapes import Box, Polygon
from planner.geometry.world import World
from planner.plan import plan_mission
from planner.search.planner_spec import PlannerSpec

TIMING_FIELDS = ("seconds",)
BUSY_SECONDS = 30.0


def reference_world() -> World:
    """The 1 x 1 workspace of the reference TL-RRT* implementation, with two wide regions."""

    def tri(x: float, y: float) -> Polygon:
        return Polygon(np.array([[x, y], [x + 0.2, y], [x, y + 0.2]]))

    return World(
        np.array([[0.0, 1.0], [0.0, 1.0]]),
        [
            Box(np.array([0.3, 0.0]), np.array([0.7, 0.2])),
            Box(np.array([0.4, 0.7]), np.array([0.6, 1.0])),
        ],
        {"l1": tri(0.1, 0.7), "l2": tri(0.7, 0.7), "l3": tri(0.7, 0.3)},
    )


def plan_document(seed: int = 3) -> str:
    """The plan JSON of a patrol with default planner options, timing fields removed."""
    plan = plan_mission(
        reference_world(),
        "[]<>l1 && []<>l2 && []<>l3",
        np.array([0.8, 0.1]),
        0.0,
        PlannerSpec(seed=seed),
    )
    doc: dict[str, Any] = plan.to_json()
    for name in TIMING_FIELDS:
        doc.pop(name)
    return json.dumps(doc, indent=1)


@contextmanager
def busy_cpu() -> Iterator[None]:
    """Burn CPU in a thread of this process (it shares the process's CPU clock and the GIL) and
    in a child process; both stop by themselves after BUSY_SECONDS at the latest."""
    stop = threading.Event()
    deadline = time.monotonic() + BUSY_SECONDS

    def spin() -> None:
        x = 0
        while not stop.is_set() and time.monotonic() < deadline:
            x += 1

    spinner = threading.Thread(target=spin, daemon=True)
    burner = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"import time\nend = time.monotonic() + {BUSY_SECONDS}\n"
            "while time.monotonic() < end: pass",
        ]
    )
    spinner.start()
    try:
        yield
    finally:
        stop.set()
        burner.kill()
        burner.wait()
        spinner.join()


def test_same_plan_on_an_idle_and_a_busy_cpu() -> None:
    idle = plan_document()
    with busy_cpu():
        busy = plan_document()
    assert busy == idle


def test_seed_changes_the_plan() -> None:
    assert plan_document(seed=3) != plan_document(seed=4)


def test_default_budget_counts_iterations() -> None:
    options = PlannerSpec()
    assert options.refine_seconds is None and options.refine_iterations > 0
