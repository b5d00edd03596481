"""The objective DAG: construction, structure, names, round trips and every malformed input."""

import math

import pytest

from tpo.errors import GraphError
from tpo.graph import Edge, ObjectiveGraph, local_slack, resolve_name

NAV = ("goal", "avoid", "monitor")


def test_chain_from_spec_with_prefix_names():
    g = ObjectiveGraph.parse("M>A>G", slack=[1, 2], objectives=NAV)
    assert g.objectives == ("monitor", "avoid", "goal")
    assert g.edges == (Edge("monitor", "avoid", 1.0), Edge("avoid", "goal", 2.0))
    assert g.order == ("monitor", "avoid", "goal")
    assert g.leaf == "goal"


def test_fan_order_breaks_ties_by_declaration():
    g = ObjectiveGraph.parse("avoid>goal, monitor>goal", slack=0)
    assert g.order == ("avoid", "monitor", "goal")
    g2 = ObjectiveGraph.parse("monitor>goal, avoid>goal", slack=0)
    assert g2.order == ("monitor", "avoid", "goal")


def test_builders_agree():
    a = ObjectiveGraph.parse("x>y>z", slack=[0.5, 1])
    b = ObjectiveGraph.chain(["x", "y", "z"], slack=[0.5, 1])
    c = ObjectiveGraph.from_edges([("x", "y"), ("y", "z")], slack=[0.5, 1])
    d = ObjectiveGraph(("x", "y", "z"), (("x", "y", 0.5), ("y", "z", 1.0)))
    assert a == b == c == d


def test_diamond_structure():
    g = ObjectiveGraph.parse("a>b, a>c, b>d, c>d", slack=[1, 2, 3, 4])
    assert g.order == ("a", "b", "c", "d")
    assert g.parents("d") == ("b", "c")
    assert g.ancestors("d") == ("a", "b", "c")
    assert g.ancestors("b") == ("a",)
    assert g.ancestors("a") == ()
    assert [(e.parent, e.child) for e in g.ancestral_edges("d")] == [
        ("a", "b"), ("a", "c"), ("b", "d"), ("c", "d")]
    assert [(e.parent, e.child) for e in g.ancestral_edges("c")] == [("a", "c")]
    assert g.ancestral_edges("a") == ()


def test_ancestral_edges_of_a_mid_chain_node_exclude_later_edges():
    g = ObjectiveGraph.parse("a>b>c>d", slack=[1, 2, 3])
    assert [e.slack for e in g.ancestral_edges("c")] == [1.0, 2.0]


def test_topological_order_is_deterministic_with_later_roots():
    # c is declared last but is a root: it comes before b only if b depends on it.
    g = ObjectiveGraph.parse("a>b, c>b, b>d")
    assert g.order == ("a", "c", "b", "d")


def test_single_objective_graph():
    g = ObjectiveGraph.parse("goal")
    assert g.order == ("goal",) and g.edges == () and g.leaf == "goal"
    assert ObjectiveGraph.parse("G", objectives=NAV).objectives == ("goal",)
    assert str(g) == "goal"


def test_global_slack_converts_to_local():
    g = ObjectiveGraph.parse("a>b>c", slack=[100, 10], slack_kind="global", gamma=0.99)
    assert g.slacks == pytest.approx((1.0, 0.1))
    assert local_slack(50, 0.9) == pytest.approx(5.0)


def test_spec_dict_and_toml_round_trip():
    for spec, canonical, slack in [
        ("monitor>avoid>goal", "monitor>avoid>goal", [0, 100]),
        ("avoid>goal, monitor>goal", "avoid>goal, monitor>goal", [1.5, 2.25]),
        ("a>b, a>c, b>d, c>d", "a>b, a>c, b>d, c>d", [0, 1e-5, 3, 4]),
        ("a>b, c>b, b>d", "a>b, c>b>d", [1, 2, 3]),  # consecutive edges merge into a chain
    ]:
        g = ObjectiveGraph.parse(spec, slack)
        assert g.spec == canonical
        assert ObjectiveGraph.parse(g.spec, list(g.slacks)) == g
        assert ObjectiveGraph.from_dict(g.to_dict()) == g
        assert ObjectiveGraph.from_toml(g.to_toml()) == g


