"""Trimming: a Büchi automaton keeps only the states that can take part in an accepting run."""

from __future__ import annotations

from collections.abc import Iterator

from planner.ltl.gba import RawBuchi
from planner.ltl.guard import Cube


def trim(ba: RawBuchi) -> RawBuchi:
    """Keep the states reachable from the initial state that can reach an accepting cycle.

    The initial state is always kept, possibly without transitions (empty language).
    Surviving states are renumbered in breadth-first order from the initial state.
    """
    succ = [[t for t, cs in ba.edges.get(p, {}).items() if cs] for p in range(ba.num_states)]
    useful = _useful(ba.initial, succ, ba.accepting)
    useful[ba.initial] = True
    order = [p for p in _bfs_order(ba.initial, succ) if useful[p]]
    new_id = [-1] * ba.num_states
    for i, p in enumerate(order):
        new_id[p] = i
    edges: dict[int, dict[int, list[Cube]]] = {}
    for p in order:
        edges[new_id[p]] = {
            new_id[t]: cs for t, cs in ba.edges.get(p, {}).items() if useful[t] and cs
        }
    accepting = {new_id[p] for p in ba.accepting if new_id[p] >= 0}
    names = [ba.names[p] for p in order]
    return RawBuchi(0, accepting, edges, names)


def _useful(start: int, succ: list[list[int]], accepting: set[int]) -> list[bool]:
    """Which states ``start`` reaches that can reach an accepting state on a cycle.

    Tarjan's strongly connected components, iteratively: a component is complete only
    after every component it reaches, so it is useful when it has a cycle through an
    accepting state or an edge into a useful component.
    """
    n = len(succ)
    index = [-1] * n
    low = [0] * n
    on_stack = [False] * n
    useful = [False] * n
    leads_on = [False] * n  # an edge into a complete useful component
    stack: list[int] = []
    index[start] = low[start] = 0
    count = 1
    stack.append(start)
    on_stack[start] = True
    work: list[tuple[int, Iterator[int]]] = [(start, iter(succ[start]))]
    while work:
        node, children = work[-1]
        for child in children:
            if index[child] < 0:
                index[child] = low[child] = count
                count += 1
                stack.append(child)
                on_stack[child] = True
                work.append((child, iter(succ[child])))
                break
            if on_stack[child]:
                if index[child] < low[node]:
                    low[node] = index[child]
            elif useful[child]:
                leads_on[node] = True
        else:
            work.pop()
            if low[node] == index[node]:
                at = len(stack) - 1
                while stack[at] != node:
                    at -= 1
                component = stack[at:]
                del stack[at:]
                cyclic = len(component) > 1 or node in succ[node]
                good = any(leads_on[q] for q in component) or (
                    cyclic and any(q in accepting for q in component)
                )
                for q in component:
                    on_stack[q] = False
                    useful[q] = good
            if work:
                parent = work[-1][0]
                if on_stack[node]:
                    if low[node] < low[parent]:
                        low[parent] = low[node]
                elif useful[node]:
                    leads_on[parent] = True
    return useful


def _bfs_order(start: int, succ: list[list[int]]) -> list[int]:
    order = [start]
    seen = [False] * len(succ)
    seen[start] = True
    for p in order:
        for t in sorted(succ[p]):
            if not seen[t]:
                seen[t] = True
                order.append(t)
    return order
