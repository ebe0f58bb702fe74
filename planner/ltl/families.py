"""The published LTL benchmark families, as Spot's ``genltl`` defines them, and the
response chains of robot missions.

They are the translator's yardstick (``bench/translator.py``) and test corpus
(``tests/planner/test_ltl_families.py``). The pattern lists are copied from Spot's
``spot/gen/formulas.cc`` (2020): Dwyer, Avrunin and Corbett's specification patterns
(``dac``, 55 formulas), Etessami and Holzmann's list (``eh``, 12) and Somenzi and Bloem's
(``sb``, 27). Spot renames the atoms to ``p0, p1, ...`` in order of appearance; the
language up to that renaming is the same, so the atoms are kept as written.

Parametric families, with ``n`` the parameter of ``genltl``:

- ``response_chain(k)``: ``[](g1 -> <>g2) && ... && [](g(k-1) -> <>gk) && []<>g1``, pick up
  here and deliver there (not a ``genltl`` family; ``k`` atoms),
- ``gf_and(n)`` (``--and-gf``): ``GF p1 & ... & GF pn``,
- ``gh_r(n)`` (``--gh-r``): ``(GF p1 | FG p2) & ... & (GF pn | FG p(n+1))``, ``n + 1`` atoms,
- ``rv_counter(n)`` (``--rv-counter``): Rozier and Vardi's ``n``-bit counter over the atoms
  ``b`` and ``m``; it needs ``X`` up to depth ``n``.
"""

from __future__ import annotations

from collections.abc import Callable

