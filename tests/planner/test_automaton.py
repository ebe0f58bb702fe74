"""Guards, the Buchi class, lasso acceptance, distances and the HOA / DOT / JSON exports."""

from __future__ import annotations

import json
import random
import re

import pytest

from planner.ltl.automaton import Buchi, Edge, nodes_on_cycles
from planner.ltl.guard import Cube, Guard, covers
from planner.ltl.translate import translate
from tests.planner.ltl_random import PROPS, random_formula, random_lasso
from tests.planner.spin_claim import parse_condition

L = frozenset


def lit(name: str, positive: bool = True) -> Guard:
    return Guard.literal(name, positive)


def test_cube_basics() -> None:
    c = Cube(L({"a"}), L({"b"}))
    assert c.holds(L({"a"})) and not c.holds(L({"a", "b"})) and not c.holds(L())
    assert c.implies(Cube.literal("a")) and not Cube.literal("a").implies(c)
    assert c.conjoin(Cube.literal("b")) is None
    assert Cube.TRUE.is_true and str(Cube.TRUE) == "1"
    with pytest.raises(ValueError, match="require and forbid"):
        Cube(L({"a"}), L({"a"}))


def test_guard_normal_form_and_printing() -> None:
    g = (lit("a") & lit("b")) | (lit("a") & lit("b", False))
    assert g == lit("a")  # (a & b) | (a & !b) merges to a
    assert (lit("a") | (lit("a") & lit("c"))) == lit("a")  # absorption
    assert (lit("a") | lit("a", False)).is_true
    assert not (lit("a") | lit("b")).is_true
    assert (lit("a") & lit("a", False)).is_false
    assert str(Guard.TRUE) == "1" and str(Guard.FALSE) == "0"
    assert str((lit("g1") & lit("g2", False)) | lit("g3")) == "(g3) || (g1 && !g2)"
    assert (~(lit("a") | lit("b"))) == (lit("a", False) & lit("b", False))
    assert lit("a").implies(lit("a") | lit("b")) and not lit("a").implies(lit("b"))
    assert covers([Cube.literal("b"), Cube.literal("b", False)], Cube.literal("a"))
    assert not covers([Cube.literal("b")], Cube.literal("a"))


def test_guard_holds_matches_its_string() -> None:
    rng = random.Random(3)
    for _ in range(200):
        g = Guard.FALSE
        for _ in range(rng.randint(0, 3)):
            cube = Guard.TRUE
            for p in PROPS:
                r = rng.random()
                if r < 0.3:
                    cube = cube & lit(p)
                elif r < 0.6:
                    cube = cube & lit(p, False)
            g = g | cube
        back = parse_condition(str(g))
        assert back.equivalent(g)
        for mask in range(8):
            letter = L(p for i, p in enumerate(PROPS) if mask >> i & 1)
            assert back.holds(letter) == g.holds(letter)
            assert g.holds(letter) != (~g).holds(letter)


def small() -> Buchi:
    """GF a over {a, b}: state 1 is accepting and reached when a holds; 2 is a dead end."""
    return Buchi(
        atoms=("a", "b"),
        state_names=("init", "accept_S1", "S2"),
        initial=0,
        accepting=frozenset({1}),
        edges=(
            Edge(0, Guard.TRUE, 0),
            Edge(0, lit("a"), 1),
            Edge(1, Guard.TRUE, 0),
            Edge(0, lit("b") & lit("a", False), 2),
        ),
    )


def test_buchi_structure() -> None:
    nba = small()
    assert nba.num_states == 3
    assert nba.num_transitions == 4
    assert [e.target for e in nba.out_edges(0)] == [0, 1, 2]
    assert nba.successors(0, L({"a"})) == {0, 1}
    assert nba.successors(0, L({"b"})) == {0, 2}
    assert nba.successors(2, L({"a"})) == frozenset()


def test_buchi_lasso_acceptance() -> None:
    nba = small()
    assert nba.accepts_lasso([], [L({"a"})])
    assert nba.accepts_lasso([L()], [L(), L({"a", "b"})])
    assert not nba.accepts_lasso([L({"a"}), L({"a"})], [L({"b"})])
    with pytest.raises(ValueError, match="cycle"):
        nba.accepts_lasso([L()], [])


def test_distances_to_acceptance() -> None:
    assert small().distances_to_acceptance() == {1: 0, 0: 1}
    seq = translate("[]!o && <>(g1 && <>(g2 && <>g3))")
    dist = seq.distances_to_acceptance()
    assert dist[seq.initial] == 1  # g1 & g2 & g3 at once reaches acceptance
    assert max(dist.values()) == 1 and len(dist) == seq.num_states


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"initial": 5}, "initial state"),
        ({"accepting": frozenset({7})}, "accepting"),
        ({"edges": (Edge(0, Guard.TRUE, 9),)}, "leaves"),
        ({"edges": (Edge(0, Guard.FALSE, 0),)}, "false guard"),
        ({"edges": (Edge(0, lit("z"), 0),)}, "not in atoms"),
    ],
)
def test_buchi_rejects_malformed_automata(kwargs: dict[str, object], message: str) -> None:
    base: dict[str, object] = {
        "atoms": ("a",),
        "state_names": ("s0",),
        "initial": 0,
        "accepting": frozenset(),
        "edges": (),
    }
    with pytest.raises(ValueError, match=message):
        Buchi(**(base | kwargs))  # type: ignore[arg-type]


