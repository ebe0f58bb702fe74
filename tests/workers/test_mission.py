"""Mission documents: every bad input gives a MissionError naming the exact path."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from envs.spec import RobotSpec
from planner.errors import LtlnavError
from planner.search.planner_spec import PlannerSpec
from workers.mission import MissionError, MissionSpec, load_mission, parse_mission

BASE: dict[str, Any] = {
    "name": "small",
    "world": {
        "bounds": [[-10, 10], [-10, 10]],
        "obstacles": [
            {"box": {"min": [1, 1], "max": [2, 3]}},
            {"ball": {"center": [4, 4], "radius": 0.5}},
            {"polygon": [[0, -4], [1, -4], [0, -3]]},
        ],
        "regions": {
            "g1": {"ball": {"center": [8, 8], "radius": 1}},
            "g2": {"box": {"min": [-8, 6], "max": [-6, 8]}},
            "g3": {"polygon": [[6, -8], [8, -8], [7, -6]]},
        },
    },
    "robot": {"model": "unicycle", "start": [-8, -8, 0], "radius": 0.2},
    "task": "[]!obstacle && <>(g1 && <>(g2 && <>g3))",
    "planner": {"seed": 3},
}


def mission(**changes: Any) -> dict[str, Any]:
    data = copy.deepcopy(BASE)
    data.update(changes)
    return data


def problems(data: dict[str, Any]) -> list[tuple[str, str]]:
    with pytest.raises(MissionError) as info:
        parse_mission(data)
    err = info.value
    assert isinstance(err, LtlnavError)
    assert str(err) == "\n".join(f"{p}: {m}" for p, m in err.problems)
    return err.problems


def test_the_planner_margin_defaults_to_the_robots_own() -> None:
    unset = parse_mission(mission())
    assert unset.planner.margin is None
    assert unset.planner_options().margin == 0.3  # the unicycle's
    assert unset.planner_options().seed == 3
    quad = {"model": "quadrotor", "start": [-8, -8, 1], "radius": 0.2}
    world = {**BASE["world"], "bounds": [[-10, 10], [-10, 10], [0, 4]]}
    world["obstacles"] = [{"box": {"min": [1, 1, 0], "max": [2, 3, 4]}}]
    world["regions"] = {"g1": {"ball": {"center": [8, 8, 2], "radius": 1}}}
    flying = parse_mission(mission(robot=quad, world=world, task="<>g1"))
    assert flying.planner_options().margin == 0.3
    racecar = {"model": "racecar", "start": [-8, -8, 0], "radius": 0.3}
    assert parse_mission(mission(robot=racecar)).planner_options().margin == 0.3
    chosen = parse_mission(mission(robot=quad, world=world, task="<>g1", planner={"margin": 0}))
    assert chosen.planner_options().margin == 0.0  # a mission's own margin, even 0, is kept


def test_valid_mission() -> None:
    spec = parse_mission(mission())
    assert spec.name == "small"
    assert spec.planner == PlannerSpec(seed=3)
    assert spec.robot.workspace_dim == 2
    assert spec.labels() == frozenset({"g1", "g2", "g3"})
    world = spec.build_world()
    assert world is spec.build_world()
    assert world.region_names == ("g1", "g2", "g3")
    assert len(world.obstacles) == 3


def test_defaults() -> None:
    data = mission()
    del data["name"], data["planner"]
    spec = parse_mission(data)
    assert spec.name == "mission"
    assert spec.planner == PlannerSpec()


def test_build_world_follows_changes() -> None:
    data = mission()
    data["world"]["random_obstacles"] = {"count": 5, "size": [1, 1], "seed": 1, "clearance": 1}
    spec = parse_mission(data)
    first = spec.build_world()
    assert len(first.obstacles) == 8
    moved = spec.model_copy(update={"robot": RobotSpec(model="point", start=[0.0, 8.0])})
    assert moved.build_world() is not first


def test_region_radius_must_be_positive() -> None:
    data = mission()
    data["world"]["regions"]["g1"]["ball"]["radius"] = 0
    assert problems(data) == [("world.regions.g1.ball.radius", "must be > 0")]


def test_unknown_label_names_column_and_known_labels() -> None:
    data = mission(task="[]!obstacle && <>(g1 && <>g4)")
    assert problems(data) == [
        ("task", "unknown label 'g4' (column 27); the world defines g1, g2, g3")
    ]


def test_unknown_label_in_letter_syntax() -> None:
    data = mission(task="G!obstacle & GFg1 & GFg5")
    assert problems(data) == [
        ("task", "unknown label 'g5' (column 23); the world defines g1, g2, g3")
    ]


def test_start_in_collision() -> None:
    data = mission()
    data["robot"]["start"] = [2.1, 2.0]
    [(path, message)] = problems(data)
    assert path == "robot.start"
    assert "in collision with world.obstacles.0" in message
    assert "robot.radius 0.2" in message
    data["robot"]["start"] = [2.3, 2.0]
    data["robot"]["radius"] = 0.2
    assert parse_mission(data).robot.start == [2.3, 2.0]


def test_start_too_close_to_the_bounds_or_outside() -> None:
    data = mission()
    data["robot"]["start"] = [-9.9, 0]
    [(path, message)] = problems(data)
    assert (path, "world boundary" in message) == ("robot.start", True)
    data["robot"]["start"] = [-12, 0]
    [(path, message)] = problems(data)
    assert (path, "outside the world bounds" in message) == ("robot.start", True)


def test_region_outside_bounds() -> None:
    data = mission()
    data["world"]["regions"]["g1"] = {"ball": {"center": [9.5, 8], "radius": 1}}
    [(path, message)] = problems(data)
    assert path == "world.regions.g1"
    assert message.startswith("lies outside the world bounds")


def test_goal_inside_obstacles() -> None:
    data = mission()
    data["world"]["obstacles"].append({"box": {"min": [6.5, 6.5], "max": [9.5, 9.5]}})
    [(path, message)] = problems(data)
    assert path == "world.regions.g1"
    assert "entirely inside obstacles" in message


def test_goal_free_only_for_a_thinner_robot() -> None:
    data = mission()
    # Four boxes leave only a 0.2-wide free cross in the middle of g1.
    for lo, hi in [([6, 6], [7.9, 7.9]), ([8.1, 6], [10, 7.9]), ([6, 8.1], [7.9, 10])]:
        data["world"]["obstacles"].append({"box": {"min": lo, "max": hi}})
    data["world"]["obstacles"].append({"box": {"min": [8.1, 8.1], "max": [10, 10]}})
    data["robot"]["radius"] = 0.05
    parse_mission(data)
    data["robot"]["radius"] = 0.2
    assert [p for p, _ in problems(data)] == ["world.regions.g1"]


def test_unused_region_inside_obstacles_is_fine() -> None:
    data = mission(task="[]!obstacle && <>g1")
    data["world"]["obstacles"].append({"box": {"min": [-9, 5], "max": [-5, 9]}})
    assert parse_mission(data).labels() == frozenset({"g1"})


def test_wrong_start_length() -> None:
    data = mission()
    data["robot"]["start"] = [1, 2, 3, 4]
    assert problems(data) == [
        ("robot.start", "a unicycle starts at [x, y] or [x, y, theta], got 4 numbers")
    ]
    data["robot"] = {"model": "quadrotor", "start": [1, 2]}
    assert problems(data) == [
        ("robot.start", "a quadrotor starts at [x, y, z] or [x, y, z, yaw], got 2 numbers")
    ]


def test_3d_world_with_a_2d_robot() -> None:
    data = mission(task="<>g1")
    data["world"] = {
        "bounds": [[0, 10], [0, 10], [0, 10]],
        "regions": {"g1": {"ball": {"center": [5, 5, 5], "radius": 1}}},
    }
    data["robot"] = {"model": "unicycle", "start": [1, 1]}
    [(path, message)] = problems(data)
    assert path == "robot.model"
    assert "unicycle moves in 2D but the world is 3D" in message
    data["robot"] = {"model": "point", "start": [1, 1]}
    assert [p for p, _ in problems(data)] == ["robot.start"]
    data["robot"] = {"model": "quadrotor", "start": [1, 1, 1, 0.5]}
    assert parse_mission(data).robot.position().tolist() == [1, 1, 1]


def test_unknown_top_level_key_lists_allowed_keys() -> None:
    assert problems(mission(planer={"seed": 1})) == [
        ("planer", "unknown key; allowed here: name, world, robot, task, planner, training")
    ]


def test_unknown_nested_key() -> None:
    data = mission()
    data["world"]["regions"]["g1"]["ball"]["centre"] = [1, 1]
    assert problems(data) == [
        ("world.regions.g1.ball.centre", "unknown key; allowed here: center, radius")
    ]


def test_formula_syntax_error_has_column() -> None:
    [(path, message)] = problems(mission(task="[]!obstacle && <>(g1 && )"))
    assert path == "task"
    assert message.startswith("column 25: ")
    assert "expected" in message


def test_next_is_rejected() -> None:
    [(path, message)] = problems(mission(task="[]!obstacle && X g1"))
    assert path == "task"
    assert message.startswith("column 16: ")


def test_polygon_with_two_vertices() -> None:
    data = mission()
    data["world"]["regions"]["g3"] = {"polygon": [[6, -8], [8, -8]]}
    assert problems(data) == [
        ("world.regions.g3.polygon", "a polygon needs at least 3 vertices, got 2")
    ]


def test_shape_with_two_keys() -> None:
    data = mission()
    data["world"]["obstacles"][1] = {"ball": {"center": [4, 4], "radius": 1}, "box": {}}
    [(path, message)] = problems(data)
    assert path == "world.obstacles.1"
    assert "exactly one key" in message


def test_every_problem_is_reported() -> None:
    data = mission(task="<>g7", name="bad name", planner={"eta": -1})
    data["robot"]["model"] = "tank"
    data["world"]["bounds"] = [[1, 0], [0, 1]]
    data["world"]["obstacles"][0]["box"]["max"] = [float("nan"), 3]
    paths = [p for p, _ in problems(data)]
    assert paths == [
        "name",
        "world.bounds",
        "world.obstacles.0.box.max.0",
        "robot.model",
        "planner.eta",
        "task",
    ]


def test_several_cross_section_problems_at_once() -> None:
    data = mission(task="[]!obstacle && <>g1 && <>g9")
    data["robot"]["start"] = [1.5, 2]
    data["world"]["obstacles"].append({"ball": {"center": [8, 8], "radius": 2}})
    assert [p for p, _ in problems(data)] == ["task", "robot.start", "world.regions.g1"]


def test_missing_sections_and_wrong_types() -> None:
    data = mission(task=5)
    del data["robot"]
    data["world"]["regions"] = [1]
    assert problems(data) == [
        ("world.regions", "must be a mapping"),
        ("robot", "required"),
        ("task", "must be a string"),
    ]
    with pytest.raises(MissionError) as info:
        parse_mission([1, 2])
    assert info.value.problems[0][0] == "mission"


def test_region_label_rules() -> None:
    data = mission()
    data["world"]["regions"]["obstacle"] = {"ball": {"center": [0, 0], "radius": 1}}
    [(path, message)] = problems(data)
    assert path == "world.regions.obstacle"
    assert "reserved" in message


def test_region_named_like_a_shape_keeps_its_path() -> None:
    data = mission(task="<>ball")
    data["world"]["regions"]["ball"] = {"ball": {"center": [0, 0], "radius": -1}}
    assert problems(data) == [("world.regions.ball.ball.radius", "must be > 0")]


def test_generator_failure_is_located() -> None:
    data = mission()
    data["world"]["random_obstacles"] = {"count": 10, "size": [3, 3], "clearance": 15}
    [(path, message)] = problems(data)
    assert path == "world.random_obstacles.count"
    assert "could place only" in message


def test_load_yaml_and_json(tmp_path: Path) -> None:
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(BASE))
    (tmp_path / "m.json").write_text(json.dumps(BASE))
    (tmp_path / "m.txt").write_text(json.dumps(BASE))
    specs = [load_mission(tmp_path / f"m.{ext}") for ext in ("yaml", "json", "txt")]
    assert specs[0] == specs[1] == specs[2]
    assert isinstance(specs[0], MissionSpec)


def test_bad_yaml_names_its_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("name: x\nworld:\n  bounds: [[0, 1], [0, 1]]\n  regions: {a: [}\n")
    with pytest.raises(MissionError) as info:
        load_mission(path)
    [(where, message)] = info.value.problems
    assert where == str(path)
    assert message.startswith("invalid YAML at line 4")


def test_duplicate_yaml_key_names_its_line(tmp_path: Path) -> None:
    path = tmp_path / "dup.yaml"
    path.write_text("name: x\ntask: '<>g1'\nname: y\n")
    with pytest.raises(MissionError) as info:
        load_mission(path)
    assert info.value.problems == [
        (str(path), "invalid YAML at line 3, column 1: duplicate key 'name'")
    ]


def test_bad_json_and_unreadable_files(tmp_path: Path) -> None:
    path = tmp_path / "bad.json"
    path.write_text('{"name": "x",\n "world": }')
    with pytest.raises(MissionError) as info:
        load_mission(path)
    assert info.value.problems[0][1].startswith("invalid JSON at line 2, column 11")
    for missing in (tmp_path / "absent.yaml", tmp_path):
        with pytest.raises(MissionError, match="cannot read the file"):
            load_mission(missing)
    empty = tmp_path / "empty.yaml"
    empty.write_text("\n")
    with pytest.raises(MissionError, match="the file is empty"):
        load_mission(empty)


def test_json_schema_documents_every_field() -> None:
    schema = MissionSpec.model_json_schema()
    assert schema["additionalProperties"] is False
    for name, definition in schema["$defs"].items():
        if name == "PlannerSpec":
            continue
        for field, prop in definition.get("properties", {}).items():
            assert prop.get("description"), f"{name}.{field} has no description"


def test_start_position_and_dimension() -> None:
    robot = RobotSpec(model="racecar", start=[1.0, 2.0, 0.3])
    assert robot.workspace_dim == 2
    assert np.array_equal(robot.position(), [1.0, 2.0])
    assert robot.radius == 0.2 and robot.params == {}
    assert RobotSpec(model="point", start=[1, 2, 3]).workspace_dim == 3


def test_validation_needs_no_simulator() -> None:
    code = "import sys, workers.mission; print(sorted({'torch', 'pybullet'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_unknown_robot_parameter_names_the_known_ones() -> None:
    data = {
        "task": "<>g1",
        "robot": {"model": "unicycle", "start": [0, 0], "params": {"top_speed": 2.0}},
        "world": {
            "bounds": [[-5, 5], [-5, 5]],
            "regions": {"g1": {"ball": {"center": [3, 3], "radius": 1}}},
        },
    }
    with pytest.raises(MissionError) as caught:
        parse_mission(data)
    message = str(caught.value)
    assert "robot.params" in message and "top_speed" in message and "max_speed" in message
    data["robot"]["params"] = {"max_speed": -1.0}  # type: ignore[index]
    with pytest.raises(MissionError, match=r"robot\.params"):
        parse_mission(data)
