"""Translator benchmark: the published LTL families, sizes and times, beside ltl2ba and spin.

Run with ``.venv/bin/python bench/translator.py [--quick] [--baseline TREE] [--ltl2ba PATH]
[--spin] [--timeout S]``. One row per formula of Dwyer et al.'s patterns (``dac``),
Etessami-Holzmann's (``eh``) and Somenzi-Bloem's (``sb``) lists and the parametric families
of :mod:`planner.ltl.families` (response chains and ``gf-and`` to 12 atoms, ``gh-r`` to
12 atoms, ``rv-counter`` to 4 bits): states, transitions (cubes, as ltl2ba counts them) and
milliseconds of CPU (``time.process_time``, the best of three under 50 ms: the machine is
shared).

``--baseline TREE`` translates every formula also with the translator of another checkout
(e.g. ``git archive HEAD~3 | tar -x -C /tmp/old``); the two run in two worker processes fed
alternately, one formula at a time, so both see the same load. ``--ltl2ba PATH`` adds the
states and transitions of ltl2ba 1.x (built from its C sources, not shipped here: in the
source folder of LTL2BA 1.1, ``touch config.h && gcc -O2 -DNXT -o ltl2ba *.c``) and
``--spin`` those of ``spin -f`` (Debian's spin 6.5, Etessami-Holzmann's translator, which
reads no ``X``). A translation over ``--timeout`` seconds shows ``-`` and ``>``.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SLOW_MS = 1000.0
"""The target: every formula translates in under a second."""


@dataclass(frozen=True)
class Case:
    """One benchmark formula: its family, index or parameter and text (letter syntax)."""

    family: str
    k: int
    text: str


def cases(quick: bool = False) -> list[Case]:
    """Every formula of the benchmark, the pattern lists first."""
    from planner.ltl.families import FAMILIES, PATTERNS

    out = [Case(name, i, t) for name, ts in PATTERNS.items() for i, t in enumerate(ts, 1)]
    top = {"response-chain": 12, "gf-and": 12, "gh-r": 11, "rv-counter": 4}
    for name, make in FAMILIES.items():
        ks = range(1, top[name] + 1)
        if quick:
            ks = range(1, top[name] + 1, 3)
        out += [Case(name, k, make(k)) for k in ks]
    return out


# ---------------------------------------------------------------- worker side


class _TimeoutError(Exception):
    pass


def _on_alarm(signum: int, frame: Any) -> None:
    raise _TimeoutError


def worker(tree: Path, timeout: float) -> None:
    """Translate the formulas read from stdin (one JSON string a line) with ``tree``'s code.

    Prints one JSON object a line: ``states``, ``transitions``, ``ms`` or ``timeout``.
    """
    sys.path.insert(0, str(tree))
    from planner.ltl.formula import parse
    from planner.ltl.translate import translate

    signal.signal(signal.SIGALRM, _on_alarm)
    for line in sys.stdin:
        text = json.loads(line)
        formula = parse(text)
        result: dict[str, Any]
        best = float("inf")
        try:
            for _ in range(3):
                signal.setitimer(signal.ITIMER_REAL, timeout)
                start = time.process_time()
                nba = translate(formula)
                best = min(best, (time.process_time() - start) * 1000)
                signal.setitimer(signal.ITIMER_REAL, 0)
                if best > 50:
                    break
            result = {"states": nba.num_states, "transitions": nba.num_transitions, "ms": best}
        except _TimeoutError:
            result = {"timeout": True}
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        print(json.dumps(result), flush=True)


class Worker:
    """A translator worker process over one source tree."""

    def __init__(self, tree: Path, timeout: float) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--worker", str(tree), "--timeout", str(timeout)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=tree,
        )

    def run(self, text: str) -> dict[str, Any]:
        """The worker's result for one formula."""
        stdin, stdout = self.proc.stdin, self.proc.stdout
        assert stdin is not None and stdout is not None
        stdin.write(json.dumps(text) + "\n")
        stdin.flush()
        result: dict[str, Any] = json.loads(stdout.readline())
        return result

    def close(self) -> None:
        """End the worker."""
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait()


