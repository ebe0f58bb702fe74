"""Ablation of the learning levers on the car example's sub-tasks (plain stable-baselines3).

Each named configuration (reward mode and constants, env options, algorithm and its
hyperparameters, planner clearance, leg splitting) is trained on the sub-tasks of
``examples/car-phi2-fin.yaml`` (planned with the mission's seed) for several seeds. During
training a quick evaluation (``--quick-episodes`` rollouts) runs every ``--eval-every`` steps;
the first one at >= 95 % success is recorded and, with ``--stop-at-target`` (default), ends
training like the production early stop. The final model is then evaluated over
``--trials`` rollouts (200, as in the paper) from the sub-task's real start with
``curriculum=0``, no stall termination and deterministic actions. The start is perturbed by
``--eval-noise`` metres and ``--eval-heading`` radians: the dynamics and the deterministic
policy are otherwise noise free, and 200 identical rollouts would measure one trajectory.

At most ``--jobs`` (default 2) training processes run at once, each with one torch thread.
One JSON line per run goes to ``--out``/results.jsonl and a table is printed:
config, sub-task, seed, steps to first >= 95 % quick eval, final success over the trials,
collision rate, training steps per second, wall time.

Its length (one script past 400 lines) is the list of named configurations, each documented
where declared, beside the one runner they share; splitting them would separate a lever from
the runner that measures it.

Run as ``.venv/bin/python bench/learning_levers.py --configs rrt,rrt-cur --subtasks 0
--seeds 0,1 --steps 30000`` (``--list`` names every configuration).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
# Run as a script, bench/ comes first on sys.path and bench/envs.py would shadow the package.
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

MISSION = ROOT / "examples" / "car-phi2-fin.yaml"


@dataclass(frozen=True)
class Config:
    """One named training configuration; every field is a lever of the ablation."""

    name: str
    doc: str
    reward: str = "rrt"
    """Reward mode (``envs.rewards``)."""
    rewards: dict[str, float] = field(default_factory=dict)
    """Reward constants over the mode's defaults."""
    env: dict[str, Any] = field(default_factory=dict)
    """``EnvOptions`` overrides for training (evaluation keeps them but sets ``curriculum=0``,
    ``stall_steps=0`` and its own start noise)."""
    algo: str = "sac"
    """``sac`` or ``td3``."""
    sb3: dict[str, Any] = field(default_factory=dict)
    """Keyword arguments of the SB3 algorithm over the bench defaults (``BASE_SB3``)."""
    extra_clearance: float = 0.0
    """Planner clearance beyond the robot radius (metres): a guide further from obstacles."""
    split: float | None = None
    """Cut each sub-task into legs of at most this many metres, one agent per leg."""


BASE_SB3: dict[str, Any] = {"learning_rate": 3e-4, "batch_size": 256, "gamma": 0.99}
CUR = {"curriculum": 0.7}
FWD = {**CUR, "min_forward": 0.2}
X10 = {"crash": -10.0, "goal": 20.0, "progress": 0.5, "step_cost": 0.01}