def test_from_dict_with_global_slack():
    g = ObjectiveGraph.from_dict({"dag": "M>G", "slack": 10, "slack_kind": "global",
                                  "gamma": 0.9}, objectives=NAV)
    assert g.edges == (Edge("monitor", "goal", pytest.approx(1.0)),)


def test_bind_resolves_names_against_a_model():
    g = ObjectiveGraph.parse("M>a>g", slack=[1, 2]).bind(NAV)
    assert g == ObjectiveGraph.parse("monitor>avoid>goal", slack=[1, 2])


def test_with_slack_keeps_the_dag():
    g = ObjectiveGraph.parse("a>b>c").with_slack([3, 4])
    assert g.slacks == (3.0, 4.0) and g.spec == "a>b>c"


def test_resolve_name_exact_match_beats_prefix():
    assert resolve_name("go", ("go", "goal")) == "go"
    assert resolve_name("GOA", ("go", "goal")) == "goal"


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: ObjectiveGraph.parse("a>b, b>c, c>a"), "cycle: a > b > c > a"),
        (lambda: ObjectiveGraph.parse("a>a"), "self-loop on objective 'a'"),
        (lambda: ObjectiveGraph.parse("a>b, a>b"), "duplicate edge a>b"),
        (lambda: ObjectiveGraph.parse("a>b, c>d"), "exactly one sink (leaf), found 2: b, d"),
        (lambda: ObjectiveGraph.parse("a, b"), "exactly one sink (leaf), found 2: a, b"),
        (lambda: ObjectiveGraph.parse("a>b, c"), "objective(s) c have no edge"),
        (lambda: ObjectiveGraph.parse("a>>b"), "empty objective name"),
        (lambda: ObjectiveGraph.parse("  "), "empty DAG spec"),
        (lambda: ObjectiveGraph.parse(3), "a DAG spec is a string"),
        (lambda: ObjectiveGraph.parse("x>G", objectives=NAV), "unknown objective 'x'"),
        (lambda: ObjectiveGraph.parse("g>a", objectives=("goal", "go2", "avoid")),
         "ambiguous objective 'g': matches goal, go2"),
        (lambda: ObjectiveGraph.parse("a>b", slack=-1), "slack must be >= 0, got -1"),
        (lambda: ObjectiveGraph.parse("a>b", slack=math.nan), "slack must be finite"),
        (lambda: ObjectiveGraph.parse("a>b", slack=math.inf), "slack must be finite"),
        (lambda: ObjectiveGraph.parse("a>b", slack="1"), "slack must be a number"),
        (lambda: ObjectiveGraph.parse("a>b", slack=True), "slack must be a number"),
        (lambda: ObjectiveGraph.parse("a>b>c", slack=[1, 2, 3]),
         "got 3 slack values for 2 edge(s)"),
        (lambda: ObjectiveGraph.parse("a", slack=[1, 2]), "got 2 slack values for 0 edge(s)"),
        (lambda: ObjectiveGraph.parse("a>b", slack=1, slack_kind="global"),
         "global slack needs gamma"),
        (lambda: ObjectiveGraph.parse("a>b", slack=1, slack_kind="global", gamma=1.0),
         "gamma must be a number in [0, 1)"),
        (lambda: ObjectiveGraph.parse("a>b", slack_kind="relative"), "slack kind must be"),
        (lambda: ObjectiveGraph(("a", "a")), "duplicate objective 'a'"),
        (lambda: ObjectiveGraph(("a", "b"), (("a", "z", 0.0),)), "unknown objective 'z'"),
        (lambda: ObjectiveGraph(()), "at least one objective"),
        (lambda: ObjectiveGraph.from_dict({"slack": 1}), "no 'dag' key"),
        (lambda: ObjectiveGraph.from_dict({"dag": "a>b", "slak": 1}), "unknown DAG key(s): slak"),
        (lambda: ObjectiveGraph.from_toml("dag = "), "bad TOML"),
        (lambda: ObjectiveGraph.parse("a>b").parents("q"), "unknown objective 'q'"),
    ],
)
def test_malformed_input_names_the_problem(build, message):
    with pytest.raises(GraphError) as err:
        build()
    assert message in str(err.value)