# ---------------------------------------------------------------- references

_LABEL = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*:\s*$")


def claim_size(claim: str) -> tuple[int, int]:
    """States and transitions (cubes) of a never claim printed by ltl2ba or spin.

    Consecutive labels name one state; ``skip`` (accept everything) counts one transition.
    """
    states = transitions = 0
    previous_label = False
    for raw in claim.splitlines():
        line = raw.strip()
        is_label = bool(_LABEL.match(line))
        if is_label and not previous_label:
            states += 1
        previous_label = is_label
        if line.startswith("::") and "false" not in line.split("->")[0]:
            transitions += line.split("->")[0].count("||") + 1
        elif line == "skip":
            transitions += 1
    return states, transitions


def reference(command: list[str], text: str, timeout: float) -> str:
    """``states/transitions`` of an outside translator on ``text`` (spin syntax), or ``-``."""
    try:
        done = subprocess.run(
            [*command, text], capture_output=True, text=True, timeout=timeout, check=False
        )
    except subprocess.TimeoutExpired:
        return "-"
    if "never" not in done.stdout:
        return "err"
    states, transitions = claim_size(done.stdout)
    return f"{states}/{transitions}"


# ---------------------------------------------------------------- table


def _cell(result: dict[str, Any] | None, timeout: float) -> list[str]:
    if result is None:
        return []
    if result.get("timeout"):
        return ["-", "-", f">{timeout * 1000:.0f}"]
    return [str(result["states"]), str(result["transitions"]), f"{result['ms']:.1f}"]


def main(argv: list[str] | None = None) -> None:
    """Print the table, then the formulas over a second and over ltl2ba's size."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="every third parameter only")
    parser.add_argument("--baseline", type=Path, help="another checkout to compare with")
    parser.add_argument("--ltl2ba", help="path of an ltl2ba executable")
    parser.add_argument("--spin", action="store_true", help="add spin -f (if installed)")
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds per translation")
    parser.add_argument("--family", action="append", help="only these families")
    parser.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        worker(args.worker, args.timeout)
        return

    from planner.ltl.formula import atoms, parse, to_spin, uses_next

    new = Worker(ROOT, args.timeout)
    old = Worker(args.baseline.resolve(), args.timeout) if args.baseline else None
    spin = args.spin and shutil.which("spin") is not None
    header = ["family", "k", "AP", "states", "trans", "ms"]
    if old:
        header += ["old st", "old tr", "old ms"]
    if args.ltl2ba:
        header.append("ltl2ba st/tr")
    if spin:
        header.append("spin st/tr")
    print(" ".join(f"{h:>14}" if i == 0 else f"{h:>8}" for i, h in enumerate(header)))
    slow: list[str] = []
    larger: list[str] = []
    for case in cases(args.quick):
        if args.family and case.family not in args.family:
            continue
        formula = parse(case.text)
        ours = new.run(case.text)
        before = old.run(case.text) if old else None
        row = [case.family, str(case.k), str(len(atoms(formula)))]
        row += _cell(ours, args.timeout) + _cell(before, args.timeout)
        name = f"{case.family} {case.k}"
        if ours.get("timeout") or ours["ms"] > SLOW_MS:
            slow.append(name)
        if args.ltl2ba:
            ref = reference([args.ltl2ba, "-f"], to_spin(formula), args.timeout)
            row.append(ref)
            if "/" in ref and not ours.get("timeout") and ours["states"] > int(ref.split("/")[0]):
                larger.append(f"{name} ({ours['states']} > {ref.split('/')[0]})")
        if spin:
            row.append(
                "X"
                if uses_next(formula)
                else reference(["spin", "-f"], to_spin(formula), args.timeout)
            )
        print(" ".join(f"{c:>14}" if i == 0 else f"{c:>8}" for i, c in enumerate(row)))
        sys.stdout.flush()
    new.close()
    if old:
        old.close()
    print(f"\nover {SLOW_MS:.0f} ms: {', '.join(slow) or 'none'}")
    if args.ltl2ba:
        print(f"more states than ltl2ba: {', '.join(larger) or 'none'}")


if __name__ == "__main__":
    main()
