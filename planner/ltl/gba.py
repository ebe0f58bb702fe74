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

from collections.abc import Sequence
from dataclasses import dataclass, field
from operator import itemgetter

from planner.errors import AutomatonTooLargeError
from planner.ltl.guard import Cube
from planner.ltl.masks import CubeOf, Mask, add_mask, masks_cover
from planner.ltl.vwaa import Vwaa

BaState = tuple[frozenset[int], int]
BitState = tuple[int, int]
"""A Büchi state as the degeneralizer keeps it: the bits of its VWAA states, its level."""
MoveBits = list[tuple[bool, int, int, int, bool]]
"""A VWAA state's moves: (marked, targets as bits, the cube's masks, whether it gives way)."""
Step = tuple[int, int, int, int, int]
"""A move in the product: skipped where the rank missed so far is below the first; the
rank missed after it is at most the second; then its targets as bits and its cube's masks."""


@dataclass
class RawBuchi:
    """A Büchi automaton under construction: ``edges[source][target]`` lists cubes.

    A list is not changed once it is in ``edges``: the reductions share lists between the
    automata they return and make new ones where cubes change. ``names`` says what each
    state stands for, for debugging (the degeneralizer's: the bits of its alternating
    automaton's states and its level; see :meth:`Degeneralizer.describe`).
    """

    initial: int
    accepting: set[int]
    edges: dict[int, dict[int, list[Cube]]]
    names: Sequence[object] = field(default_factory=list)

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
        self._move_bits: dict[int, MoveBits] = {}
        self._final_bits = sum(1 << f for f in vwaa.finals)
        self._free_bits = sum(1 << q for q in vwaa.final_free)
        self._giving_way: dict[tuple[int, int], Cube] | None = None
        self._states_from_bits: dict[int, frozenset[int]] = {}
        self._cube_of = CubeOf(self._atom_bits)
        self._ranks_from: dict[int, dict[int, int]] = {}
        self._order_from: dict[int, list[tuple[int, list[Step]]]] = {}
        self._restarts: dict[int, dict[BitState, list[Mask]]] = {}
        self.one_level_per_set = True
        """After ``build``: whether every GBA state ``e`` was reached at one level only, so
        the degeneralization added no copies (another order of the acceptance sets reaches
        at least the same sets ``e``)."""

    def successors(self, e: frozenset[int], level: int) -> dict[BaState, list[Cube]]:
        """The outgoing transitions of Büchi state ``(e, level)``, by target state."""
        out = self._successor_masks(sum(1 << q for q in e), level)
        return {(self._states_of(bits), j): self._cubes(masks) for (bits, j), masks in out.items()}

    def _successor_masks(self, e: int, level: int) -> dict[BitState, list[Mask]]:
        """:meth:`successors` with state sets and cubes as bit masks."""
        start = level if level < self.r else 0
        ranks = self._ranks(start)
        partial: dict[BitState, list[Mask]] = {(0, self.r - start): [(0, 0)]}
        for steps in self._steps(e, start):
            grown: dict[BitState, list[Mask]] = {}
            for (target_bits, missed), masks in partial.items():
                for skip_below, lower_to, move_targets, move_pos, move_neg in steps:
                    if missed < skip_below:
                        continue  # staying misses nothing more: it simulates leaving
                    key = (target_bits | move_targets, lower_to if lower_to < missed else missed)
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
        out: dict[BitState, list[Mask]] = {}
        finals_outside = self._final_bits & ~e
        for (target_bits, missed), masks in partial.items():
            created = target_bits & finals_outside
            while created:
                f = (created & -created).bit_length() - 1
                created &= created - 1
                f_rank = ranks.get(f)
                if f_rank is not None and f_rank < missed:
                    missed = f_rank
            target = (target_bits, start + missed)
            bucket = out.get(target)
            if bucket is None:
                out[target] = masks
                continue
            for pos, neg in masks:
                add_mask(bucket, pos, neg)
        return self._prune_dominated(out)

    def _steps(self, e: int, start: int) -> list[list[Step]]:
        """The moves of the states of ``e`` as :data:`Step` s, state by state in the order of
        their acceptance sets after ``start``'s (the others first)."""
        order = self._order_from.get(start)
        if order is None:
            ranks = self._ranks(start)
            order = self._order_from[start] = [
                (q, self._step_moves(q, ranks.get(q)))
                for q in sorted(self.vwaa.moves, key=lambda q: (q in ranks, ranks.get(q, 0), q))
            ]
        return [steps for q, steps in order if e >> q & 1]

    def _step_moves(self, q: int, rank: int | None) -> list[Step]:
        """``q``'s moves as steps of the product, ``rank`` its rank (None: unranked).

        An unranked state never lowers the level and never takes a move that gives way; a
        ranked one takes such a move only where nothing of a lower rank was missed, and
        lowers the level to its rank when it stays unmarked."""
        never = self.r + 1
        if rank is None:
            return [(-1, never, t, pos, neg) for _, t, pos, neg, way in self._moves(q) if not way]
        return [
            (rank if way else -1, never if marked else rank, t, pos, neg)
            for marked, t, pos, neg, way in self._moves(q)
        ]

    def _ranks(self, start: int) -> dict[int, int]:
        """Each final state's rank: how many acceptance sets after ``start``'s its set comes."""
        ranks = self._ranks_from.get(start)
        if ranks is None:
            ranks = self._ranks_from[start] = {
                f: index - start - 1 for f, index in self.acc_index.items() if index > start
            }
        return ranks

    def _moves(self, q: int) -> MoveBits:
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
        cube_of = self._cube_of
        return [cube_of[mask] for mask in masks]

    def _prune_dominated(self, out: dict[BitState, list[Mask]]) -> dict[BitState, list[Mask]]:
        """Drop cubes whose letters also lead to a state that directly simulates the target
        (in place: ``out`` is returned).

        ``(e', j')`` simulates ``(e, j)`` when ``e'`` drops only obligations from which no
        final state is reachable (so no acceptance set can get worse) and ``j <= j' < r``
        or ``j = j' = r``. Removing such "little brothers" preserves the language.
        """
        kept_bits = ~self._free_bits
        # ``other <= targets`` and ``targets - other <= free`` imply that the two agree outside
        # ``free``: only states of the same group can simulate each other (for a conjunction
        # of k eventualities, 2^k successors in 2^k groups instead of 4^k pairs).
        groups: dict[int, list[BitState]] = {}
        for key in out:
            group = key[0] & kept_bits
            members = groups.get(group)
            if members is None:
                groups[group] = [key]
            else:
                members.append(key)
        kept: dict[BitState, list[Mask]] = {}
        for members in groups.values():
            if len(members) == 1:
                continue
            bits = members[0][0]
            for other in members:
                if other[0] != bits:
                    break
            else:
                self._prune_by_level(out, members, kept)
                continue
            for key in members:
                targets, level = key
                better = [
                    m
                    for other in members
                    if other != key
                    and not other[0] & ~targets
                    and (level <= other[1] < self.r or level == other[1] == self.r)
                    for m in out[other]
                ]
                if better:
                    kept[key] = [m for m in out[key] if not masks_cover(better, *m)]
        for key, masks in kept.items():
            if masks:
                out[key] = masks
            else:
                del out[key]
        return out

    def _prune_by_level(
        self,
        out: dict[BitState, list[Mask]],
        members: list[BitState],
        kept: dict[BitState, list[Mask]],
    ) -> None:
        """:meth:`_prune_dominated` for targets that differ in their level alone: each below
        ``r`` is simulated by those of higher levels below ``r``."""
        better: list[Mask] = []
        for key in sorted(members, key=itemgetter(1), reverse=True):
            if key[1] == self.r:
                continue
            masks = out[key]
            if better and len(masks) > 1:
                kept[key] = [m for m in masks if not masks_cover(better, *m)]
            elif better and masks_cover(better, *masks[0]):
                kept[key] = []  # the usual target, of one cube, covered
            better += masks

    def build(self) -> RawBuchi:
        """The reachable part of the degeneralized automaton."""
        ids: dict[BitState, int] = {}
        names: list[object] = []
        todo: list[BitState] = []

        def state_id(s: BitState) -> int:
            found = ids.get(s)
            if found is None:
                self._check_budget(len(names) + 1)
                found = ids[s] = len(names)
                names.append(s)
                todo.append(s)
            return found

        edges: dict[int, dict[int, list[Cube]]] = {}
        initial_sets = [sum(1 << q for q in e) for e in self.vwaa.initial]
        if len(initial_sets) == 1:
            initial = state_id((initial_sets[0], 0))
        else:
            initial = len(names)
            names.append("init")
            merged: dict[int, list[Cube]] = {}
            for e in initial_sets:
                for target, masks in self._successor_masks(e, 0).items():
                    bucket = merged.setdefault(state_id(target), [])
                    for cube in self._cubes(masks):
                        add_cube(bucket, cube)
            edges[initial] = merged
        cube_of = self._cube_of.__getitem__
        alone: dict[Mask, list[Cube]] = {}  # one list per single cube, shared by its edges
        while todo:
            s = todo.pop()
            row = edges[ids[s]] = {}
            for target, masks in self._build_successors(*s).items():
                if len(masks) == 1:
                    cubes = alone.get(masks[0])
                    if cubes is None:
                        cubes = alone[masks[0]] = [cube_of(masks[0])]
                else:
                    cubes = list(map(cube_of, masks))
                found = ids.get(target)
                row[state_id(target) if found is None else found] = cubes
        accepting = {i for s, i in ids.items() if s[1] == self.r}
        self.one_level_per_set = len({e for e, _ in ids}) == len(ids)
        if self.r == 0 and len(initial_sets) != 1:
            accepting.add(initial)
        return RawBuchi(initial, accepting, edges, names)

    def _build_successors(self, e: int, level: int) -> dict[BitState, list[Mask]]:
        """:meth:`_successor_masks` for :meth:`build`: the accepting level starts the next
        round from level 0's, so a set reached at both gets its successors made once."""
        if 0 < level < self.r or self.r == 0:
            return self._successor_masks(e, level)
        found = self._restarts.pop(e, None)
        if found is None:
            found = self._restarts[e] = self._successor_masks(e, level)
        return found

    def _check_budget(self, states: int) -> None:
        if self.max_states is not None and states > self.max_states:
            raise AutomatonTooLargeError(self.max_states)

    def describe(self, state: BitState) -> str:
        """A state of :meth:`build`'s automaton as text: its formulas and its level."""
        e, level = state
        body = " & ".join(sorted(self.vwaa.name(q) for q in self._states_of(e))) or "true"
        return f"{{{body}}}/{level}"
