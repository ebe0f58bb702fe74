"""Direct simulation of a Büchi automaton over few atoms, as bit arrays.

``q`` simulates ``p`` when ``q`` accepts whenever ``p`` does and, for every transition
``p -w-> t``, ``q`` has a transition ``q -w-> q'`` with ``q'`` simulating ``t``. With ``m``
atoms the letters ``w`` are ``2^m`` bits, packed in 64-bit words. ``answer[t, q]`` holds
the letters on which ``q`` reaches a simulator of ``t``; ``q`` answers ``p`` when each edge
``p -> t`` has its letters among ``answer[t, q]``. The greatest fixpoint is reached in
rounds that recompute only what the states whose simulators shrank can change:
``answer[t]`` for those ``t``, then the edges into them, then their sources. States with the
same simulators have the same ``answer`` row, and edges with the same letters into such
states the same verdicts: each round computes every distinct one once, as array
operations over all states at once.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from planner.ltl.gba import RawBuchi
from planner.ltl.letters import LetterSets

CHUNK_CELLS = 1 << 22
"""Largest intermediate array (elements) of one vectorised step: bounds the memory."""

Ints = NDArray[np.int64]
Words = NDArray[np.uint64]
Bools = NDArray[np.bool_]


def letter_words(atoms: int) -> int:
    """64-bit words of a letter set over ``atoms`` atoms (``2^atoms`` letters)."""
    return max(1, (1 << atoms) // 64)


class _Edges:
    """The automaton's edges sorted by source, one per (source, target) with its letters."""

    def __init__(self, ba: RawBuchi, atom_names: list[str]) -> None:
        sets = LetterSets(atom_names)
        self.words = letter_words(len(atom_names))
        mask = (1 << 64) - 1
        rows = sorted(
            (p, t, sets.of_cubes(cubes))
            for p, out in ba.edges.items()
            for t, cubes in out.items()
            if cubes
        )
        rows = [row for row in rows if row[2]]
        n = ba.num_states
        self.sources: Ints = np.array([p for p, _, _ in rows], dtype=np.int64)
        self.targets: Ints = np.array([t for _, t, _ in rows], dtype=np.int64)
        letters = [[w >> (64 * k) & mask for k in range(self.words)] for _, _, w in rows]
        labels = np.array(letters, dtype=np.uint64).reshape(len(rows), self.words)
        self.labels, self.label_id = np.unique(labels, axis=0, return_inverse=True)
        self.label_id = self.label_id.reshape(-1)
        self.starts = np.searchsorted(self.sources, np.arange(n + 1))
        self.with_edges: Ints = np.flatnonzero(np.diff(self.starts) > 0)
        self.in_order: Ints = np.argsort(self.targets, kind="stable")
        self.in_starts = np.searchsorted(self.targets[self.in_order], np.arange(n + 1))


def letter_simulation(ba: RawBuchi, atom_names: list[str]) -> Bools:
    """``sim[p, q]``: ``q`` directly simulates ``p`` (``atom_names``: at most
    :data:`~planner.ltl.letters.MAX_ATOMS`, every atom of the guards)."""
    n = ba.num_states
    edges = _Edges(ba, atom_names)
    accepting = np.zeros(n, dtype=bool)
    accepting[sorted(ba.accepting)] = True
    sim: Bools = ~accepting[:, None] | accepting[None, :]
    np.fill_diagonal(sim, True)

    answer = np.empty((n, n, edges.words), dtype=np.uint64)
    edge_ok = np.ones((len(edges.sources), n), dtype=bool)
    changed: Ints = np.arange(n)
    while changed.size:
        _update_answers(answer, sim, changed, edges)
        into = np.flatnonzero(np.isin(edges.targets, changed))
        _update_edges(edge_ok, answer, sim, into, edges)
        touched = np.unique(edges.sources[into])
        holds = np.ones((len(touched), n), dtype=bool)
        for i, p in enumerate(touched):
            holds[i] = edge_ok[edges.starts[p] : edges.starts[p + 1]].all(axis=0)
        shrinks = (sim[touched] & ~holds).any(axis=1)
        changed = touched[shrinks]
        sim[changed] &= holds[shrinks]
    return sim


def _distinct_rows(rows: Bools) -> tuple[Bools, Ints]:
    """The distinct rows of a boolean matrix and, for each row, the index of its copy."""
    index: dict[bytes, int] = {}
    copy_of = np.array(
        [index.setdefault(row.tobytes(), len(index)) for row in np.packbits(rows, axis=1)],
        dtype=np.int64,
    )
    first = np.zeros(len(index), dtype=np.int64)
    first[copy_of[::-1]] = np.arange(len(rows))[::-1]
    return rows[first], copy_of


def _update_answers(answer: Words, sim: Bools, changed: Ints, edges: _Edges) -> None:
    """``answer[t, q]`` for each ``t`` in ``changed`` and every ``q``: the letters of the
    edges ``q -> q'`` into simulators ``q'`` of ``t``, found from the simulators' side."""
    rows, copy_of = _distinct_rows(sim[changed])
    block = np.zeros((len(rows), answer.shape[1], edges.words), dtype=np.uint64)
    in_degree = np.diff(edges.in_starts)
    work = np.cumsum(rows.astype(np.int64) @ in_degree)  # edges into simulators, per row
    bounds = np.searchsorted(work, np.arange(CHUNK_CELLS, work[-1], CHUNK_CELLS), side="right")
    for lo, hi in zip([0, *bounds], [*bounds, len(rows)], strict=True):
        row, simulator = np.nonzero(rows[lo:hi])
        counts = in_degree[simulator]
        pair = np.repeat(np.arange(len(row)), counts)
        offset = np.arange(len(pair)) - np.repeat(np.cumsum(counts) - counts, counts)
        into = edges.in_order[edges.in_starts[simulator][pair] + offset]
        letters = edges.labels[edges.label_id[into]]
        np.bitwise_or.at(block, (row[pair] + lo, edges.sources[into]), letters)
    if len(changed) == len(answer):  # the first round: every state, in order
        np.take(block, copy_of, axis=0, out=answer)
    else:
        answer[changed] = block[copy_of]


def _update_edges(edge_ok: Bools, answer: Words, sim: Bools, into: Ints, edges: _Edges) -> None:
    """``edge_ok[e, q]``: ``q`` answers edge ``e`` (one of ``into``) on all its letters."""
    targets = edges.targets[into]
    _, row_class = _distinct_rows(sim[targets])
    keys = edges.label_id[into] * (row_class.max(initial=0) + 1) + row_class
    unique_keys, first, verdict_of = np.unique(keys, return_index=True, return_inverse=True)
    n, words = answer.shape[1], edges.words
    verdicts = np.empty((len(unique_keys), n), dtype=bool)
    step = max(1, CHUNK_CELLS // max(1, n * words))
    for lo in range(0, len(unique_keys), step):
        chosen = first[lo : lo + step]
        letters = edges.labels[edges.label_id[into[chosen]]]
        missing = letters[:, None, :] & ~answer[targets[chosen]]
        verdicts[lo : lo + step] = ~missing.any(axis=2)
    edge_ok[into] = verdicts[verdict_of.reshape(-1)]
