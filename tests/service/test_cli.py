"""The ``ltlnav`` command line end to end, through Typer's runner (real planner, tiny worlds)."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from service.cli import EXIT_BAD_INPUT, EXIT_INFEASIBLE, app
from service.plan_summary import clearance_line

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
runner = CliRunner()

GF3: dict[str, Any] = {
    "name": "tiny-gf2",
    "task": "[]!obstacle && []<>a && []<>b",
    "robot": {"model": "point", "start": [0.5, 0.5], "radius": 0.05},
    "planner": {"seed": 1, "refine_seconds": 0.2},
    "world": {
        "bounds": [[0, 4], [0, 4]],
        "obstacles": [{"box": {"min": [1.8, 0.0], "max": [2.2, 2.5]}}],
        "regions": {
            "a": {"ball": {"center": [3.4, 0.6], "radius": 0.3}},
            "b": {"box": {"min": [0.2, 3.2], "max": [0.8, 3.8]}},
        },
    },
}


def write(tmp_path: Path, mission: dict[str, object]) -> Path:
    path = tmp_path / "mission.yaml"
    path.write_text(yaml.safe_dump(mission))
    return path


def test_ltl2ba_prints_hoa() -> None:
    result = runner.invoke(app, ["ltl2ba", "[]<>a && []<>b"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0] == "HOA: v1"
    assert "--BODY--" in lines and lines[-1] == "--END--"
    assert any(line.startswith("AP: 2") for line in lines)


@pytest.mark.parametrize("fmt", ["dot", "json"])
def test_ltl2ba_other_formats(fmt: str) -> None:
    result = runner.invoke(app, ["ltl2ba", "a U b", "--format", fmt])
    assert result.exit_code == 0, result.output
    if fmt == "json":
        document = json.loads(result.output)
        assert set(document["atoms"]) == {"a", "b"}
    else:
        assert result.output.lstrip().startswith("digraph")


def test_ltl2ba_reports_formula_column() -> None:
    result = runner.invoke(app, ["ltl2ba", "[]<>a && "])
    assert result.exit_code == EXIT_BAD_INPUT
    assert "column" in result.output


def test_plan_writes_valid_json_and_picture(tmp_path: Path) -> None:
    mission = write(tmp_path, GF3)
    out_json, out_png = tmp_path / "plan.json", tmp_path / "plan.png"
    result = runner.invoke(
        app, ["plan", str(mission), "--json", str(out_json), "--plot", str(out_png)]
    )
    assert result.exit_code == 0, result.output
    plan = json.loads(out_json.read_text())
    prefix, suffix = np.array(plan["prefix"]), np.array(plan["suffix"])
    assert np.allclose(prefix[0], [0.5, 0.5])
    assert np.allclose(suffix[0], prefix[-1]) and np.allclose(suffix[-1], prefix[-1])
    assert {sub["goal"] for sub in plan["subtasks"]} >= {"a", "b"}
    assert plan["automaton"]["states"] >= 2 and plan["cost"] > 0
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "sub-task" in result.output


def test_plan_says_whether_the_margin_fitted(tmp_path: Path) -> None:
    wide = runner.invoke(app, ["plan", str(write(tmp_path, GF3))])
    assert wide.exit_code == 0, wide.output
    assert "clearance: 0.35 m (radius 0.05 + margin 0.30)" in wide.output
    # A 0.6 m door: room for the radius and half the 0.3 m margin (0.5 m), not all of it.
    door = copy.deepcopy(GF3)
    door["task"] = "[]!obstacle && <>a"
    door["robot"]["radius"] = 0.1
    door["world"] = {
        "bounds": [[0, 4], [0, 4]],
        "obstacles": [
            {"box": {"min": [1.9, 0.0], "max": [2.1, 1.7]}},
            {"box": {"min": [1.9, 2.3], "max": [2.1, 4.0]}},
        ],
        "regions": {"a": {"ball": {"center": [3.4, 0.6], "radius": 0.3}}},
    }
    narrow = runner.invoke(app, ["plan", str(write(tmp_path, door))])
    assert narrow.exit_code == 0, narrow.output
    assert "clearance: 0.25 m at the narrowest (radius 0.10 + 0.15 of the 0.30 m margin" in (
        narrow.output
    )


def test_the_clearance_line_without_a_margin() -> None:
    line = clearance_line(0.2, 0.2, 0.0)
    assert line == "clearance: 0.20 m (the robot's radius; no margin asked)"


def test_plan_seed_override_is_deterministic(tmp_path: Path) -> None:
    mission = write(tmp_path, {**GF3, "planner": {"seed": 0, "refine_seconds": 0.0}})
    costs = []
    for _ in range(2):
        out = tmp_path / "p.json"
        result = runner.invoke(app, ["plan", str(mission), "--json", str(out), "--seed", "7"])
        assert result.exit_code == 0, result.output
        costs.append(json.loads(out.read_text())["prefix"])
    assert costs[0] == costs[1]


def test_plan_infeasible_mission_exits_with_reason(tmp_path: Path) -> None:
    walled = dict(GF3)
    walled["task"] = "[]<>a && []!a"
    result = runner.invoke(app, ["plan", str(write(tmp_path, walled))])
    assert result.exit_code == EXIT_INFEASIBLE, result.output
    assert "unsatisfiable" in result.output


def test_plan_bad_mission_names_the_field(tmp_path: Path) -> None:
    bad = json.loads(json.dumps(GF3))
    bad["world"]["regions"]["a"]["ball"]["radius"] = -1
    result = runner.invoke(app, ["plan", str(write(tmp_path, bad))])
    assert result.exit_code == EXIT_BAD_INPUT
    assert "world.regions.a.ball.radius" in result.output


def test_plan_refuses_an_automaton_over_the_admission_limit(tmp_path: Path) -> None:
    """``ltlnav plan`` keeps the limits ``validate``, ``train`` and the service keep: an
    any-order visit of 12 regions (4096 states, 37 s to translate) is refused at once."""
    many = json.loads(json.dumps(GF3))
    many["task"] = " && ".join(f"<>g{i}" for i in range(12))
    many["world"]["regions"] = {
        f"g{i}": {"ball": {"center": [0.3 + 0.3 * i, 3.5], "radius": 0.1}} for i in range(12)
    }
    result = runner.invoke(app, ["plan", str(write(tmp_path, many))])
    assert result.exit_code == EXIT_BAD_INPUT, result.output
    assert "LTLNAV_MAX_AUTOMATON_STATES" in result.output


def test_plan_refuses_more_legs_than_the_admission_limit(tmp_path: Path) -> None:
    legged = json.loads(json.dumps(GF3))
    legged.setdefault("planner", {})["leg_length"] = 0.01
    result = runner.invoke(app, ["plan", str(write(tmp_path, legged))])
    assert result.exit_code == EXIT_BAD_INPUT, result.output
    assert "planner.leg_length" in result.output and "LTLNAV_MAX_SUBTASKS" in result.output


def test_validate_accepts_every_example() -> None:
    for path in sorted(EXAMPLES.glob("*.yaml")):
        result = runner.invoke(app, ["validate", str(path)])
        assert result.exit_code == 0, f"{path.name}: {result.output}"
