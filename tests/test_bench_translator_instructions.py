"""The translator's instruction count (``bench/translator_instructions.py``) measures the
translation alone: more instructions for a larger automaton, none for the imports (those of
the first translation included)."""

from __future__ import annotations

import shutil
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from bench.translator_instructions import translation

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which("valgrind") is None, reason="valgrind is not installed")
@pytest.mark.timeout(300)
def test_translation_counts_grow_with_the_automaton() -> None:
    with ThreadPoolExecutor(2) as pool:
        small = translation(ROOT, "gf-and", 3, pool)
        four = translation(ROOT, "gh-r", 4, pool)
    # Three recurrences cost some 5 million, ten times what a fresh interpreter's count moves
    # by; an import counted (numpy.ma alone is some 50 million, the translator's modules some
    # 500) would not fit under the bound.
    assert 0 < small < 25_000_000
    assert four > small + 40_000_000


@pytest.mark.skipif(shutil.which("valgrind") is None, reason="valgrind is not installed")
@pytest.mark.timeout(300)
def test_the_tree_given_is_the_one_counted(tmp_path: Path) -> None:
    shutil.copytree(ROOT / "planner", tmp_path / "planner")
    translate = tmp_path / "planner" / "ltl" / "translate.py"
    twice = "\n\n_once = translate\n\n\ndef translate(*args, **kwargs):\n"
    twice += "    _once(*args, **kwargs)\n    return _once(*args, **kwargs)\n"
    translate.write_text(translate.read_text() + twice)
    with ThreadPoolExecutor(2) as pool:
        here = translation(ROOT, "gh-r", 3, pool)
        doubled = translation(tmp_path, "gh-r", 3, pool)
    assert 1.4 * here < doubled < 2.2 * here  # the second call finds warm caches
