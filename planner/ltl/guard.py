"""Symbolic transition guards: conjunctions of literals (cubes) and their disjunctions (DNF).

Büchi automata label their transitions with propositional formulas over the atomic
propositions. Keeping these formulas symbolic, instead of enumerating the 2^|AP| letters,
is what lets the translator handle missions with a dozen goal regions.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import ClassVar


@dataclass(frozen=True, order=False, slots=True)
class Cube:
    """A conjunction of literals: every name in ``pos`` holds and none in ``neg`` does.

    ``pos`` and ``neg`` are disjoint; a contradictory conjunction is not a cube (see
    :meth:`conjoin`, which returns ``None`` for it).
    """

    pos: frozenset[str] = field(default_factory=frozenset)
    neg: frozenset[str] = field(default_factory=frozenset)

    TRUE: ClassVar[Cube]

    def __post_init__(self) -> None:
        if self.pos & self.neg:
            clash = ", ".join(sorted(self.pos & self.neg))
            raise ValueError(f"a cube cannot require and forbid the same atom ({clash})")

    @staticmethod
    def literal(name: str, positive: bool = True) -> Cube:
        """The cube of a single literal ``name`` or ``!name``."""
        one = frozenset((name,))
        return Cube(one, frozenset()) if positive else Cube(frozenset(), one)

    @property
    def is_true(self) -> bool:
        """True for the empty conjunction, which every letter satisfies."""
        return not self.pos and not self.neg

    @property
    def atoms(self) -> frozenset[str]:
        """The atoms this cube mentions."""
        return self.pos | self.neg

    def holds(self, label: frozenset[str]) -> bool:
        """Whether the letter ``label`` (the set of true atoms) satisfies the cube."""
        return self.pos <= label and not (self.neg & label)

    def conjoin(self, other: Cube) -> Cube | None:
        """The conjunction of two cubes, or ``None`` when it is unsatisfiable."""
        pos = self.pos | other.pos
        neg = self.neg | other.neg
        if pos & neg:
            return None
        return Cube(pos, neg)

    def implies(self, other: Cube) -> bool:
        """Whether every letter satisfying ``self`` satisfies ``other``."""
        return other.pos <= self.pos and other.neg <= self.neg

    def sort_key(self) -> tuple[int, tuple[tuple[str, bool], ...]]:
        """A total order for deterministic output: fewer literals first, then by name."""
        lits = sorted([(a, True) for a in self.pos] + [(a, False) for a in self.neg])
        return (len(lits), tuple(lits))

    def __str__(self) -> str:
        if self.is_true:
            return "1"
        lits = sorted([(a, a) for a in self.pos] + [(a, "!" + a) for a in self.neg])
        return " && ".join(text for _, text in lits)


Cube.TRUE = Cube()


def _absorb(cubes: Iterable[Cube]) -> frozenset[Cube]:
    """Drop cubes implied by another cube and merge pairs ``(c & x) | (c & !x)`` into ``c``."""
    work = set(cubes)
    if len(work) < 2:
        return frozenset(work)
    changed = True
    while changed:
        changed = False
        ordered = sorted(work, key=lambda c: len(c.pos) + len(c.neg))
        kept: list[Cube] = []
        for cube in ordered:
            if not any(cube.implies(k) for k in kept):
                kept.append(cube)
        work = set(kept)
        for cube in kept:
            for atom in cube.pos:
                twin = Cube(cube.pos - {atom}, cube.neg | {atom})
                if twin in work:
                    work.discard(cube)
                    work.discard(twin)
                    work.add(Cube(cube.pos - {atom}, cube.neg))
                    changed = True
                    break
            if changed:
                break
    return frozenset(work)


@dataclass(frozen=True, slots=True)
class Guard:
    """A propositional formula in disjunctive normal form: the disjunction of ``cubes``.

    The cube set is kept irredundant (no cube implies another), so equal guards built in
    different ways usually compare equal. No cubes means false; the single empty cube true.
    """

    cubes: frozenset[Cube] = field(default_factory=frozenset)

    TRUE: ClassVar[Guard]
    FALSE: ClassVar[Guard]

    def __post_init__(self) -> None:
        if len(self.cubes) > 1 or type(self.cubes) is not frozenset:
            object.__setattr__(self, "cubes", _absorb(self.cubes))

    @staticmethod
    def of(cubes: Iterable[Cube]) -> Guard:
        """The disjunction of ``cubes``."""
        return Guard(frozenset(cubes))

    @staticmethod
    def literal(name: str, positive: bool = True) -> Guard:
        """The guard of a single literal."""
        return Guard(frozenset((Cube.literal(name, positive),)))

    @property
    def is_false(self) -> bool:
        """True when no letter satisfies the guard."""
        return not self.cubes

    @property
    def is_true(self) -> bool:
        """True when every letter satisfies the guard (a tautology check, not just syntax)."""
        return _tautology(tuple(self.cubes))

    @property
    def atoms(self) -> frozenset[str]:
        """The atoms the guard mentions."""
        out: frozenset[str] = frozenset()
        for cube in self.cubes:
            out |= cube.atoms
        return out

    def holds(self, label: frozenset[str]) -> bool:
        """Whether the letter ``label`` satisfies the guard."""
        return any(cube.holds(label) for cube in self.cubes)

    def sorted_cubes(self) -> list[Cube]:
        """The cubes in a deterministic order."""
        return sorted(self.cubes, key=Cube.sort_key)

    def restrict(self, cube: Cube) -> Guard:
        """The cofactor of the guard under the partial assignment ``cube``."""
        out = []
        for c in self.cubes:
            if c.pos & cube.neg or c.neg & cube.pos:
                continue
            out.append(Cube(c.pos - cube.pos, c.neg - cube.neg))
        return Guard.of(out)

    def covers(self, cube: Cube) -> bool:
        """Whether every letter satisfying ``cube`` satisfies the guard."""
        return self.restrict(cube).is_true

    def implies(self, other: Guard) -> bool:
        """Whether every letter satisfying ``self`` satisfies ``other``."""
        return all(other.covers(c) for c in self.cubes)

    def equivalent(self, other: Guard) -> bool:
        """Whether both guards accept exactly the same letters."""
        return self.implies(other) and other.implies(self)

    def __and__(self, other: Guard) -> Guard:
        out = []
        for a in self.cubes:
            for b in other.cubes:
                c = a.conjoin(b)
                if c is not None:
                    out.append(c)
        return Guard.of(out)

    def __or__(self, other: Guard) -> Guard:
        return Guard(self.cubes | other.cubes)

    def __invert__(self) -> Guard:
        result = Guard.TRUE
        for cube in self.cubes:
            negated = [Cube.literal(a, False) for a in cube.pos]
            negated += [Cube.literal(a, True) for a in cube.neg]
            result = result & Guard.of(negated)
        return result

    def __str__(self) -> str:
        if self.is_false:
            return "0"
        cubes = self.sorted_cubes()
        if len(cubes) == 1 and cubes[0].is_true:
            return "1"
        return " || ".join(f"({c})" for c in cubes)


Guard.TRUE = Guard(frozenset((Cube.TRUE,)))
Guard.FALSE = Guard(frozenset())


def _tautology(cubes: tuple[Cube, ...]) -> bool:
    """Shannon expansion on the most frequent atom; small guards make this cheap."""
    if not cubes:
        return False
    if any(c.is_true for c in cubes):
        return True
    counts: dict[str, int] = {}
    for c in cubes:
        for a in c.atoms:
            counts[a] = counts.get(a, 0) + 1
    atom = max(sorted(counts), key=lambda a: counts[a])
    high = tuple(Cube(c.pos - {atom}, c.neg) for c in cubes if atom not in c.neg)
    low = tuple(Cube(c.pos, c.neg - {atom}) for c in cubes if atom not in c.pos)
    return _tautology(high) and _tautology(low)


def covers(cubes: list[Cube], cube: Cube) -> bool:
    """Whether the disjunction ``cubes`` holds on every letter satisfying ``cube``."""
    rest = []
    for c in cubes:
        if c.pos & cube.neg or c.neg & cube.pos:
            continue
        reduced = Cube(c.pos - cube.pos, c.neg - cube.neg)
        if reduced.is_true:
            return True
        rest.append(reduced)
    return _tautology(tuple(rest))
