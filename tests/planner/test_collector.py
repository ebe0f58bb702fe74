"""The planner pauses the cyclic garbage collector while it builds large object graphs and
restores it afterwards, also on errors and when the caller had paused it already."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import pytest

from planner.collector import collection_paused
from planner.errors import FormulaError
from planner.ltl.translate import translate


@pytest.fixture
def collector_on() -> Iterator[None]:
    gc.enable()
    yield
    gc.enable()


def test_the_collector_is_off_inside_and_on_again_after(collector_on: None) -> None:
    with collection_paused():
        assert not gc.isenabled()
        with collection_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()  # the inner pause leaves the outer one alone
    assert gc.isenabled()


def test_a_failed_translation_restores_the_collector(collector_on: None) -> None:
    with pytest.raises(FormulaError):
        translate("[]<>(a &&")
    assert gc.isenabled()


def test_a_caller_that_paused_the_collector_keeps_it_paused() -> None:
    gc.disable()
    try:
        translate("[]<>a && []<>b")
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_cyclic_garbage_made_in_a_pause_is_collected_after_it(collector_on: None) -> None:
    class Node:
        other: object = None

    with collection_paused():
        a, b = Node(), Node()
        a.other, b.other = b, a
        alive = weakref.ref(a)
        del a, b
        for _ in range(10_000):  # allocations that would trigger automatic collections
            Node()
        assert alive() is not None
    gc.collect()
    assert alive() is None
