"""A racecar mission in a dense forest whose guide the car's own controller fails (issue 17).

The training-speed target for the racecar is measured on a plan where the pursuit feed-forward
alone does not hold every sub-task, so that SAC has to learn. ``mission(seed)`` is a 20 x 20 m
forest of 70 trees (0.3-0.8 m across), a racecar start with a random heading and two goals placed
where a grid search reaches them, and the task ``<>(g1 && <>g2)``. ``main`` tries seeds from
``--first`` on, plans each, runs ``--episodes`` zero-action episodes per sub-task from its real
starts, and writes the first mission with a sub-task under 90 % to ``--out``
(``bench/missions/racecar-dense-forest-SEED.yaml`` by default). ``--size`` draws the forest in
another square (``racecar-dense-forest-SIZEm-SEED``), with as many trees per square metre and
goals at least 6 m apart (scaled down in a smaller square): ``racecar-dense-forest-10m-4.yaml``
is the first 10 m one with a sub-task under 90 % (85 %) and ``racecar-dense-forest-30m-47.yaml``
the first 30 m one (40 %; seeds 0-46 held), on which the rays' range in the robot's terms was
measured (``bench/LEARNING.md``).

``bench/missions/racecar-dense-forest.yaml`` is seed 7's, the first such mission when it was
drawn (85 % from the start in 20 episodes); the racecar's controller, changed since, now holds
it (100 % at step 0, and seeds 0-14 likewise). ``racecar-dense-forest-15.yaml`` is the first
with a sub-task under 90 % for the controller of 01301fc (80 % in 20 episodes): the world the
racecar's speed target was first reported on. ``racecar-dense-forest-38.yaml`` (0 %) and
``-62.yaml`` (80 %), the next two from seeds 16 and 39 on, are tuning worlds
(``bench/LEARNING.md``). With the controller of 76bbd70 no further seed qualifies at 20 m
(63-162), at 30 m (48-97) nor at 40 m (0-49); at 10 m ``racecar-dense-forest-10m-21.yaml`` is
the next one after seed 4 (0 % on sub-task 0; seeds 5-20 held).

Run ``.venv/bin/python bench/dense_forest.py``, then time ``ltlnav train
bench/missions/racecar-dense-forest-SEED.yaml --out DIR --jobs 2``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(Path(__file__).resolve().parent))  # after the packages: bench/planner.py

import numpy as np  # noqa: E402
import yaml  # noqa: E402
from random_worlds import _ball  # noqa: E402
from zero_grid import controller_rates  # noqa: E402

from planner.geometry.world_spec import WorldSpec  # noqa: E402
from planner.search.reachability import unreachable_regions  # noqa: E402
from workers.mission import MissionError  # noqa: E402

SIZE, TREES, RADIUS = 20.0, 70, 0.27


def mission(seed: int, size: float = SIZE) -> dict[str, Any]:
    """The dense-forest racecar mission of ``seed`` in a ``size`` x ``size`` m square (trees as
    dense as in the 20 m one)."""
    rng = np.random.default_rng(seed)
    trees_count = round(TREES * (size / SIZE) ** 2)
    radii = rng.uniform(0.15, 0.4, trees_count)
    centres = rng.uniform(0.0, size, (trees_count, 2))
    trees = [_ball(c, float(r)) for c, r in zip(centres, radii, strict=True)]
    base: dict[str, Any] = {"bounds": [[0.0, size], [0.0, size]], "obstacles": trees}
    world = WorldSpec.model_validate({**base, "regions": {}}).build()
    start = world.sample_free(rng, 1, RADIUS + 0.5)[0]
    regions: dict[str, Any] = {}
    apart = 6.0 * min(1.0, size / SIZE)
    for _ in range(1000):
        centre = world.sample_free(rng, 1, 1.0 + RADIUS)[0]
        placed = [np.array(r["ball"]["center"]) for r in regions.values()]
        if any(np.linalg.norm(centre - p) < apart for p in [start, *placed]):
            continue
        trial = {**regions, f"g{len(regions) + 1}": _ball(centre, 1.0)}
        built = WorldSpec.model_validate({**base, "regions": trial}).build()
        if not unreachable_regions(built, start, RADIUS, list(trial)):
            regions = trial
        if len(regions) == 2:
            break
    else:
        raise ValueError(f"seed {seed}: no two reachable goals fit")
    heading = round(float(rng.uniform(-np.pi, np.pi)), 3)
    name = "racecar-dense-forest" + ("" if size == SIZE else f"-{size:g}m")
    return {
        "name": f"{name}-{seed}",
        "task": "[]!obstacle && <>(g1 && <>g2)",
        "robot": {
            "model": "racecar",
            "start": [*(round(float(v), 3) for v in start), heading],
            "radius": RADIUS,
        },
        "planner": {"seed": 0},
        "world": {**base, "regions": regions},
    }


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--first", type=int, default=0)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--size", type=float, default=SIZE, help="side of the square world, m")
    p.add_argument("--out", type=Path, help="default: bench/missions/<the mission's name>.yaml")
    p.add_argument("--work", type=Path, default=ROOT / "var" / "bench" / "dense_forest")
    args = p.parse_args(argv)
    for seed in range(args.first, args.first + 50):
        try:
            document = mission(seed, args.size)
        except ValueError as error:
            print(error, flush=True)
            continue
        try:
            rates = controller_rates(document, args.episodes, args.work / str(seed))
        except MissionError as error:
            print(f"seed {seed}: no plan ({error})", flush=True)
            continue
        print(f"seed {seed}: controller alone {[f'{100 * r:.0f} %' for r in rates]}", flush=True)
        if min(rates) < 0.9:
            out = args.out or ROOT / "bench" / "missions" / f"{document['name']}.yaml"
            out.write_text(yaml.safe_dump(document, sort_keys=False))
            print(f"written to {out}")
            return
    raise SystemExit("no seed in 50 gives a sub-task the controller fails")


if __name__ == "__main__":
    main()