CONFIGS: dict[str, Config] = {
    c.name: c
    for c in (
        Config(
            "paper",
            "rrt-paper reward, bare (s_t, i_t) observation",
            "rrt-paper",
            env={"observation": "paper"},
        ),
        Config("paper-guided", "rrt-paper reward, lookahead observation", "rrt-paper"),
        Config("rrt", "scaled rrt reward (default options)"),
        Config(
            "rrt-paperobs", "scaled rrt, bare (s_t, i_t) observation", env={"observation": "paper"}
        ),
        Config("rrt-cur", "rrt + curriculum 0.7", env=CUR),
        Config("rrt-cur5", "rrt + curriculum 0.5", env={"curriculum": 0.5}),
        Config("rrt-cur9", "rrt + curriculum 0.9", env={"curriculum": 0.9}),
        Config("paper-cur", "rrt-paper + curriculum 0.7", "rrt-paper", env=CUR),
        Config(
            "rrt-cur-noise",
            "rrt + curriculum 0.7 + start noise 0.2 m / 0.4 rad",
            env={**CUR, "start_noise": 0.2, "heading_noise": 0.4},
        ),
        Config(
            "rrt-cur-fwd", "rrt + curriculum + min_forward 0.2", env={**CUR, "min_forward": 0.2}
        ),
        Config(
            "rrt-cur-stall",
            "rrt + curriculum + stall 30 steps, penalty -1",
            env={**CUR, "stall_steps": 30, "stall_penalty": -1.0},
        ),
        Config(
            "rrt-cur-nostep", "rrt + curriculum, no step cost", rewards={"step_cost": 0.0}, env=CUR
        ),
        Config("rrt-cur-g98", "rrt + curriculum, gamma 0.98", env=CUR, sb3={"gamma": 0.98}),
        Config(
            "rrt-cur-gs2",
            "rrt + curriculum, 2 gradient steps per env step",
            env=CUR,
            sb3={"gradient_steps": 2},
        ),
        Config(
            "rrt-cur-tf4",
            "rrt + curriculum, train_freq 4 / 4 gradient steps",
            env=CUR,
            sb3={"train_freq": 4, "gradient_steps": 4},
        ),
        Config(
            "rrt-cur-ls5k",
            "rrt + curriculum, learning_starts 5000",
            env=CUR,
            sb3={"learning_starts": 5000},
        ),
        Config(
            "rrt-cur-ent", "rrt + curriculum, fixed ent_coef 0.01", env=CUR, sb3={"ent_coef": 0.01}
        ),
        Config("rrt-cur-td3", "rrt + curriculum, TD3", env=CUR, algo="td3"),
        Config(
            "rrt-cur-clear",
            "rrt + curriculum, guide planned at radius + 0.3 m",
            env=CUR,
            extra_clearance=0.3,
        ),
        Config("rrt-split5", "rrt, legs of at most 5 m", split=5.0),
        Config("rrt-cur-split5", "rrt + curriculum, legs of at most 5 m", env=CUR, split=5.0),
        Config(
            "rrt-cur-prog", "rrt + curriculum, progress 0.1/m", rewards={"progress": 0.1}, env=CUR
        ),
        Config("rrt-fwd", "rrt + min_forward 0.2, no curriculum", env={"min_forward": 0.2}),
        Config("paper-fwd", "rrt-paper + min_forward 0.2", "rrt-paper", env={"min_forward": 0.2}),
        Config("paper-cur-fwd", "rrt-paper + curriculum + min_forward 0.2", "rrt-paper", env=FWD),
        Config(
            "fwd-paperobs",
            "rrt-cur-fwd, bare (s_t, i_t) observation",
            env={**FWD, "observation": "paper"},
        ),
        Config("fwd-clear", "rrt-cur-fwd, guide at radius + 0.3 m", env=FWD, extra_clearance=0.3),
        Config(
            "fwd-noise",
            "rrt-cur-fwd + start noise 0.2 m / 0.4 rad",
            env={**FWD, "start_noise": 0.2, "heading_noise": 0.4},
        ),
        Config(
            "fwd-clear-noise",
            "rrt-cur-fwd, clearance + 0.3, start noise 0.2 m / 0.4 rad",
            env={**FWD, "start_noise": 0.2, "heading_noise": 0.4},
            extra_clearance=0.3,
        ),
        Config(
            "fwd-mf0",
            "rrt + curriculum, min_forward 0 (no reversing, may stop)",
            env={**CUR, "min_forward": 0.0},
        ),
        Config("fwd-mf4", "rrt + curriculum, min_forward 0.4", env={**CUR, "min_forward": 0.4}),
        Config("fwd-nostep", "rrt-cur-fwd, no step cost", rewards={"step_cost": 0.0}, env=FWD),
        Config("fwd-g98", "rrt-cur-fwd, gamma 0.98", env=FWD, sb3={"gamma": 0.98}),
        Config(
            "fwd-tf2",
            "rrt-cur-fwd, one gradient step every 2 env steps",
            env=FWD,
            sb3={"train_freq": 2},
        ),
        Config(
            "fwd-gs2",
            "rrt-cur-fwd, 2 gradient steps per env step",
            env=FWD,
            sb3={"gradient_steps": 2},
        ),
        Config(
            "fwd-ls5k", "rrt-cur-fwd, learning_starts 5000", env=FWD, sb3={"learning_starts": 5000}
        ),
        Config("fwd-ent", "rrt-cur-fwd, fixed ent_coef 0.01", env=FWD, sb3={"ent_coef": 0.01}),
        Config("fwd-td3", "rrt-cur-fwd, TD3", env=FWD, algo="td3"),
        Config("fwd-split5", "rrt-cur-fwd, legs of at most 5 m", env=FWD, split=5.0),
        Config("fwd-rays", "rrt-cur-fwd + 8 rays", env={**FWD, "rays": 8}),
        Config("C-x10-hug", "C-x10 on the guide planned at the robot radius", rewards=X10, env=FWD),
        Config(
            "C-x10-nocur",
            "C-x10 without the curriculum",
            rewards=X10,
            env={"min_forward": 0.2},
            extra_clearance=0.3,
        ),
        Config(
            "C-td3",
            "fwd-clear with TD3 (Gaussian action noise 0.2)",
            env=FWD,
            extra_clearance=0.3,
            algo="td3",
        ),
        Config(
            "C-x10-td3",
            "fwd-clear, rewards x10, TD3 (action noise 0.2)",
            rewards=X10,
            env=FWD,
            extra_clearance=0.3,
            algo="td3",
        ),
        Config(
            "C-x10",
            "fwd-clear, rewards x10 (crash -10, goal 20, 0.5/m, step 0.01)",
            rewards=X10,
            env=FWD,
            extra_clearance=0.3,
        ),
        Config(
            "C-ent",
            "fwd-clear, ent_coef auto from 0.01",
            env=FWD,
            extra_clearance=0.3,
            sb3={"ent_coef": "auto_0.01"},
        ),
        Config(
            "C-x10-ent",
            "fwd-clear, rewards x10, ent_coef auto from 0.01",
            rewards=X10,
            env=FWD,
            extra_clearance=0.3,
            sb3={"ent_coef": "auto_0.01"},
        ),
        Config(
            "paper-C",
            "rrt-paper, lookahead obs, curriculum, min_forward, clearance + 0.3",
            "rrt-paper",
            env=FWD,
            extra_clearance=0.3,
        ),
        Config(
            "x10-clear",
            "rrt x10, guide at radius + 0.3 m (no curriculum, no min_forward)",
            rewards=X10,
            extra_clearance=0.3,
        ),
        Config(
            "x10-clear-cur",
            "rrt x10 + curriculum, guide at radius + 0.3 m",
            rewards=X10,
            env=CUR,
            extra_clearance=0.3,
        ),
        Config("clear", "rrt, guide at radius + 0.3 m", extra_clearance=0.3),
        Config(
            "clear-cur", "rrt + curriculum, guide at radius + 0.3 m", env=CUR, extra_clearance=0.3
        ),
        Config(
            "clear-fwd",
            "rrt + min_forward 0.2, guide at radius + 0.3 m",
            env={"min_forward": 0.2},
            extra_clearance=0.3,
        ),
        Config(
            "paper-clear",
            "rrt-paper reward and observation, guide at radius + 0.3 m",
            "rrt-paper",
            env={"observation": "paper"},
            extra_clearance=0.3,
        ),
        Config(
            "paper-clear-g",
            "rrt-paper reward, lookahead obs, guide at radius + 0.3 m",
            "rrt-paper",
            extra_clearance=0.3,
        ),
        Config(
            "stall",
            "rrt + curriculum + stall 30 steps (penalty -1), no min_forward",
            env={**CUR, "stall_steps": 30, "stall_penalty": -1.0},
        ),
        Config("step01", "rrt + curriculum, step cost 0.01", rewards={"step_cost": 0.01}, env=CUR),
    )
}


