"""Tokenizer and recursive-descent parser for LTL formulas (see :mod:`planner.ltl.formula`).

Precedence, tightest first: unary ``! X G F [] <>``; binary temporal ``U R V W``
(right-associative); ``&&``; ``||``; ``->`` (right-associative); ``<->``
(right-associative). Every error names the 1-based column and what was expected there.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import NoReturn

from planner.errors import FormulaError
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


@dataclass(frozen=True)
class Token:
    """One lexical token; ``kind`` is a symbolic name, ``column`` 1-based."""

    kind: str
    text: str
    column: int


_IDENT = re.compile(r"[a-z_][a-z0-9_]*")
_SYMBOLS: tuple[tuple[str, str], ...] = (
    ("<->", "IFF"),
    ("->", "IMPLIES"),
    ("[]", "G"),
    ("<>", "F"),
    ("&&", "AND"),
    ("/\\", "AND"),
    ("||", "OR"),
    ("\\/", "OR"),
    ("&", "AND"),
    ("|", "OR"),
    ("!", "NOT"),
    ("~", "NOT"),
    ("(", "LPAREN"),
    (")", "RPAREN"),
)
_LETTER_OPS = {"G": "G", "F": "F", "X": "X", "U": "U", "R": "R", "V": "R", "W": "W"}
_HINTS = {
    "[": "did you mean '[]' (always)?",
    "<": "did you mean '<>' (eventually) or '<->' (iff)?",
    "-": "did you mean '->' (implies)?",
    "/": "did you mean '/\\' (and)?",
    "\\": "did you mean '\\/' (or)?",
    "=": "implication is written '->' and equivalence '<->'",
}


def tokenize(text: str) -> list[Token]:
    """Split ``text`` into tokens, ending with an ``EOF`` token one column past the end."""
    tokens: list[Token] = []
    i = 0
    while i < len(text):
        ch = text[i]
        if ch.isspace():
            i += 1
            continue
        match = _IDENT.match(text, i)
        if match:
            word = match.group()
            kind = {"true": "TRUE", "false": "FALSE"}.get(word, "ID")
            tokens.append(Token(kind, word, i + 1))
            i = match.end()
            continue
        if ch in _LETTER_OPS:
            tokens.append(Token(_LETTER_OPS[ch], ch, i + 1))
            i += 1
            continue
        for symbol, kind in _SYMBOLS:
            if text.startswith(symbol, i):
                tokens.append(Token(kind, symbol, i + 1))
                i += len(symbol)
                break
        else:
            raise FormulaError(_unknown_character(ch), formula=text, column=i + 1)
    tokens.append(Token("EOF", "", len(text) + 1))
    return tokens


def _unknown_character(ch: str) -> str:
    if ch.isupper():
        return (
            f"unexpected character '{ch}': propositions are lowercase identifiers "
            "([a-z_][a-z0-9_]*) and the only uppercase operators are G F X U R V W"
        )
    if ch.isdigit():
        return f"unexpected character '{ch}': propositions must start with a letter or '_'"
    hint = _HINTS.get(ch)
    return f"unexpected character '{ch}'" + (f": {hint}" if hint else "")


def _describe(token: Token) -> str:
    return "end of input" if token.kind == "EOF" else f"'{token.text}'"


class Parser:
    """Recursive-descent parser over the token list of one formula."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.tokens = tokenize(text)
        self.pos = 0

    def parse(self) -> Formula:
        """Parse the whole text as one formula."""
        formula = self._iff()
        token = self._peek()
        if token.kind != "EOF":
            if token.kind == "RPAREN":
                self._fail(token, "an operator or end of input (this ')' has no matching '(')")
            self._fail(token, "an operator or end of input")
        return formula

    def _peek(self) -> Token:
        return self.tokens[self.pos]

    def _take(self) -> Token:
        token = self.tokens[self.pos]
        self.pos += 1
        return token

    def _fail(self, token: Token, expected: str, after: Token | None = None) -> NoReturn:
        where = f" after '{after.text}'" if after is not None else ""
        raise FormulaError(
            f"expected {expected}{where}, found {_describe(token)}",
            formula=self.text,
            column=token.column,
            expected=expected,
        )

    def _iff(self) -> Formula:
        left = self._implies()
        if self._peek().kind == "IFF":
            self._take()
            return Iff(left, self._iff())
        return left

    def _implies(self) -> Formula:
        left = self._or()
        if self._peek().kind == "IMPLIES":
            self._take()
            return Implies(left, self._implies())
        return left

    def _or(self) -> Formula:
        left = self._and()
        while self._peek().kind == "OR":
            self._take()
            left = Or(left, self._and())
        return left

    def _and(self) -> Formula:
        left = self._binary_temporal()
        while self._peek().kind == "AND":
            self._take()
            left = And(left, self._binary_temporal())
        return left

    def _binary_temporal(self) -> Formula:
        left = self._unary()
        kind = self._peek().kind
        if kind in ("U", "R", "W"):
            self._take()
            right = self._binary_temporal()
            if kind == "U":
                return Until(left, right)
            return Release(left, right) if kind == "R" else WeakUntil(left, right)
        return left

    def _unary(self) -> Formula:
        token = self._peek()
        if token.kind in ("NOT", "X", "G", "F"):
            self._take()
            arg = self._unary()
            if token.kind == "NOT":
                return Not(arg)
            if token.kind == "X":
                return Next(arg)
            return Globally(arg) if token.kind == "G" else Eventually(arg)
        return self._atom()

    def _atom(self) -> Formula:
        token = self._take()
        if token.kind == "ID":
            return Prop(token.text)
        if token.kind in ("TRUE", "FALSE"):
            return Const(token.kind == "TRUE")
        if token.kind == "LPAREN":
            inner = self._iff()
            close = self._peek()
            if close.kind != "RPAREN":
                self._fail(close, f"')' to close the '(' at column {token.column}")
            self._take()
            return inner
        previous = self.tokens[self.pos - 2] if self.pos >= 2 else None
        self._fail(token, "a formula", after=previous)
