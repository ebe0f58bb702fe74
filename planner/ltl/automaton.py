"""Büchi automata with symbolic guards: the planner's view of an LTL formula.

A run reads one letter (the set of true atomic propositions) per step and is accepting
when it visits an accepting state infinitely often. Exports: HOA v1 (read by Spot, Owl,
ltl3ba), Graphviz DOT and a JSON document.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Callable, Hashable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, NamedTuple, TypeVar

from planner.ltl.guard import Cube, Guard

N = TypeVar("N", bound=Hashable)


class Edge(NamedTuple):
    """A transition ``source --guard--> target``; the guard is never false."""

    source: int
    guard: Guard
    target: int


@dataclass(frozen=True)
class Buchi:
    """A nondeterministic Büchi automaton over the letters ``2^atoms``.

    State ids are indices into ``state_names``. The translator emits at most one edge per
    ordered pair of states; each guard is a DNF whose cubes count as separate transitions,
    as in ltl2ba.
    """

    atoms: tuple[str, ...]
    state_names: tuple[str, ...]
    initial: int
    accepting: frozenset[int]
    edges: tuple[Edge, ...]

    def __post_init__(self) -> None:
        n = len(self.state_names)
        if not 0 <= self.initial < n:
            raise ValueError(f"initial state {self.initial} is not one of the {n} states")
        if any(not 0 <= q < n for q in self.accepting):
            raise ValueError("an accepting state id is out of range")
        known = set(self.atoms)
        checked: set[int] = set()  # guards are shared between edges: each is checked once
        for source, guard, target in self.edges:
            if not (0 <= source < n and 0 <= target < n):
                raise ValueError(f"edge {source}->{target} leaves the {n} states")
            if id(guard) in checked:
                continue
            checked.add(id(guard))
            if guard.is_false:
                raise ValueError(f"edge {source}->{target} has a false guard")
            if not guard.atoms <= known:
                unknown = ", ".join(sorted(guard.atoms - known))
                raise ValueError(f"edge {source}->{target} uses {unknown}, not in atoms")

    @property
    def num_states(self) -> int:
        """Number of states."""
        return len(self.state_names)

    @property
    def num_transitions(self) -> int:
        """Number of transitions counted as ltl2ba does: one per cube of each guard."""
        return sum(len(e.guard.cubes) for e in self.edges)

    @cached_property
    def _out(self) -> tuple[tuple[Edge, ...], ...]:
        out: list[list[Edge]] = [[] for _ in self.state_names]
        for e in self.edges:
            out[e.source].append(e)
        return tuple(tuple(sorted(es, key=lambda e: e.target)) for es in out)

    def out_edges(self, q: int) -> tuple[Edge, ...]:
        """The edges leaving state ``q``, by target id."""
        return self._out[q]

    def successors(self, q: int, label: frozenset[str]) -> frozenset[int]:
        """The states reachable from ``q`` by reading the letter ``label``."""
        return frozenset(e.target for e in self._out[q] if e.guard.holds(label))

    def accepts_lasso(
        self, prefix: Sequence[frozenset[str]], cycle: Sequence[frozenset[str]]
    ) -> bool:
        """Whether the automaton accepts ``prefix · cycle^ω``.

        Searches the product of states and word positions for a reachable accepting node
        that lies on a cycle of the product (such a cycle stays in the word's loop part).
        Linear in the size of the product.
        """
        if not cycle:
            raise ValueError("the cycle of a lasso word must contain at least one letter")
        word = [frozenset(x) for x in prefix] + [frozenset(x) for x in cycle]
        loop = len(prefix)

        def step(node: tuple[int, int]) -> list[tuple[int, int]]:
            q, i = node
            j = i + 1 if i + 1 < len(word) else loop
            return [(p, j) for p in self.successors(q, word[i])]

        return any(q in self.accepting for q, _ in nodes_on_cycles([(self.initial, 0)], step))

    def distances_to_acceptance(self) -> dict[int, int]:
        """Fewest edges from each state to an accepting state that lies on a cycle.

        States that cannot reach such a state are absent. TL-RRT* biases its sampling
        toward transitions that decrease this distance.
        """
        cyclic = nodes_on_cycles(self._ids, lambda q: [e.target for e in self._out[q]])
        targets = sorted(self.accepting & cyclic)
        pred: dict[int, list[int]] = {q: [] for q in self._ids}
        for e in self.edges:
            pred[e.target].append(e.source)
        dist = {q: 0 for q in targets}
        queue = deque(targets)
        while queue:
            q = queue.popleft()
            for p in pred[q]:
                if p not in dist:
                    dist[p] = dist[q] + 1
                    queue.append(p)
        return dist

    @property
    def _ids(self) -> range:
        return range(len(self.state_names))

    def to_hoa(self, name: str = "") -> str:
        """The automaton in HOA v1 with state-based Büchi acceptance, one line per cube."""
        index = {a: i for i, a in enumerate(self.atoms)}
        aps = " ".join(json.dumps(a) for a in self.atoms)
        lines = ["HOA: v1"]
        if name:
            lines.append(f"name: {json.dumps(name)}")
        lines += [
            f"States: {self.num_states}",
            f"Start: {self.initial}",
            f"AP: {len(self.atoms)}" + (f" {aps}" if aps else ""),
            "acc-name: Buchi",
            "Acceptance: 1 Inf(0)",
            "properties: trans-labels explicit-labels state-acc",
            "--BODY--",
        ]
        for q in self._ids:
            mark = " {0}" if q in self.accepting else ""
            lines.append(f"State: {q} {json.dumps(self.state_names[q])}{mark}")
            for e in self._out[q]:
                for cube in e.guard.sorted_cubes():
                    lines.append(f"[{_hoa_label(cube, index)}] {e.target}")
        lines.append("--END--")
        return "\n".join(lines) + "\n"

    def to_dot(self) -> str:
        """The automaton as a Graphviz digraph; accepting states are double circles."""
        lines = ["digraph buchi {", "  rankdir=LR;", "  node [shape=circle, fontsize=10];"]
        lines.append('  __start [shape=point, label=""];')
        for q in self._ids:
            shape = "doublecircle" if q in self.accepting else "circle"
            lines.append(f"  {q} [shape={shape}, label={json.dumps(self.state_names[q])}];")
        lines.append(f"  __start -> {self.initial};")
        for e in self.edges:
            lines.append(f"  {e.source} -> {e.target} [label={json.dumps(str(e.guard))}];")
        lines.append("}")
        return "\n".join(lines) + "\n"

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready document: atoms, states and edges with guards in spin syntax."""
        return {
            "atoms": list(self.atoms),
            "states": [
                {
                    "id": q,
                    "name": self.state_names[q],
                    "accepting": q in self.accepting,
                    "initial": q == self.initial,
                }
                for q in self._ids
            ],
            "edges": [
                {"source": e.source, "target": e.target, "guard": str(e.guard)}
                for e in sorted(self.edges, key=lambda e: (e.source, e.target))
            ],
        }


def _hoa_label(cube: Cube, index: dict[str, int]) -> str:
    if cube.is_true:
        return "t"
    lits = sorted([(index[a], str(index[a])) for a in cube.pos])
    lits += sorted([(index[a], f"!{index[a]}") for a in cube.neg])
    return "&".join(text for _, text in sorted(lits))


def nodes_on_cycles(starts: Iterable[N], step: Callable[[N], Iterable[N]]) -> set[N]:
    """The nodes reachable from ``starts`` that lie on a cycle of the graph ``step``.

    Iterative Tarjan: a node is on a cycle when its strongly connected component has
    more than one node or a self-loop. ``step`` is called once per reachable node.
    """
    index: dict[N, int] = {}
    low: dict[N, int] = {}
    on_stack: set[N] = set()
    stack: list[N] = []
    looped: set[N] = set()
    cyclic: set[N] = set()
    for root in starts:
        if root in index:
            continue
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        work: list[tuple[N, Iterator[N]]] = [(root, iter(step(root)))]
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(step(child))))
                    break
                if child in on_stack:
                    if child == node:
                        looped.add(node)
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1 or node in looped:
                        cyclic.update(component)
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
    return cyclic
