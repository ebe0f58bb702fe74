"""Parse the Promela never claim printed by ``spin -f`` into a :class:`Buchi` (test helper).

A never claim is a list of labelled states; a state whose label starts with ``accept`` is
accepting, several labels may name one state (``accept_init: T0_init:``). A state body is

- ``do``/``if`` with options ``:: (cond) -> goto LABEL`` and the shortcut
  ``:: atomic { (cond) -> assert(!(cond)) }``, which spin emits for "from here on every
  word is accepted" and which we model as a jump to an accepting ``true`` sink;
- ``skip``: an accepting sink (the claim terminates, i.e. matches);
- ``false;`` or the single option ``:: false``: no transition.

Conditions use ``&& || ! ( ) 1 0 true false`` and proposition names.
"""

from __future__ import annotations

import re
import subprocess

from planner.ltl.automaton import Buchi, Edge
from planner.ltl.guard import Guard

_LABEL = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*):\s*$")
_GOTO = re.compile(r"^::\s*(.*?)\s*->\s*goto\s+([A-Za-z_][A-Za-z0-9_]*)\s*$")
_ATOMIC = re.compile(r"^::\s*atomic\s*\{\s*(.*?)\s*->\s*assert\(.*\)\s*\}\s*$")
_TOKEN = re.compile(r"\s*(&&|\|\||!|\(|\)|[A-Za-z_][A-Za-z0-9_]*|[01])")
SINK = "accept_all"


class ClaimSyntaxError(ValueError):
    """The text is not a never claim this parser understands."""


def run_spin(formula: str, timeout: float = 10.0) -> str:
    """The never claim of ``formula`` printed by ``spin -f`` (raises on timeout or error)."""
    done = subprocess.run(
        ["spin", "-f", formula], capture_output=True, text=True, timeout=timeout, check=False
    )
    if done.returncode != 0 or "never" not in done.stdout:
        raise ClaimSyntaxError(f"spin failed on {formula!r}: {done.stdout}{done.stderr}")
    return done.stdout


def parse_condition(text: str) -> Guard:
    """A spin boolean condition as a DNF guard."""
    tokens = []
    pos = 0
    text = text.strip()
    while pos < len(text):
        match = _TOKEN.match(text, pos)
        if not match:
            raise ClaimSyntaxError(f"bad condition {text!r} at {pos}")
        tokens.append(match.group(1))
        pos = match.end()
        while pos < len(text) and text[pos].isspace():
            pos += 1
    parser = _CondParser(tokens)
    guard = parser.disjunction()
    if parser.i != len(tokens):
        raise ClaimSyntaxError(f"trailing tokens in condition {text!r}")
    return guard


class _CondParser:
    def __init__(self, tokens: list[str]) -> None:
        self.tokens = tokens
        self.i = 0

    def peek(self) -> str | None:
        return self.tokens[self.i] if self.i < len(self.tokens) else None

    def disjunction(self) -> Guard:
        guard = self.conjunction()
        while self.peek() == "||":
            self.i += 1
            guard = guard | self.conjunction()
        return guard

    def conjunction(self) -> Guard:
        guard = self.unary()
        while self.peek() == "&&":
            self.i += 1
            guard = guard & self.unary()
        return guard

    def unary(self) -> Guard:
        token = self.peek()
        if token is None:
            raise ClaimSyntaxError("condition ends early")
        self.i += 1
        if token == "!":
            return ~self.unary()
        if token == "(":
            inner = self.disjunction()
            if self.peek() != ")":
                raise ClaimSyntaxError("missing ')' in condition")
            self.i += 1
            return inner
        if token in ("1", "true"):
            return Guard.TRUE
        if token in ("0", "false"):
            return Guard.FALSE
        return Guard.literal(token)


def parse_claim(text: str, atoms: tuple[str, ...]) -> Buchi:
    """The Büchi automaton of a never claim over the propositions ``atoms``.

    States whose body is ``skip`` and the target of the ``atomic`` shortcut are one
    accepting sink named ``accept_all``, so the state count is comparable to spin's.
    """
    lines = [line.strip() for line in text.splitlines()]
    lines = [line for line in lines if line and not line.startswith("never")]
    labels_of: list[list[str]] = []
    options: list[list[tuple[Guard, str]]] = []
    sink_labels: list[str] = []
    pending: list[str] = []
    for line in lines:
        label = _LABEL.match(line)
        if label:
            pending.append(label.group(1))
            continue
        if line in ("do", "if"):
            labels_of.append(pending)
            options.append([])
            pending = []
            continue
        if line in ("od;", "fi;", "}", ":: false", ":: (false)"):
            continue
        if line == "skip":
            sink_labels.extend(pending)
            pending = []
            continue
        if line == "false;":
            labels_of.append(pending)
            options.append([])
            pending = []
            continue
        goto = _GOTO.match(line)
        atomic = _ATOMIC.match(line)
        if goto:
            options[-1].append((parse_condition(goto.group(1)), goto.group(2)))
        elif atomic:
            options[-1].append((parse_condition(atomic.group(1)), SINK))
        else:
            raise ClaimSyntaxError(f"unexpected line in never claim: {line!r}\n{text}")
    names = [labels[0] if labels else f"anon{i}" for i, labels in enumerate(labels_of)]
    index = {lab: i for i, labels in enumerate(labels_of) for lab in labels}
    accepting = {
        i for i, labels in enumerate(labels_of) if any(x.startswith("accept") for x in labels)
    }
    sink = len(names)
    names.append(SINK)
    accepting.add(sink)
    for lab in [SINK, *sink_labels]:
        index[lab] = sink
    merged: dict[tuple[int, int], Guard] = {(sink, sink): Guard.TRUE}
    for source, opts in enumerate(options):
        for guard, target_label in opts:
            key = (source, index[target_label])
            merged[key] = merged.get(key, Guard.FALSE) | guard
    edges = tuple(Edge(s, g, t) for (s, t), g in sorted(merged.items()) if not g.is_false)
    return Buchi(
        atoms=atoms,
        state_names=tuple(names),
        initial=0,
        accepting=frozenset(accepting),
        edges=edges,
    )


def reachable_states(nba: Buchi) -> int:
    """How many states the initial state reaches (spin leaves unreachable ones in claims)."""
    seen = {nba.initial}
    stack = [nba.initial]
    while stack:
        for e in nba.out_edges(stack.pop()):
            if e.target not in seen:
                seen.add(e.target)
                stack.append(e.target)
    return len(seen)
