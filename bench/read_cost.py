"""What one read (and one submission) of a mission costs the API, for code trees side by side
in one run.

``.venv/bin/python bench/read_cost.py --code OLD_CHECKOUT .`` starts ``ltlnav serve
--no-worker`` (embedded defaults, fresh data; with ``--postgres SERVER_URL`` a fresh
PostgreSQL database) once per tree and round, alternating the trees,
with ``PYTHONPATH`` set to the tree, submits 20 missions (queued: no worker runs) and measures:

- ``--reads`` sequential ``GET /missions/{id}``: the client's median, the API's own median
  (``Server-Timing``) and the API process's CPU time per read (from ``/proc``);
- ``--bursts`` bursts of 20 concurrent reads (what 50 pollers re-aligned by a stall send):
  median, p99 and worst latency;
- ``--posts`` sequential ``POST /missions`` of a whole document: the API's CPU time per
  submission.

The machine's other load counts in every figure: run it on an idle machine.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.service import (  # noqa: E402
    EXAMPLE,
    api_server,
    bench_mission,
    phase_layout,
    stop_on_sigterm,
)
from bench.service_load import cpu_seconds, server_seconds  # noqa: E402

MISSIONS = 20
BURST = 20


@dataclass
class Figures:
    """One tree's samples, over every round."""

    client: list[float] = field(default_factory=list)
    server: list[float] = field(default_factory=list)
    cpu_per_read: list[float] = field(default_factory=list)
    burst: list[float] = field(default_factory=list)
    cpu_per_post: list[float] = field(default_factory=list)


def sequential(url: str, pid: int, ids: list[str], reads: int, into: Figures) -> None:
    with httpx.Client(base_url=url) as client:
        for index in range(200):
            client.get(f"/missions/{ids[index % MISSIONS]}")
        cpu_before = cpu_seconds(pid)
        for index in range(reads):
            began = time.perf_counter()
            response = client.get(f"/missions/{ids[index % MISSIONS]}")
            into.client.append(time.perf_counter() - began)
            response.raise_for_status()
            into.server.append(server_seconds(response))
        into.cpu_per_read.append((cpu_seconds(pid) - cpu_before) / reads)


async def bursts(url: str, ids: list[str], count: int, into: Figures) -> None:
    limits = httpx.Limits(max_connections=BURST)
    async with httpx.AsyncClient(base_url=url, limits=limits) as client:

        async def read(index: int) -> float:
            began = time.perf_counter()
            response = await client.get(f"/missions/{ids[index % MISSIONS]}")
            response.raise_for_status()
            return time.perf_counter() - began

        for _ in range(count):
            into.burst.extend(await asyncio.gather(*(read(i) for i in range(BURST))))
            await asyncio.sleep(0.1)


def measure(
    tree: Path, reads: int, burst_count: int, posts: int, into: Figures, postgres: str | None
) -> None:
    parent = Path(tempfile.mkdtemp(prefix="ltlnav-read-cost-"))
    os.environ["PYTHONPATH"] = str(tree)
    started: list[Any] = []
    options = argparse.Namespace(timesteps=3000, redis=None, postgres=postgres)
    with (
        phase_layout(parent, "reads", options) as layout,
        api_server(layout, started) as url,
    ):
        with httpx.Client(base_url=url) as client:
            ids = [
                client.post("/missions", json={"example": EXAMPLE}).json()["id"]
                for _ in range(MISSIONS)
            ]
        sequential(url, started[0].pid, ids, reads, into)
        asyncio.run(bursts(url, ids, burst_count, into))
        submissions(url, started[0].pid, posts, into)


def submissions(url: str, pid: int, posts: int, into: Figures) -> None:
    """``posts`` sequential ``POST /missions`` of a whole document (validated and stored; no
    worker runs): the API's CPU time per submission."""
    if posts <= 0:
        return
    document = bench_mission(3000)
    with httpx.Client(base_url=url, timeout=30) as client:
        cpu_before = cpu_seconds(pid)
        for _ in range(posts):
            client.post("/missions", json=document).raise_for_status()
        into.cpu_per_post.append((cpu_seconds(pid) - cpu_before) / posts)


def ms(seconds: float) -> str:
    return f"{1000 * seconds:.1f}"


def quantile(samples: list[float], q: float) -> float:
    ordered = sorted(samples)
    return ordered[round(q * (len(ordered) - 1))]


def main() -> None:
    stop_on_sigterm()
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--code", type=Path, nargs="+", required=True, help="code trees")
    parser.add_argument("--rounds", type=int, default=2, help="servers per tree, alternating")
    parser.add_argument("--reads", type=int, default=2000, help="sequential reads per round")
    parser.add_argument("--bursts", type=int, default=40, help="bursts of 20 per round")
    parser.add_argument("--posts", type=int, default=200, help="sequential submissions per round")
    parser.add_argument(
        "--postgres", help="PostgreSQL server URL (no database name): state there, not SQLite"
    )
    args = parser.parse_args()
    figures = {tree: Figures() for tree in args.code}
    for _ in range(args.rounds):
        for tree in args.code:
            measure(
                tree.resolve(), args.reads, args.bursts, args.posts, figures[tree], args.postgres
            )
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the end")
    print(
        "| code | client median | API median | API CPU per read | burst median / p99 / max "
        "| API CPU per POST |"
    )
    print("|---|---|---|---|---|---|")
    for tree, found in figures.items():
        burst = "/".join(ms(quantile(found.burst, q)) for q in (0.5, 0.99, 1.0))
        print(
            f"| {tree} | {ms(statistics.median(found.client))} ms "
            f"| {ms(statistics.median(found.server))} ms "
            f"| {ms(statistics.mean(found.cpu_per_read))} ms | {burst} ms "
            f"| {ms(statistics.mean(found.cpu_per_post or [math.nan]))} ms |"
        )


if __name__ == "__main__":
    main()