DAC = (
    "[](!p0)",
    "<>p2 -> (!p0 U p2)",
    "[](p1 -> [](!p0))",
    "[]((p1 & !p2 & <>p2) -> (!p0 U p2))",
    "[](p1 & !p2 -> (!p0 W p2))",
    "<>(p0)",
    "!p2 W (p0 & !p2)",
    "[](!p1) | <>(p1 & <>p0)",
    "[](p1 & !p2 -> (!p2 W (p0 & !p2)))",
    "[](p1 & !p2 -> (!p2 U (p0 & !p2)))",
    "(!p0 W (p0 W (!p0 W (p0 W []!p0))))",
    "<>p2 -> ((!p0 & !p2) U (p2 | ((p0 & !p2) U (p2 |"
    " ((!p0 & !p2) U (p2 | ((p0 & !p2) U (p2 | (!p0 U p2)))))))))",
    "<>p1 -> (!p1 U (p1 & (!p0 W (p0 W (!p0 W (p0 W []!p0))))))",
    "[]((p1 & <>p2) -> ((!p0 & !p2) U (p2 | ((p0 & !p2) U (p2 |"
    "((!p0 & !p2) U (p2 | ((p0 & !p2) U (p2 | (!p0 U p2))))))))))",
    "[](p1 -> ((!p0 & !p2) U (p2 | ((p0 & !p2) U (p2 | ((!p0 & !p2) U"
    "(p2 | ((p0 & !p2) U (p2 | (!p0 W p2) | []p0)))))))))",
    "[](p0)",
    "<>p2 -> (p0 U p2)",
    "[](p1 -> [](p0))",
    "[]((p1 & !p2 & <>p2) -> (p0 U p2))",
    "[](p1 & !p2 -> (p0 W p2))",
    "!p0 W p3",
    "<>p2 -> (!p0 U (p3 | p2))",
    "[]!p1 | <>(p1 & (!p0 W p3))",
    "[]((p1 & !p2 & <>p2) -> (!p0 U (p3 | p2)))",
    "[](p1 & !p2 -> (!p0 W (p3 | p2)))",
    "[](p0 -> <>p3)",
    "<>p2 -> (p0 -> (!p2 U (p3 & !p2))) U p2",
    "[](p1 -> [](p0 -> <>p3))",
    "[]((p1 & !p2 & <>p2) -> ((p0 -> (!p2 U (p3 & !p2))) U p2))",
    "[](p1 & !p2 -> ((p0 -> (!p2 U (p3 & !p2))) W p2))",
    "<>p0 -> (!p0 U (p3 & !p0 & X(!p0 U p4)))",
    "<>p2 -> (!p0 U (p2 | (p3 & !p0 & X(!p0 U p4))))",
    "([]!p1) | (!p1 U (p1 & <>p0 -> (!p0 U (p3 & !p0 & X(!p0 U p4)))))",
    "[]((p1 & <>p2) -> (!p0 U (p2 | (p3 & !p0 & X(!p0 U p4)))))",
    "[](p1 -> (<>p0 -> (!p0 U (p2 | (p3 & !p0 & X(!p0 U p4))))))",
    "(<>(p3 & X<>p4)) -> ((!p3) U p0)",
    "<>p2 -> ((!(p3 & (!p2) & X(!p2 U (p4 & !p2)))) U (p2 | p0))",
    "([]!p1) | ((!p1) U (p1 & ((<>(p3 & X<>p4)) -> ((!p3) U p0))))",
    "[]((p1 & <>p2)->((!(p3 & (!p2) & X(!p2 U (p4 & !p2)))) U (p2|p0)))",
    "[](p1 -> (!(p3 & (!p2) & X(!p2 U (p4 & !p2))) U (p2 | p0) | [](!(p3 & X<>p4))))",
    "[] (p3 & X<> p4 -> X(<>(p4 & <> p0)))",
    "<>p2 -> (p3 & X(!p2 U p4) -> X(!p2 U (p4 & <> p0))) U p2",
    "[] (p1 -> [] (p3 & X<> p4 -> X(!p4 U (p4 & <> p0))))",
    "[] ((p1 & <>p2)->(p3 & X(!p2 U p4) -> X(!p2 U (p4 & <> p0))) U p2)",
    "[] (p1 -> (p3 & X(!p2 U p4) -> X(!p2 U (p4 & <> p0))) U (p2 |"
    "[] (p3 & X(!p2 U p4) -> X(!p2 U (p4 & <> p0)))))",
    "[] (p0 -> <>(p3 & X<>p4))",
    "<>p2 -> (p0 -> (!p2 U (p3 & !p2 & X(!p2 U p4)))) U p2",
    "[] (p1 -> [] (p0 -> (p3 & X<> p4)))",
    "[] ((p1 & <>p2) -> (p0 -> (!p2 U (p3 & !p2 & X(!p2 U p4)))) U p2)",
    "[] (p1 -> (p0 -> (!p2 U (p3 & !p2 & X(!p2 U p4)))) U (p2 | [](p0 -> (p3 & X<> p4))))",
    "[] (p0 -> <>(p3 & !p5 & X(!p5 U p4)))",
    "<>p2 -> (p0 -> (!p2 U (p3 & !p2 & !p5 & X((!p2 & !p5) U p4)))) U p2",
    "[] (p1 -> [] (p0 -> (p3 & !p5 & X(!p5 U p4))))",
    "[] ((p1 & <>p2) -> (p0 -> (!p2 U (p3 & !p2 & !p5 & X((!p2 & !p5) U p4)))) U p2)",
    "[] (p1 -> (p0 -> (!p2 U (p3 & !p2 & !p5 & X((!p2 & !p5) U p4)))) U "
    "(p2 | [] (p0 -> (p3 & !p5 & X(!p5 U p4)))))",
)
"""Dwyer et al.'s specification patterns (``genltl --dac-patterns``)."""

EH = (
    "p0 U (p1 & G(p2))",
    "p0 U (p1 & X(p2 U p3))",
    "p0 U (p1 & X(p2 & (F(p3 & X(F(p4 & X(F(p5 & X(F(p6))))))))))",
    "F(p0 & X(G(p1)))",
    "F(p0 & X(p1 & X(F(p2))))",
    "F(p0 & X(p1 U p2))",
    "(F(G(p0))) | (G(F(p1)))",
    "G(p0 -> (p1 U p2))",
    "G(p0 & X(F(p1 & X(F(p2 & X(F(p3)))))))",
    "(G(F(p0))) & (G(F(p1))) & (G(F(p2))) & (G(F(p3))) & (G(F(p4)))",
    "(p0 U (p1 U p2)) | (p1 U (p2 U p0)) | (p2 U (p0 U p1))",
    "G(p0 -> (p1 U ((G(p2)) | (G(p3)))))",
)
"""Etessami and Holzmann's list (``genltl --eh-patterns``)."""

