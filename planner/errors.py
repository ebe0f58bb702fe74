"""Typed errors whose messages a user can act on.

Every layer raises these (or subclasses) for bad input; the CLI prints the message and the
API maps them to 4xx responses.
"""

from __future__ import annotations


class LtlnavError(Exception):
    """Base class of every user-facing error of ltlnav."""


class FormulaError(LtlnavError):
    """An LTL formula that cannot be parsed or is not allowed for a mission.

    ``column`` is 1-based and points into ``formula``; ``expected`` says what the parser wanted.
    """

    def __init__(
        self,
        message: str,
        formula: str = "",
        column: int | None = None,
        expected: str | None = None,
    ) -> None:
        self.formula = formula
        self.column = column
        self.expected = expected
        self.reason = message
        super().__init__(self._render())

    def _render(self) -> str:
        if self.column is None:
            return self.reason
        pointer = " " * (self.column - 1) + "^"
        return f"column {self.column}: {self.reason}\n  {self.formula}\n  {pointer}"


class FieldError(LtlnavError):
    """Bad input located by ``field``, the dotted path of the culprit within its section; the
    spec layer prefixes the section to report the full path."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.reason = message
        super().__init__(f"{field}: {message}")


class WorldError(FieldError):
    """A world that is malformed or unusable."""


class PlanningError(LtlnavError):
    """A mission for which no plan was found; the message says why (unsatisfiable, budget)."""


class AutomatonTooLargeError(PlanningError):
    """A formula whose Büchi automaton outgrew the state budget of its translation."""

    def __init__(self, max_states: int) -> None:
        super().__init__(f"its Büchi automaton grows past {max_states} states while translating")
        self.max_states = max_states


def unsatisfiable(formula_has_run: bool) -> PlanningError:
    """The error of a task with no accepting run in this world; ``formula_has_run`` tells whether
    the formula's own automaton has one (the world is to blame) or not (a contradiction)."""
    if not formula_has_run:
        why = "the formula itself has no satisfying behaviour (it is a contradiction)"
    else:
        why = (
            "every accepting run of its automaton needs labels that no collision-free "
            "point of this world carries together (e.g. two disjoint regions at once, "
            "being inside an obstacle, or a region the robot cannot fit in)"
        )
    return PlanningError(f"the task is unsatisfiable in this world: {why}")
