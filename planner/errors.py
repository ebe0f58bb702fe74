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