SB = (
    "p0 U p1",
    "p0 U (p1 U p2)",
    "!(p0 U (p1 U p2))",
    "G(F(p0)) -> G(F(p1))",
    "(F(p0)) U (G(p1))",
    "(G(p0)) U p1",
    "!((F(F(p0))) <-> (F(p)))",
    "!((G(F(p0))) -> (G(F(p))))",
    "!((G(F(p0))) <-> (G(F(p))))",
    "p0 R (p0 | p1)",
    "(Xp0 U Xp1) | !X(p0 U p1)",
    "(Xp0 U p1) | !X(p0 U (p0 & p1))",
    "G(p0 -> F(p1)) & (((X(p0)) U p1) | !X(p0 U (p0 & p1)))",
    "G(p0 -> F(p1)) & (((X(p0)) U X(p1)) | !X(p0 U p1))",
    "G(p0 -> F(p1))",
    "!G(p0 -> X(p1 R p2))",
    "!(F(G(p0)) | F(G(p1)))",
    "G(F(p0) & F(p1))",
    "F(p0) & F(!p0)",
    "(X(p1) & p2) R X(((p3 U p0) R p2) U (p3 R p2))",
    "(G(p1 | G(F(p0))) & G(p2 | G(F(!p0)))) | G(p1) | G(p2)",
    "(G(p1 | F(G(p0))) & G(p2 | F(G(!p0)))) | G(p1) | G(p2)",
    "!((G(p1 | G(F(p0))) & G(p2 | G(F(!p0)))) | G(p1) | G(p2))",
    "!((G(p1 | F(G(p0))) & G(p2 | F(G(!p0)))) | G(p1) | G(p2))",
    "(G(p1 | X(G p0))) & (G (p2 | X(G !p0)))",
    "G(p1 | (Xp0 & X!p0))",
    "(p0 U p0) | (p1 U p0)",
)
"""Somenzi and Bloem's list (``genltl --sb-patterns``)."""


def response_chain(k: int) -> str:
    """``[](g1 -> <>g2) && ... && [](g(k-1) -> <>gk) && []<>g1`` (``k >= 1`` atoms)."""
    parts = [f"[](g{i} -> <>g{i + 1})" for i in range(1, k)]
    return " && ".join([*parts, "[]<>g1"])


def gf_and(n: int) -> str:
    """``GF p1 & ... & GF pn`` (``genltl --and-gf``)."""
    return " & ".join(f"GF p{i}" for i in range(1, n + 1))


def gh_r(n: int) -> str:
    """``(GF p1 | FG p2) & ... & (GF pn | FG p(n+1))`` (``genltl --gh-r``)."""
    return " & ".join(f"(GF p{i} | FG p{i + 1})" for i in range(1, n + 1))


def _xn(text: str, n: int) -> str:
    return "X" * n + f"({text})" if n else text


def rv_counter(n: int) -> str:
    """Rozier and Vardi's ``n``-bit binary counter (``genltl --rv-counter``, ``n >= 1``).

    ``m`` marks the least significant bit of each ``n``-bit number, ``b`` is the bit; every
    number is the previous one plus one, starting from zero.
    """
    marker = " & ".join([*(_xn("!m", i) for i in range(1, n)), _xn("m", n)])
    zero = " & ".join(_xn("!b", i) for i in range(n))
    xn_b, xn_nb = _xn("b", n), _xn("!b", n)
    keep = f"X((!m & (b <-> {xn_b})) U m)"
    carry = f"(m | (!m & !b & {xn_b} & {keep}))"
    flip = f"({xn_nb} & X((b & !m & {xn_nb}) U {carry}))"
    return (
        f"(m & G(m -> ({marker}))) & ({zero}) & "
        f"G((m & !b) -> ({xn_b} & {keep})) & G((m & b) -> {flip})"
    )


FAMILIES: dict[str, Callable[[int], str]] = {
    "response-chain": response_chain,
    "gf-and": gf_and,
    "gh-r": gh_r,
    "rv-counter": rv_counter,
}
"""The parametric families by their ``genltl`` option name."""

PATTERNS: dict[str, tuple[str, ...]] = {"dac": DAC, "eh": EH, "sb": SB}
"""The pattern lists by name."""
