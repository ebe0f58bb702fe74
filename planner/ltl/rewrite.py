"""Language-preserving rewriting of LTL formulas in negation normal form.

Applied before translation because a smaller formula gives a smaller alternating
automaton. The rules are the classic ones of ltl2ba, Etessami–Holzmann and
Somenzi–Bloem (``F F a = F a``, ``true U a = F a``, ``G (a & b) = G a & G b``, ...).
Conjunctions such as ``G F a & G F b`` are deliberately kept apart: the translator gives
each ``G F`` its own acceptance condition, which is what keeps them cheap.
"""

from __future__ import annotations

from planner.ltl.formula import (
    FALSE,
    TRUE,
    And,
    Const,
    Eventually,
    Formula,
    Globally,
    Next,
    Not,
    Or,
    Prop,
    Release,
    Until,
    WeakUntil,
    to_nnf,
)


def simplify(f: Formula) -> Formula:
    """Rewrite the NNF formula ``f`` bottom-up until no rule applies."""
    previous = None
    while previous != f:
        previous = f
        f = _rewrite(f)
    return f


def _rewrite(f: Formula) -> Formula:
    if isinstance(f, Const | Prop | Not):
        return f
    if isinstance(f, And | Or):
        return _junction(f)
    if isinstance(f, Next):
        return _next(_rewrite(f.arg))
    if isinstance(f, Eventually):
        return _eventually(_rewrite(f.arg))
    if isinstance(f, Globally):
        return _globally(_rewrite(f.arg))
    assert isinstance(f, Until | Release | WeakUntil)
    left, right = _rewrite(f.left), _rewrite(f.right)
    if isinstance(f, Until):
        return _until(left, right)
    if isinstance(f, Release):
        return _release(left, right)
    return _weak_until(left, right)


def _suffix_invariant(f: Formula) -> bool:
    """Whether ``f`` holds on a word iff it holds on every suffix (``G F a``, ``F G a``, ...).

    For such formulas ``X f = F f = G f = f``.
    """
    if isinstance(f, Const):
        return True
    if isinstance(f, Globally | Eventually):
        return isinstance(f.arg, Globally | Eventually) and type(f.arg) is not type(f)
    if isinstance(f, And | Or):
        return _suffix_invariant(f.left) and _suffix_invariant(f.right)
    return False


def _next(a: Formula) -> Formula:
    return a if _suffix_invariant(a) else Next(a)


def _eventually(a: Formula) -> Formula:
    if isinstance(a, Eventually) or _suffix_invariant(a):
        return a
    if isinstance(a, Next):
        return Next(_eventually(a.arg))
    if isinstance(a, Until):
        return _eventually(a.right)
    return Eventually(a)


def _globally(a: Formula) -> Formula:
    if isinstance(a, Globally) or _suffix_invariant(a):
        return a
    if isinstance(a, Eventually):
        return _infinitely_often(a.arg)
    if isinstance(a, And):
        return And(_globally(a.left), _globally(a.right))
    if isinstance(a, Next):
        return Next(_globally(a.arg))
    if isinstance(a, Release):
        return _globally(a.right)
    return Globally(a)


def _infinitely_often(a: Formula) -> Formula:
    """``G F a``, split where possible: ``G F (a & F b) = G F a & G F b``.

    Also ``G F X a = G F F a = G F a``. Each ``G F`` conjunct becomes one acceptance
    condition of its own, which keeps goal sequences repeated forever small.
    """
    if isinstance(a, Next | Eventually):
        return _infinitely_often(a.arg)
    if _is_gf(a):
        return a
    if isinstance(a, And):
        parts = _operands(a, And)
        delayed = [p for p in parts if isinstance(p, Eventually) or _is_gf(p)]
        if delayed:
            core = [p for p in parts if p not in delayed]
            out = [_infinitely_often(p) for p in delayed]
            if core:
                joined = core[0]
                for p in core[1:]:
                    joined = And(joined, p)
                out.insert(0, Globally(Eventually(joined)))
            result = out[0]
            for p in out[1:]:
                result = And(result, p)
            return result
    return Globally(Eventually(a))


def _until(a: Formula, b: Formula) -> Formula:
    if isinstance(b, Const) or a in (b, FALSE):
        return b
    if a == TRUE or isinstance(b, Eventually):
        return _eventually(b)
    if isinstance(a, Next) and isinstance(b, Next):
        return Next(_until(a.arg, b.arg))
    return Until(a, b)


def _release(a: Formula, b: Formula) -> Formula:
    if isinstance(b, Const) or a in (b, TRUE):
        return b
    if a == FALSE or isinstance(b, Globally):
        return _globally(b)
    if isinstance(a, Next) and isinstance(b, Next):
        return Next(_release(a.arg, b.arg))
    return Release(a, b)


