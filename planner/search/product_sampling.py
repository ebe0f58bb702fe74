"""Sampling and automaton bookkeeping shared by the TL-RRT* trees.

:class:`Stepper` caches automaton successors by (state, label bitmask): the trees ask the same
question for every neighbour of every sample. :class:`Sampler` draws free points and points of
regions in batches (one world call per batch instead of per sample) and picks the biased
sampling target of TL-RRT*: an automaton transition on a shortest path toward the goal states,
and a point of the region whose label enables it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

import numpy as np

from planner.geometry.labels import LabelOracle
from planner.geometry.world import World
from planner.ltl.automaton import Buchi
from planner.ltl.guard import Cube


class Stepper:
    """Successors of automaton states under bitmask labels, cached."""

    def __init__(self, nba: Buchi, oracle: LabelOracle) -> None:
        self.nba = nba
        self.oracle = oracle
        self._cache: dict[tuple[int, int], tuple[int, ...]] = {}

    def __call__(self, q: int, mask: int) -> tuple[int, ...]:
        key = (q, mask)
        got = self._cache.get(key)
        if got is None:
            got = tuple(sorted(self.nba.successors(q, self.oracle.label(mask))))
            self._cache[key] = got
        return got


class Realisable:
    """The cubes of an automaton that some free point of the world can produce.

    TL-RRT* steers toward and measures distances through these only, so that an unpruned
    automaton (whose cheapest path may need two disjoint regions at once) does not mislead the
    biased sampling.
    """

    def __init__(self, nba: Buchi, world: World, clearance: float) -> None:
        self.nba = nba
        self.cubes: dict[tuple[int, int], list[Cube]] = {}
        for e in nba.edges:
            ok = [c for c in e.guard.sorted_cubes() if world.realisable(c.pos, c.neg, clearance)]
            if ok:
                self.cubes[(e.source, e.target)] = ok
        self.succ: dict[int, list[int]] = {q: [] for q in range(nba.num_states)}
        self.pred: dict[int, list[int]] = {q: [] for q in range(nba.num_states)}
        for src, dst in self.cubes:
            self.succ[src].append(dst)
            self.pred[dst].append(src)

    def distances_to(self, targets: Iterable[int]) -> dict[int, int]:
        """Fewest realisable edges from each state to one of ``targets`` (0 for the targets);
        states that cannot reach them are absent."""
        dist = {q: 0 for q in sorted(set(targets))}
        queue = deque(dist)
        while queue:
            q = queue.popleft()
            for p in self.pred[q]:
                if p not in dist:
                    dist[p] = dist[q] + 1
                    queue.append(p)
        return dist

    def on_cycle(self, q: int) -> bool:
        """Whether ``q`` can return to itself through realisable edges."""
        seen: set[int] = set()
        stack = list(self.succ[q])
        while stack:
            p = stack.pop()
            if p == q:
                return True
            if p not in seen:
                seen.add(p)
                stack.extend(self.succ[p])
        return False

    def acceptance_distances(self) -> dict[int, int]:
        """:meth:`Buchi.distances_to_acceptance` restricted to realisable edges."""
        return self.distances_to(q for q in self.nba.accepting if self.on_cycle(q))

    def advancing_cubes(self, q: int, dist: dict[int, int]) -> list[Cube]:
        """The realisable cubes of the edges leaving ``q`` toward a state one step closer."""
        here = dist.get(q)
        if here is None or here == 0:
            return []
        out: list[Cube] = []
        for dst in self.succ[q]:
            if dst != q and dist.get(dst) == here - 1:
                out.extend(self.cubes[(q, dst)])
        return out


class Sampler:
    """Buffered uniform samples of free space and of regions, and cube-satisfying targets."""

    def __init__(
        self,
        world: World,
        oracle: LabelOracle,
        rng: np.random.Generator,
        clearance: float,
        batch: int = 128,
        bridge_sigma: float = 0.0,
    ) -> None:
        self.world = world
        self.sigma = bridge_sigma
        """Spread of the bridge-test pairs (0: uniform sampling only)."""
        self.bridge_pairs = 4 * batch
        self.oracle = oracle
        self.rng = rng
        self.clearance = clearance
        self.batch = batch
        self._free: list[np.ndarray] = []
        self._region: dict[str, list[np.ndarray]] = {}
        self.empty_regions: set[str] = set()
        """Regions in which repeated sampling found no free point."""

    def free(self) -> np.ndarray:
        """One collision-free point: uniform, or now and then a bridge point (see _bridges)."""
        if not self._free:
            pts = self.world.sample_free(self.rng, self.batch, self.clearance)
            bridges = self._bridges(self.bridge_pairs)
            if len(bridges):
                pts = np.vstack([pts, bridges])
                pts = pts[self.rng.permutation(len(pts))]
            self._free = list(pts)
        return self._free.pop()

    def _bridges(self, n: int) -> np.ndarray:
        """Bridge-test samples (Hsu et al. 2003): midpoints of pairs of nearby points that
        are both in collision while the midpoint is free. They land in doors and gaps between
        obstacles, the narrow passages that uniform samples almost never hit; in open space
        no pair passes, so the uniform distribution is left alone there."""
        if n <= 0 or self.sigma <= 0.0:
            return np.empty((0, self.world.dim))
        d = self.world.dim
        lo = self.world.bounds[:, 0] + self.clearance
        hi = self.world.bounds[:, 1] - self.clearance
        a = self.rng.uniform(lo, hi, size=(n, d))
        b = a + self.rng.normal(scale=self.sigma, size=(n, d))
        inside = np.all((b >= lo) & (b <= hi), axis=1)
        mid = 0.5 * (a + b)
        hit = self.world.in_collision(np.vstack([a, b, mid]), self.clearance)
        ok = inside & hit[:n] & hit[n : 2 * n] & ~hit[2 * n :]
        return np.asarray(mid[ok])

    def in_region(self, label: str) -> np.ndarray | None:
        """One uniform free point of region ``label``, None if it seems to have none."""
        buf = self._region.setdefault(label, [])
        if not buf:
            if label in self.empty_regions:
                return None
            for _ in range(4):
                buf.extend(self.world.sample_region(label, self.rng, self.batch, self.clearance))
                if buf:
                    break
            else:
                self.empty_regions.add(label)
                return None
        return buf.pop()

    def near(self, center: np.ndarray, radius: float) -> np.ndarray:
        """A uniform point of the ball around ``center`` (may be in collision)."""
        d = len(center)
        v = self.rng.normal(size=d)
        v /= max(float(np.linalg.norm(v)), 1e-12)
        return np.asarray(center + v * radius * self.rng.uniform() ** (1.0 / d))

    def satisfying(self, cube: Cube) -> np.ndarray | None:
        """A free point whose label satisfies ``cube`` (inside a region of its positive part),
        None when a few tries find none."""
        pos = sorted(cube.pos & set(self.oracle.names))
        for _ in range(4):
            if pos:
                x = self.in_region(pos[int(self.rng.integers(len(pos)))])
                if x is None:
                    return None
            else:
                x = self.free()
            if cube.holds(self.oracle.label(self.oracle.masks(x[None, :])[0])):
                return x
        return None
