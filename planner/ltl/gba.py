"""From a VWAA to a Büchi automaton through a symbolic generalized Büchi automaton.

Gastin and Oddoux build the GBA whose states are sets ``e`` of VWAA states; a GBA
transition picks one VWAA transition per state of ``e`` and conjoins them. With one
acceptance set per final VWAA state ``f``, a transition is in the set of ``f`` unless it
keeps ``f`` pending: ``f`` is in the target and was either newly created or stayed by an
unmarked transition. The degeneralized Büchi automaton has states ``(e, level)``; level
``j`` has seen the acceptance sets ``1..j`` of the current round and level ``r`` is
accepting.

The GBA is never materialised: a conjunction of k ``G F`` formulas has 2^k GBA
transitions per state. Instead, for each Büchi state ``(e, level)`` a dynamic program
walks the states of ``e`` in the order of their acceptance sets and merges partial
products that agree on (successor set so far, first acceptance set missed so far). The
guards of merged partial products are unions of cubes, kept irredundant, so a cube like
``g1 & g2`` absorbs the ``g1 & g2 & g3`` of a transition that also satisfies ``g3``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from planner.errors import AutomatonTooLargeError
from planner.ltl.guard import Cube
from planner.ltl.masks import Mask, add_mask, masks_cover
from planner.ltl.vwaa import Vwaa

BaState = tuple[frozenset[int], int]


@dataclass
class RawBuchi:
    """A Büchi automaton under construction: ``edges[source][target]`` lists cubes."""

    initial: int
    accepting: set[int]
    edges: dict[int, dict[int, list[Cube]]]
    names: list[str] = field(default_factory=list)

    @property
    def num_states(self) -> int:
        """Number of states."""
        return len(self.names)


def add_cube(cubes: list[Cube], cube: Cube) -> None:
    """Add ``cube`` to the disjunction ``cubes``, keeping no cube that implies another."""
    for other in cubes:
        if cube.implies(other):
            return
    cubes[:] = [c for c in cubes if not c.implies(cube)]
    cubes.append(cube)


def _negated_literal(cube: Cube) -> Cube:
    """The cube of the negation of a one-literal cube."""
    ((name, positive),) = [(a, True) for a in cube.pos] + [(a, False) for a in cube.neg]
    return Cube.literal(name, not positive)


class Degeneralizer:
    """Explores the degeneralized Büchi automaton of a VWAA from its initial states."""

    def __init__(self, vwaa: Vwaa, max_states: int | None = None) -> None:
        self.vwaa = vwaa
        self.max_states = max_states
        """Raise ``AutomatonTooLargeError`` once the automaton, or the successors of one state,
        outgrow this many states (None: no budget)."""
        self.r = len(vwaa.finals)
        self.acc_index = {f: i + 1 for i, f in enumerate(vwaa.finals)}
        self._atom_bits: dict[str, int] = {}
        self._move_bits: dict[int, list[tuple[bool, int, int, int, bool]]] = {}
        self._giving_way: dict[tuple[int, int], Cube] | None = None
        self._states_from_bits: dict[int, frozenset[int]] = {}
        self._cube_of: dict[Mask, Cube] = {}
        self._state_names: dict[int, str] = {}
        self._ranks_from: dict[int, dict[int, int]] = {}
        self.one_level_per_set = True
        """After ``build``: whether every GBA state ``e`` was reached at one level only, so
        the degeneralization added no copies (another order of the acceptance sets reaches
        at least the same sets ``e``)."""

    def successors(self, e: frozenset[int], level: int) -> dict[BaState, list[Cube]]:
        """The outgoing transitions of Büchi state ``(e, level)``, by target state."""
        start = level if level < self.r else 0
        none_missed = self.r - start

        ranks = self._ranks(start)
        ordered = sorted(e, key=lambda q: (q in ranks, ranks.get(q, 0), q))
        partial: dict[tuple[int, int], list[Mask]] = {(0, none_missed): [(0, 0)]}
        for q in ordered:
            q_rank = ranks.get(q)
            moves = self._moves(q)
            grown: dict[tuple[int, int], list[Mask]] = {}
            for (target_bits, missed), masks in partial.items():
                for marked, move_targets, move_pos, move_neg, gives_way in moves:
                    if gives_way and (q_rank is None or missed < q_rank):
                        continue  # staying misses nothing more: it simulates leaving
                    new_missed = missed
                    if q_rank is not None and not marked and q_rank < missed:
                        new_missed = q_rank
                    key = (target_bits | move_targets, new_missed)
                    for pos, neg in masks:
                        pos |= move_pos
                        neg |= move_neg
                        if not pos & neg:
                            bucket = grown.get(key)
                            if bucket is None:
                                grown[key] = [(pos, neg)]
                            else:
                                add_mask(bucket, pos, neg)
            partial = grown
            self._check_budget(len(partial))
        out: dict[BaState, list[Mask]] = {}
        for (target_bits, missed), masks in partial.items():
            states = self._states_of(target_bits)
            for f in states - e:
                f_rank = ranks.get(f)
                if f_rank is not None and f_rank < missed:
                    missed = f_rank
            target = (states, start + missed)
            if target not in out:
                out[target] = masks
                continue
            for pos, neg in masks:
                add_mask(out[target], pos, neg)
        pruned = self._prune_dominated(out)
        return {key: self._cubes(masks) for key, masks in pruned.items()}

    def _ranks(self, start: int) -> dict[int, int]:
        """Each final state's rank: how many acceptance sets after ``start``'s its set comes."""
        ranks = self._ranks_from.get(start)
        if ranks is None:
            ranks = self._ranks_from[start] = {
                f: index - start - 1 for f, index in self.acc_index.items() if index > start
            }
        return ranks

    def _moves(self, q: int) -> list[tuple[bool, int, int, int, bool]]:
        """``q``'s moves as (marked, targets as bits, the cube's masks, whether it gives way
        to a state that ``q`` simulates; see :meth:`_gives_way`)."""
        moves = self._move_bits.get(q)
        if moves is None:
            giving_way = self._gives_way()
            moves = self._move_bits[q] = [
                (
                    move.marked,
                    sum(1 << t for t in move.targets),
                    *self._mask(giving_way.get((q, i), move.cube)),
                    (q, i) in giving_way,
                )
                for i, move in enumerate(self.vwaa.moves[q])
            ]
        return moves

    def _gives_way(self) -> dict[tuple[int, int], Cube]:
        """The moves ``(x, i)`` of final states ``x`` that go to one state ``y`` whose every
        move ``x`` also has, leaving ``x`` (the same targets, a weaker cube), when ``x`` may
        also stay unmarked on any letter (``G F a | F G b`` going to ``G b``), each with the
        cube it is built with.

        Staying then simulates going: ``x`` in place of ``y`` answers every move of ``y``
        with its own and meets its acceptance set doing so. Where staying unmarked misses no
        acceptance set earlier than one the transition misses anyway, it reaches the same
        level and the transition that goes is a little brother, not built. Where ``x`` also
        stays marked on a literal (``a`` of ``G F a``), staying is as good on the letters of
        that literal, and the move is built on the others only (``b & !a``).
        """
        if self._giving_way is None:
            moves = self.vwaa.moves
            finals = set(self.vwaa.finals)
            self._giving_way = {}
            for x in self.vwaa.finals:
                waits = any(
                    not m.marked and m.targets == {x} and m.cube == Cube.TRUE for m in moves[x]
                )
                leaving = [m for m in moves[x] if x not in m.targets]
                recurring = [
                    _negated_literal(m.cube)
                    for m in moves[x]
                    if m.marked and m.targets == {x} and len(m.cube.pos) + len(m.cube.neg) == 1
                ]
                for i, move in enumerate(moves[x]):
                    if not waits or x in move.targets or len(move.targets) != 1:
                        continue
                    (y,) = move.targets
                    if y not in finals and all(
                        any(m.targets == n.targets and m.cube.implies(n.cube) for n in leaving)
                        for m in moves[y]
                    ):
                        cube = move.cube
                        for other_letters in recurring:
                            cube = cube.conjoin(other_letters) or cube
                        self._giving_way[(x, i)] = cube
        return self._giving_way

    def _states_of(self, bits: int) -> frozenset[int]:
        states = self._states_from_bits.get(bits)
        if states is None:
            states = self._states_from_bits[bits] = frozenset(
                q for q in range(bits.bit_length()) if bits >> q & 1
            )
        return states

    def _mask(self, cube: Cube) -> Mask:
        bits = self._atom_bits
        pos = neg = 0
        for atom in cube.pos:
            pos |= bits.setdefault(atom, 1 << len(bits))
        for atom in cube.neg:
            neg |= bits.setdefault(atom, 1 << len(bits))
        return pos, neg

    def _cubes(self, masks: list[Mask]) -> list[Cube]:
        out = []
        for mask in masks:
            cube = self._cube_of.get(mask)
            if cube is None:
                names = {bit: atom for atom, bit in self._atom_bits.items()}
                pos, neg = mask
                cube = self._cube_of[mask] = Cube(
                    frozenset(a for b, a in names.items() if b & pos),
                    frozenset(a for b, a in names.items() if b & neg),
                )
            out.append(cube)
        return out

    def _prune_dominated(self, out: dict[BaState, list[Mask]]) -> dict[BaState, list[Mask]]:
        """Drop cubes whose letters also lead to a state that directly simulates the target.

        ``(e', j')`` simulates ``(e, j)`` when ``e'`` drops only obligations from which no
        final state is reachable (so no acceptance set can get worse) and ``j <= j' < r``
        or ``j = j' = r``. Removing such "little brothers" preserves the language.
        """
        free = self.vwaa.final_free
        # ``other <= targets`` and ``targets - other <= free`` imply that the two agree outside
        # ``free``: only states of the same group can simulate each other (for a conjunction
        # of k eventualities, 2^k successors in 2^k groups instead of 4^k pairs).
        group_of = {key: key[0] - free for key in out}
        groups: dict[frozenset[int], list[BaState]] = {}
        for key, name in group_of.items():
            groups.setdefault(name, []).append(key)
        pruned: dict[BaState, list[Mask]] = {}
        for key, masks in out.items():
            members = groups[group_of[key]]
            if len(members) == 1:
                pruned[key] = masks
                continue
            targets, level = key
            better = [
                m
                for other, other_level in members
                if (other, other_level) != key
                and other <= targets
                and (level <= other_level < self.r or level == other_level == self.r)
                for m in out[(other, other_level)]
            ]
            kept = [m for m in masks if not masks_cover(better, *m)] if better else masks
            if kept:
                pruned[key] = kept
        return pruned

    def build(self) -> RawBuchi:
        """The reachable part of the degeneralized automaton."""
        ids: dict[BaState, int] = {}
        names: list[str] = []
        todo: list[BaState] = []

        def state_id(s: BaState) -> int:
            if s not in ids:
                self._check_budget(len(names) + 1)
                ids[s] = len(names)
                names.append(self._name(s))
                todo.append(s)
            return ids[s]

        edges: dict[int, dict[int, list[Cube]]] = {}
        initial_sets = self.vwaa.initial
        if len(initial_sets) == 1:
            initial = state_id((initial_sets[0], 0))
        else:
            initial = len(names)
            names.append("init")
            merged: dict[int, list[Cube]] = {}
            for e in initial_sets:
                for target, cubes in self.successors(e, 0).items():
                    bucket = merged.setdefault(state_id(target), [])
                    for cube in cubes:
                        add_cube(bucket, cube)
            edges[initial] = merged
        while todo:
            s = todo.pop()
            out: dict[int, list[Cube]] = {}
            for target, cubes in self.successors(*s).items():
                out[state_id(target)] = cubes
            edges[ids[s]] = out
        accepting = {i for s, i in ids.items() if s[1] == self.r}
        self.one_level_per_set = len({e for e, _ in ids}) == len(ids)
        if self.r == 0 and len(initial_sets) != 1:
            accepting.add(initial)
        return RawBuchi(initial, accepting, edges, names)

    def _check_budget(self, states: int) -> None:
        if self.max_states is not None and states > self.max_states:
            raise AutomatonTooLargeError(self.max_states)

    def _name(self, s: BaState) -> str:
        e, level = s
        names = self._state_names
        for q in e - names.keys():
            names[q] = self.vwaa.name(q)
        body = " & ".join(sorted(names[q] for q in e)) or "true"
        return f"{{{body}}}/{level}"
