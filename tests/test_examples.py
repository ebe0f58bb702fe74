"""The bundled example missions load, match the paper's tasks, and every goal is reachable."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from planner.ltl.formula import atoms, parse
from workers.mission import MissionSpec, load_mission

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SHARED = Path("/work/shared/benchmarks")

SEQUENCE_12 = "[]!obstacle && <>(" + "".join(f"g{i} && <>(" for i in range(1, 11))
SEQUENCE_12 += "g11 && <>g12" + ")" * 11
TASKS = {
    "car-phi2-fin": "[]!obstacle && <>(g1 && <>(g2 && <>(g3 && <>ginit)))",
    "car-phi2-inf": "[]!obstacle && []<>(g1 && <>(g2 && <>g3))",
    "car-phi3-fin": SEQUENCE_12,
    "car-phi3-inf": "[]!obstacle && " + " && ".join(f"[]<>g{i}" for i in range(1, 13)),
    "racecar-phi2-fin": "[]!obstacle && <>(g1 && <>(g2 && <>(g3 && <>ginit)))",
    "racecar-phi2-inf": "[]!obstacle && []<>(g1 && <>(g2 && <>g3))",
    "quad-phi1-fin": "[]!obstacle && <>g1 && <>g2 && <>g3",
    "quad-phi1-inf": "[]!obstacle && []<>g1 && []<>g2 && []<>g3",
    "quad-phi3-fin": SEQUENCE_12,
    "quad-phi3-inf": "[]!obstacle && " + " && ".join(f"[]<>g{i}" for i in range(1, 13)),
    "tlrrt-case1": "<>l1 && []<>(l2 && <>l3) && (!l3 U l4) && []!l5",
    "tlrrt-gf3": "[]<>l1 && []<>l2 && []<>l3",
}
WORLDS = {"car": (2, 50, 4), "racecar": (2, 50, 4), "quad": (3, 25, 12), "tlrrt": (2, 2, 6)}
"""Per family: dimension, obstacles, regions (``WORLD_OF`` for an example with other regions)."""
WORLD_OF = {"car-phi3-fin": (2, 50, 12), "car-phi3-inf": (2, 50, 12)}


def load(name: str) -> MissionSpec:
    return load_mission(EXAMPLES / f"{name}.yaml")


def test_every_example_file_is_listed() -> None:
    assert sorted(p.stem for p in EXAMPLES.glob("*.yaml")) == sorted(TASKS)
    readme = (EXAMPLES / "README.md").read_text()
    for name in TASKS:
        assert f"`{name}.yaml`" in readme


@pytest.mark.parametrize("name", sorted(TASKS))
def test_example_loads_with_its_task(name: str) -> None:
    spec = load(name)
    assert spec.name == name
    assert parse(spec.task) == parse(TASKS[name])
    dim, obstacles, regions = WORLD_OF.get(name) or WORLDS[name.split("-")[0]]
    world = spec.build_world()
    assert (world.dim, len(world.obstacles), len(world.region_names)) == (dim, obstacles, regions)
    if name in ("car-phi3-fin", "car-phi3-inf"):  # the car world's boxes, 12 goals of its own
        assert spec.world.obstacles == load("car-phi2-fin").world.obstacles
        assert spec.world.regions == load("car-phi3-fin").world.regions
    if name == "racecar-phi2-inf":  # the car's patrol, driven by the racecar
        assert spec.world == load("car-phi2-inf").world
        assert spec.robot == load("racecar-phi2-fin").robot
        assert spec.planner == load("racecar-phi2-fin").planner
    assert atoms(parse(spec.task)) - {"obstacle"} <= set(world.region_names)


@pytest.mark.parametrize("name", ["tlrrt-case1", "tlrrt-gf3"])
def test_shared_benchmarks_load_and_match_the_copies(name: str) -> None:
    shared = SHARED / f"{name}.yaml"
    if not shared.exists():
        pytest.skip(f"{shared} is not on this machine")
    assert load_mission(shared) == load(name)
    assert shared.read_text() == (EXAMPLES / f"{name}.yaml").read_text()


def reachable_goals(spec: MissionSpec, cell: float) -> dict[str, bool]:
    """Which goals a grid flood fill from the start reaches at the robot's radius."""
    world = spec.build_world()
    axes = [np.arange(lo + cell / 2, hi, cell) for lo, hi in world.bounds]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    points = grid.reshape(-1, world.dim)
    free = ~world.in_collision(points, clearance=spec.robot.radius)
    components, _ = ndimage.label(free.reshape(grid.shape[:-1]))
    start = spec.robot.position()
    index = tuple(((start - world.bounds[:, 0]) / cell).astype(int))
    mine = components.reshape(-1) == components[index]
    assert components[index] > 0, "the start cell is not free"
    labels = world.label_matrix(points)
    return {name: bool(np.any(labels[:, j] & mine)) for j, name in enumerate(world.region_names)}


@pytest.mark.parametrize(
    ("name", "cell"), [("car-phi2-fin", 0.05), ("car-phi3-fin", 0.05), ("quad-phi3-inf", 0.1)]
)
def test_every_goal_is_reachable(name: str, cell: float) -> None:
    reached = reachable_goals(load(name), cell)
    assert all(reached.values()), reached
