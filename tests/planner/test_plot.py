"""The plan picture (``planner.plot.plot_plan``): the r-balls it draws."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner import plot
from planner.guidance import Guide
from planner.plan import plan_mission
from planner.search.planner_spec import PlannerSpec
from tests.planner.test_plan import START, reference_world


def drawn_radii(monkeypatch: pytest.MonkeyPatch, out: Path, **kwargs: Any) -> set[float]:
    radii: list[float] = []
    real = plot.Circle

    def recording(centre: Any, radius: float, **style: Any) -> Any:
        radii.append(radius)
        return real(centre, radius, **style)

    monkeypatch.setattr(plot, "Circle", recording)
    world = reference_world()
    plan = plan_mission(world, "<>(l1 && <>l2)", START, 0.0, PlannerSpec(seed=0, r_ball=0.04))
    plot.plot_plan(world, plan, out, **kwargs)
    assert out.is_file()
    return set(radii)


def test_the_picture_draws_the_plans_r_balls_or_the_given_guides(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert drawn_radii(monkeypatch, tmp_path / "plan.png") == {0.04}
    narrow = [Guide.from_path(np.array([[0.8, 0.1], [0.2, 0.8]]), 0.02)]
    assert drawn_radii(monkeypatch, tmp_path / "trained.png", guides=narrow) == {0.02}