def _weak_until(a: Formula, b: Formula) -> Formula:
    if b == TRUE or a == TRUE:
        return TRUE
    if a in (FALSE, b):
        return b
    if b == FALSE:
        return _globally(a)
    return WeakUntil(a, b)


def _operands(f: Formula, kind: type[And] | type[Or]) -> list[Formula]:
    if isinstance(f, kind):
        return _operands(f.left, kind) + _operands(f.right, kind)
    return [f]


def _complement(f: Formula) -> Formula:
    """The negation of ``f`` in negation normal form, e.g. ``!(a U b) = !a R !b``."""
    if isinstance(f, Prop):
        return Not(f)
    if isinstance(f, Not):
        return f.arg
    return to_nnf(Not(f))


def _junction(f: And | Or) -> Formula:
    """Flatten, deduplicate and simplify an n-ary conjunction or disjunction."""
    kind: type[And] | type[Or] = And if isinstance(f, And) else Or
    unit, zero = (TRUE, FALSE) if kind is And else (FALSE, TRUE)
    items: list[Formula] = []
    for part in _operands(f, kind):
        for sub in _operands(_rewrite(part), kind):
            if sub == zero:
                return zero
            if sub != unit and sub not in items:
                items.append(sub)
    if len(items) > 1 and any(_complement(x) in items for x in items):
        return zero
    items = _merge_pairs(items, kind)
    if kind is And:
        items = _discharge_responses(items)
    if not items:
        return unit
    out = items[0]
    for item in items[1:]:
        out = kind(out, item)
    return out


def _discharge_responses(items: list[Formula]) -> list[Formula]:
    """Conjuncts ``G (x | F b)`` become ``G F b`` when a conjunct ``G F a`` has ``a => !x``.

    ``G F a & G (!a | F b) = G F a & G F b``: infinitely many ``a`` each answered by a
    later ``b`` are infinitely many ``b``, and infinitely many ``b`` answer every request.
    Applied until stable, a response chain ``G F g1 & G (g1 -> F g2) & G (g2 -> F g3) ...``
    becomes ``G F g1 & G F g2 & G F g3 ...``. Without this, the automaton construction
    walks every set of pending deliveries (2^(k-1) configurations, as ltl2ba does) before
    the reduction finds them all equivalent. ``a => !x`` is checked syntactically: the
    negation of each disjunct of ``x`` is a conjunct of ``a``.
    """
    changed = True
    while changed:
        changed = False
        recurring = [set(_operands(_inner(x), And)) for x in items if _is_gf(x)]
        for i, item in enumerate(items):
            if not recurring or not isinstance(item, Globally) or not isinstance(item.arg, Or):
                continue
            disjuncts = _operands(item.arg, Or)
            for event in disjuncts:
                if not isinstance(event, Eventually):
                    continue
                negated = [to_nnf(Not(d)) for d in disjuncts if d is not event]
                if any(all(n in conj for n in negated) for conj in recurring):
                    found = _operands(_infinitely_often(event.arg), And)
                    rest = [x for x in items[:i] + items[i + 1 :] if x not in found]
                    items = [*rest[:i], *found, *rest[i:]]
                    changed = True
                    break
            if changed:
                break
    return items


def _merge_pairs(items: list[Formula], kind: type[And] | type[Or]) -> list[Formula]:
    """Merge operand pairs that share structure, e.g. ``(a U c) | (b U c) = (a | b) U c``."""
    merged = True
    while merged:
        merged = False
        for i, x in enumerate(items):
            for j in range(i + 1, len(items)):
                combined = _merge(x, items[j], kind)
                if combined is not None:
                    items = [*items[:i], combined, *items[i + 1 : j], *items[j + 1 :]]
                    merged = True
                    break
            if merged:
                break
    return items


def _merge(x: Formula, y: Formula, kind: type[And] | type[Or]) -> Formula | None:
    conj = kind is And
    if isinstance(x, Next) and isinstance(y, Next):
        return Next(kind(x.arg, y.arg))
    if isinstance(x, Until) and isinstance(y, Until):
        if conj and x.right == y.right:
            return Until(And(x.left, y.left), x.right)
        if not conj and x.left == y.left:
            return Until(x.left, Or(x.right, y.right))
    if isinstance(x, Release) and isinstance(y, Release):
        if conj and x.left == y.left:
            return Release(x.left, And(x.right, y.right))
        if not conj and x.right == y.right:
            return Release(Or(x.left, y.left), x.right)
    if not conj and _is_gf(x) and _is_gf(y):
        return Globally(Eventually(Or(_inner(x), _inner(y))))
    if not conj and isinstance(x, Eventually) and isinstance(y, Eventually):
        return Eventually(Or(x.arg, y.arg))
    return None


def _is_gf(f: Formula) -> bool:
    return isinstance(f, Globally) and isinstance(f.arg, Eventually)


def _inner(f: Formula) -> Formula:
    assert isinstance(f, Globally) and isinstance(f.arg, Eventually)
    return f.arg.arg