@dataclass(frozen=True)
class Job:
    """One training run."""

    config: str
    subtask: int
    seed: int
    steps: int
    eval_every: int
    quick_episodes: int
    trials: int
    stop_at_target: bool
    stop_success: float
    eval_noise: float
    eval_heading: float
    out: str


# ------------------------------------------------------------------------------ setup
def _units(cfg: Config, subtask: int) -> tuple[Any, Any, Any, list[tuple[str, Any]]]:
    """Mission, world, plan and the (label, SubTask) units to train for ``subtask``."""
    from planner.decompose import split_subtask
    from planner.plan import plan_mission
    from workers.mission import load_mission

    mission = load_mission(MISSION)
    world = mission.build_world()
    clearance = mission.robot.radius + cfg.extra_clearance
    plan = plan_mission(
        world, mission.task, mission.robot.position(), clearance, mission.planner_options()
    )
    sub = plan.subtasks[subtask]
    if cfg.split is None:
        return mission, world, plan, [(str(subtask), sub)]
    pieces = split_subtask(sub, cfg.split)
    return mission, world, plan, [(f"{subtask}.{k}", p) for k, p in enumerate(pieces)]


class BatchEval:
    """``n`` copies of a sub-task env stepped in lockstep with one batched policy call a step:
    success, collision and timeout rates of deterministic rollouts from the real start."""

    def __init__(self, make: Any, n: int, noise: float, heading: float) -> None:
        self.envs = [make(noise, heading) for _ in range(n)]

    def run(self, model: Any, seed: int) -> dict[str, float]:
        from workers.policy_act import deterministic_act

        n = len(self.envs)
        act_on = deterministic_act(model.policy)
        obs = np.stack([e.reset(seed=seed + i)[0] for i, e in enumerate(self.envs)])
        live = np.ones(n, dtype=bool)
        success = np.zeros(n, dtype=bool)
        crash = np.zeros(n, dtype=bool)
        steps = np.zeros(n)
        reach = np.zeros(n)
        while live.any():
            idx = np.flatnonzero(live)
            act = act_on(obs[idx])
            for j, k in enumerate(idx):
                o, _, term, trunc, info = self.envs[k].step(act[j])
                obs[k] = o
                if term or trunc:
                    live[k] = False
                    success[k] = bool(info["is_success"])
                    crash[k] = bool(info["collision"])
                    steps[k] = info["steps"]
                    reach[k] = (info["progress_index"] + 1) / self.envs[k].num_balls
        return {
            "success": float(success.mean()),
            "collision": float(crash.mean()),
            "steps_to_goal": float(steps[success].mean()) if success.any() else float("nan"),
            "reach": float(reach.mean()),
        }


