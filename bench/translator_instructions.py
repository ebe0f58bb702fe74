"""Translator instructions: what ``translate`` executes (valgrind), here and in another tree.

Run with ``.venv/bin/python bench/translator_instructions.py --baseline TREE [--family F]
[--k K ...]``. Wall and CPU times on a shared machine move by a tenth from run to run (a
training on the other hyperthread of the core slows a translation by a third); the number
of machine instructions the interpreter executes does not, so steps of a few percent show.
Each formula runs in a fresh ``python`` under ``valgrind --tool=callgrind`` twice, once up
to the parsed formula and once through ``translate``; the difference is the translation's.
Both runs first translate a one-atom formula, so what a first translation imports lazily
(``numpy.ma``, which ``numpy.unique`` loads: some 50 million instructions) counts in neither.
Instructions are a proxy: they do not see cache misses, which grow with the automaton.
Prints, per formula, millions of instructions in this tree and in ``TREE`` and their ratio.
Needs valgrind (``apt-get install valgrind``); 50-100 times slower than running natively.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = """
import sys
from planner.ltl.families import FAMILIES
from planner.ltl.formula import parse
from planner.ltl.translate import translate
translate(parse("G F warm_up"))
formula = parse(FAMILIES[sys.argv[1]](int(sys.argv[2])))
if sys.argv[3] == "translate":
    translate(formula)
"""


def run_script(tree: Path, family: str, k: int, stage: str, under: list[str]) -> str:
    """Run :data:`SCRIPT` in a fresh interpreter on ``tree`` (prefixed by ``under``); its
    standard error."""
    command = [*under, sys.executable, "-c", SCRIPT, family, str(k), stage]
    # ``-c`` puts the working directory first on the path: run in ``tree``. A fixed hash
    # seed keeps the order of sets of strings, and so the work, the same from run to run.
    environment = {"PYTHONPATH": str(tree), "PYTHONHASHSEED": "0"}
    done = subprocess.run(
        command, capture_output=True, text=True, cwd=tree, env=environment, check=True
    )
    return done.stderr


def instructions(tree: Path, family: str, k: int, stage: str) -> int:
    """Instructions of a fresh interpreter that imports ``tree``'s translator and parses
    ``family(k)``, then translates it when ``stage`` is ``translate``."""
    valgrind = ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null"]
    stderr = run_script(tree, family, k, stage, valgrind)
    found = re.search(r"Collected : (\d+)", stderr)
    if found is None:
        raise RuntimeError(f"valgrind printed no instruction count:\n{stderr[-2000:]}")
    return int(found.group(1))


def translation(tree: Path, family: str, k: int, pool: ThreadPoolExecutor) -> int:
    """Instructions of ``translate(family(k))`` alone in ``tree``."""
    # Once natively first: the two counted runs then load the same compiled modules (in a
    # fresh checkout the first to start would otherwise compile them, alone or both).
    run_script(tree, family, k, "parse", [])
    parsed, translated = pool.map(
        lambda stage: instructions(tree, family, k, stage), ["parse", "translate"]
    )
    return translated - parsed


def main(argv: list[str] | None = None) -> None:
    """Print one row per formula: millions of instructions here, in the baseline, ratio."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="another checkout")
    parser.add_argument("--family", default="gh-r", help="a family of planner.ltl.families")
    parser.add_argument("--k", type=int, nargs="+", default=[9, 10, 11], help="its parameters")
    parser.add_argument("--jobs", type=int, default=2, help="valgrind runs at once")
    args = parser.parse_args(argv)
    if shutil.which("valgrind") is None:
        sys.exit("valgrind is not installed: apt-get install valgrind")
    print(f"{'family':>14} {'k':>4} {'M instr':>10} {'baseline':>10} {'ratio':>6}")
    with ThreadPoolExecutor(args.jobs) as pool:
        for k in args.k:
            ours = translation(ROOT, args.family, k, pool)
            before = translation(args.baseline.resolve(), args.family, k, pool)
            print(
                f"{args.family:>14} {k:>4} {ours / 1e6:>10.0f} {before / 1e6:>10.0f}"
                f" {ours / before:>6.2f}"
            )


if __name__ == "__main__":
    main()
