"""Direct evaluation of LTL on ultimately periodic words ``prefix · cycle^ω``.

This is the reference semantics the translator is tested against: it never builds an
automaton. The word has ``len(prefix) + len(cycle)`` distinct positions (every later
position repeats one of the cycle's), so each temporal operator is a fixpoint over this
finite set: least for ``U``/``F``, greatest for ``R``/``W``/``G``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from planner.ltl.formula import (
    And,
    Const,
    Eventually,
    Formula,
    Globally,
    Iff,
    Implies,
    Next,
    Not,
    Or,
    Prop,
    Release,
    Until,
    WeakUntil,
)

Step = Callable[[list[bool], int], bool]


def holds_on_lasso(
    f: Formula, prefix: Sequence[frozenset[str]], cycle: Sequence[frozenset[str]]
) -> bool:
    """Whether the infinite word ``prefix · cycle · cycle · ...`` satisfies ``f`` at position 0.

    Letters are the sets of atomic propositions that hold. ``cycle`` must not be empty.
    """
    if not cycle:
        raise ValueError("the cycle of a lasso word must contain at least one letter")
    word = [frozenset(x) for x in prefix] + [frozenset(x) for x in cycle]
    loop_start = len(prefix)
    succ = [i + 1 for i in range(len(word))]
    succ[-1] = loop_start
    return _eval(f, word, succ, {})[0]


def _eval(
    f: Formula, word: list[frozenset[str]], succ: list[int], memo: dict[Formula, list[bool]]
) -> list[bool]:
    if f in memo:
        return memo[f]
    n = len(word)
    out: list[bool]
    if isinstance(f, Const):
        out = [f.value] * n
    elif isinstance(f, Prop):
        out = [f.name in letter for letter in word]
    elif isinstance(f, Not):
        out = [not v for v in _eval(f.arg, word, succ, memo)]
    elif isinstance(f, Next):
        arg = _eval(f.arg, word, succ, memo)
        out = [arg[succ[i]] for i in range(n)]
    elif isinstance(f, Globally | Eventually):
        arg = _eval(f.arg, word, succ, memo)
        if isinstance(f, Globally):
            out = _fixpoint(n, succ, True, lambda x, i: arg[i] and x[succ[i]])
        else:
            out = _fixpoint(n, succ, False, lambda x, i: arg[i] or x[succ[i]])
    else:
        a = _eval(f.left, word, succ, memo)
        b = _eval(f.right, word, succ, memo)
        if isinstance(f, And):
            out = [x and y for x, y in zip(a, b, strict=True)]
        elif isinstance(f, Or):
            out = [x or y for x, y in zip(a, b, strict=True)]
        elif isinstance(f, Implies):
            out = [(not x) or y for x, y in zip(a, b, strict=True)]
        elif isinstance(f, Iff):
            out = [x == y for x, y in zip(a, b, strict=True)]
        elif isinstance(f, Until):
            out = _fixpoint(n, succ, False, lambda x, i: b[i] or (a[i] and x[succ[i]]))
        elif isinstance(f, WeakUntil):
            out = _fixpoint(n, succ, True, lambda x, i: b[i] or (a[i] and x[succ[i]]))
        else:
            assert isinstance(f, Release)
            out = _fixpoint(n, succ, True, lambda x, i: b[i] and (a[i] or x[succ[i]]))
    memo[f] = out
    return out


def _fixpoint(n: int, succ: list[int], start: bool, step: Step) -> list[bool]:
    """Iterate ``x[i] = step(x, i)`` from the constant ``start`` until it is stable.

    Starting from all-false gives the least fixpoint, from all-true the greatest; each
    sweep changes at least one position, so at most ``n + 1`` sweeps run.
    """
    x = [start] * n
    changed = True
    while changed:
        changed = False
        for i in reversed(range(n)):
            value = step(x, i)
            if value != x[i]:
                x[i] = value
                changed = True
    return x