def _train_unit(
    job: Job, cfg: Config, label: str, mission: Any, world: Any, plan: Any, sub: Any
) -> dict[str, Any]:
    import torch
    from stable_baselines3 import SAC, TD3
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.noise import NormalActionNoise
    from stable_baselines3.common.vec_env import DummyVecEnv

    from envs.factory import make_env

    torch.set_num_threads(1)

    def train_env() -> Any:
        return make_env(
            mission, sub, cfg.reward, world=world, plan=plan, rewards=cfg.rewards, **cfg.env
        )

    def eval_env(noise: float, heading: float) -> Any:
        opts = {
            **cfg.env,
            "curriculum": 0.0,
            "stall_steps": 0,
            "stall_penalty": None,
            "start_noise": noise,
            "heading_noise": heading,
        }
        return make_env(
            mission, sub, cfg.reward, world=world, plan=plan, rewards=cfg.rewards, **opts
        )

    venv = DummyVecEnv([train_env])
    venv.seed(job.seed)
    kwargs = {**BASE_SB3, **cfg.sb3}
    policy_kwargs = {"net_arch": [64, 64, 64], "activation_fn": torch.nn.ReLU}
    algo = SAC if cfg.algo == "sac" else TD3
    if cfg.algo == "td3":
        kwargs.setdefault("action_noise", NormalActionNoise(np.zeros(2), np.full(2, 0.2)))
    model = algo("MlpPolicy", venv, seed=job.seed, verbose=0, policy_kwargs=policy_kwargs, **kwargs)
    folder = Path(job.out) / f"{cfg.name}-{label}-s{job.seed}"
    model.set_logger(configure(str(folder), ["csv"]))
    quick = BatchEval(eval_env, job.quick_episodes, job.eval_noise, job.eval_heading)
    curve: list[tuple[int, float, float]] = []
    first: list[int] = []
    eval_seconds = [0.0]

    class Probe(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % job.eval_every:
                return True
            t = time.perf_counter()
            r = quick.run(self.model, 10_000 + self.num_timesteps)
            eval_seconds[0] += time.perf_counter() - t
            curve.append((self.num_timesteps, r["success"], r["collision"]))
            print(
                f"  {cfg.name} {label} s{job.seed} @{self.num_timesteps}: "
                f"success {r['success']:.2f} collision {r['collision']:.2f} "
                f"reach {r['reach']:.2f}",
                flush=True,
            )
            if r["success"] >= 0.95 and not first:
                first.append(self.num_timesteps)
            return not (job.stop_at_target and r["success"] >= job.stop_success)

    t0 = time.perf_counter()
    model.learn(job.steps, callback=Probe())
    wall = time.perf_counter() - t0
    model.save(folder / "model.zip")
    final = BatchEval(eval_env, job.trials, job.eval_noise, job.eval_heading).run(model, 0)
    trained = int(model.num_timesteps)
    return {
        "config": cfg.name,
        "subtask": label,
        "seed": job.seed,
        "budget": job.steps,
        "steps": trained,
        "first95": first[0] if first else None,
        "success": final["success"],
        "collision": final["collision"],
        "steps_to_goal": final["steps_to_goal"],
        "reach": final["reach"],
        "wall": wall,
        "sps": trained / max(wall - eval_seconds[0], 1e-9),
        "curve": curve,
        "guide_length": float(np.linalg.norm(np.diff(sub.path, axis=0), axis=1).sum()),
    }


def run_job(job: Job) -> list[dict[str, Any]]:
    """Train and evaluate every unit (leg) of one (config, sub-task, seed)."""
    cfg = CONFIGS[job.config]
    mission, world, plan, units = _units(cfg, job.subtask)
    out = []
    for label, sub in units:
        row = _train_unit(job, cfg, label, mission, world, plan, sub)
        with open(Path(job.out) / "results.jsonl", "a") as fh:
            fh.write(json.dumps(row) + "\n")
        print(_line(row), flush=True)
        out.append(row)
    return out


# ------------------------------------------------------------------------------ report
HEADER = (
    f"{'config':<16} {'sub':>4} {'seed':>4} {'steps':>7} {'first95':>7} {'success':>7} "
    f"{'collide':>7} {'sps':>5} {'wall s':>6}"
)


def _line(r: dict[str, Any]) -> str:
    first = "-" if r["first95"] is None else str(r["first95"])
    return (
        f"{r['config']:<16} {r['subtask']:>4} {r['seed']:>4} {r['steps']:>7} {first:>7} "
        f"{100 * r['success']:>6.1f}% {100 * r['collision']:>6.1f}% {r['sps']:>5.0f} "
        f"{r['wall']:>6.0f}"
    )


def summary(rows: list[dict[str, Any]]) -> str:
    """Per (config, sub-task, budget): median success and collision, median first-95 step."""
    groups: dict[tuple[str, str, int], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["config"], r["subtask"], r["budget"]), []).append(r)
    lines = [
        f"{'config':<16} {'sub':>4} {'budget':>7} {'seeds':>5} {'med succ':>8} "
        f"{'med coll':>8} {'med first95':>11} {'med wall':>8}"
    ]
    for (c, s, b), rs in sorted(groups.items()):
        firsts = [r["first95"] if r["first95"] is not None else float("inf") for r in rs]
        f = statistics.median(firsts)
        lines.append(
            f"{c:<16} {s:>4} {b:>7} {len(rs):>5} "
            f"{100 * statistics.median(r['success'] for r in rs):>7.1f}% "
            f"{100 * statistics.median(r['collision'] for r in rs):>7.1f}% "
            f"{'never' if f == float('inf') else int(f):>11} "
            f"{statistics.median(r['wall'] for r in rs):>8.0f}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Parse the command line, run the jobs (at most ``--jobs`` at once) and print the table."""
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--configs", default="paper,rrt,rrt-cur", help="comma-separated names")
    p.add_argument("--subtasks", default="0,1,2,3", help="comma-separated sub-task indices")
    p.add_argument("--seeds", default="0,1", help="comma-separated seeds")
    p.add_argument(
        "--runs", default="", help="explicit sub-task:seed pairs (e.g. 1:0,2:0,0:1) over the grid"
    )
    p.add_argument("--steps", type=int, default=30_000, help="env-step budget per agent")
    p.add_argument("--eval-every", type=int, default=5_000, help="quick evaluation period")
    p.add_argument("--quick-episodes", type=int, default=20, help="rollouts per quick eval")
    p.add_argument("--trials", type=int, default=200, help="rollouts of the final evaluation")
    p.add_argument(
        "--stop-success", type=float, default=0.95, help="quick-eval success that stops training"
    )
    p.add_argument("--no-stop", action="store_true", help="train the whole budget")
    p.add_argument("--eval-noise", type=float, default=0.2, help="start perturbation (m)")
    p.add_argument("--eval-heading", type=float, default=0.4, help="heading perturbation (rad)")
    p.add_argument("--jobs", type=int, default=2, help="training processes at once")
    p.add_argument("--out", default="/tmp/ltlnav-levers", help="logs and results.jsonl")
    p.add_argument("--list", action="store_true", help="list the configurations and exit")
    p.add_argument("--report", action="store_true", help="summarise --out/results.jsonl")
    a = p.parse_args(argv)
    if a.list:
        for c in CONFIGS.values():
            print(f"{c.name:<16} {c.doc}")
        return
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.report:
        done = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines() if x]
        print(HEADER)
        for r in done:
            print(_line(r))
        print()
        print(summary(done))
        return
    names = [n for n in a.configs.split(",") if n]
    for n in names:
        if n not in CONFIGS:
            p.error(f"unknown config {n!r}; known: {', '.join(CONFIGS)}")
    jobs = [
        Job(
            n,
            int(s),
            int(seed),
            a.steps,
            a.eval_every,
            a.quick_episodes,
            a.trials,
            not a.no_stop,
            a.stop_success,
            a.eval_noise,
            a.eval_heading,
            str(out),
        )
        for seed in a.seeds.split(",")
        for n in names
        for s in a.subtasks.split(",")
    ]
    if a.runs:
        pairs = [tuple(int(v) for v in r.split(":")) for r in a.runs.split(",") if r]
        jobs = [
            Job(
                n,
                sub,
                seed,
                a.steps,
                a.eval_every,
                a.quick_episodes,
                a.trials,
                not a.no_stop,
                a.stop_success,
                a.eval_noise,
                a.eval_heading,
                str(out),
            )
            for n in names
            for sub, seed in pairs
        ]
    print(HEADER, flush=True)
    rows: list[dict[str, Any]] = []
    if a.jobs <= 1:
        for j in jobs:
            rows.extend(run_job(j))
    else:
        ctx = mp.get_context("spawn")
        with ctx.Pool(a.jobs, maxtasksperchild=1) as pool:
            for got in pool.imap_unordered(run_job, jobs):
                rows.extend(got)
    print()
    print(summary(rows))


if __name__ == "__main__":
    main()