def parse_hoa(text: str) -> Buchi:
    """A strict reader for the HOA subset we write (state-based Büchi, cube labels)."""
    head, body = text.split("--BODY--\n")
    assert body.endswith("--END--\n")
    header = dict(line.split(": ", 1) for line in head.strip().splitlines())
    assert header["HOA"] == "v1"
    assert header["acc-name"] == "Buchi" and header["Acceptance"] == "1 Inf(0)"
    count, _, names_text = header["AP"].partition(" ")
    atoms = tuple(json.loads(q) for q in re.findall(r'"(?:[^"\\]|\\.)*"', names_text))
    assert len(atoms) == int(count)
    n = int(header["States"])
    names: list[str] = []
    accepting: set[int] = set()
    guards: dict[tuple[int, int], Guard] = {}
    state = -1
    for line in body[: -len("--END--\n")].splitlines():
        m = re.fullmatch(r'State: (\d+) ("[^"]*")( \{0\})?', line)
        if m:
            state = int(m.group(1))
            assert state == len(names)
            names.append(json.loads(m.group(2)))
            if m.group(3):
                accepting.add(state)
            continue
        m = re.fullmatch(r"\[([^\]]+)\] (\d+)", line)
        assert m, line
        cube = Guard.TRUE
        if m.group(1) != "t":
            for literal in m.group(1).split("&"):
                negative = literal.startswith("!")
                cube = cube & lit(atoms[int(literal.lstrip("!"))], not negative)
        key = (state, int(m.group(2)))
        guards[key] = guards.get(key, Guard.FALSE) | cube
    assert len(names) == n
    return Buchi(
        atoms=atoms,
        state_names=tuple(names),
        initial=int(header["Start"]),
        accepting=frozenset(accepting),
        edges=tuple(Edge(s, g, t) for (s, t), g in sorted(guards.items())),
    )


def test_hoa_header_and_labels() -> None:
    nba = translate("[]!o && []<>g1 && []<>g2")
    hoa = nba.to_hoa("phi")
    lines = hoa.splitlines()
    assert lines[0] == "HOA: v1"
    assert 'name: "phi"' in lines
    assert f"States: {nba.num_states}" in lines
    assert f"Start: {nba.initial}" in lines
    assert 'AP: 3 "g1" "g2" "o"' in lines
    assert "acc-name: Buchi" in lines and "Acceptance: 1 Inf(0)" in lines
    assert lines[-1] == "--END--" and "--BODY--" in lines
    labels = [line for line in lines if line.startswith("[")]
    assert len(labels) == nba.num_transitions
    assert all(re.fullmatch(r"\[(t|!?\d(&!?\d)*)\] \d+", line) for line in labels)
    assert sum(1 for line in lines if line.endswith("{0}")) == len(nba.accepting)
    assert "[t] 0" in translate("true").to_hoa()
    assert "AP: 0" in translate("true").to_hoa()


def test_hoa_reads_back_to_the_same_language() -> None:
    rng = random.Random(11)
    for _ in range(60):
        nba = translate(random_formula(rng, depth=3))
        back = parse_hoa(nba.to_hoa())
        assert back.num_states == nba.num_states
        assert back.num_transitions == nba.num_transitions
        for _ in range(10):
            prefix, cycle = random_lasso(rng)
            assert back.accepts_lasso(prefix, cycle) == nba.accepts_lasso(prefix, cycle)


def test_dot_and_json_exports() -> None:
    nba = translate("[]!o && <>(g1 && <>g2)")
    dot = nba.to_dot()
    assert dot.startswith("digraph buchi {") and dot.rstrip().endswith("}")
    assert dot.count("doublecircle") == len(nba.accepting)
    assert dot.count(" -> ") == len(nba.edges) + 1  # plus the start arrow
    doc = json.loads(json.dumps(nba.to_json()))
    assert doc["atoms"] == ["g1", "g2", "o"]
    assert [s["id"] for s in doc["states"]] == list(range(nba.num_states))
    assert sum(s["initial"] for s in doc["states"]) == 1
    assert {s["id"] for s in doc["states"] if s["accepting"]} == set(nba.accepting)
    assert set(doc["states"][0]) == {"id", "name", "accepting", "initial"}
    for edge in doc["edges"]:
        assert set(edge) == {"source", "target", "guard"}
        original = next(
            e for e in nba.edges if (e.source, e.target) == (edge["source"], edge["target"])
        )
        assert parse_condition(edge["guard"]).equivalent(original.guard)


def _reach(graph: dict[int, list[int]], starts: list[int]) -> set[int]:
    seen: set[int] = set()
    todo = list(starts)
    while todo:
        node = todo.pop()
        if node not in seen:
            seen.add(node)
            todo.extend(graph[node])
    return seen


def test_nodes_on_cycles_are_the_reachable_nodes_that_reach_themselves() -> None:
    rng = random.Random(5)
    for _ in range(300):
        n = rng.randrange(1, 12)
        graph = {v: rng.sample(range(n), rng.randrange(0, min(n, 3) + 1)) for v in range(n)}
        starts = rng.sample(range(n), rng.randrange(1, min(n, 2) + 1))
        calls: list[int] = []

        def step(
            v: int, graph: dict[int, list[int]] = graph, calls: list[int] = calls
        ) -> list[int]:
            calls.append(v)
            return graph[v]

        reachable = _reach(graph, starts)
        expected = {v for v in reachable if v in _reach(graph, graph[v])}
        assert nodes_on_cycles(starts, step) == expected
        assert sorted(calls) == sorted(reachable)  # once per reachable node
