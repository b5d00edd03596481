"""Property-based fuzzing of the two text inputs users write: DAG specs and maps.
No input may crash them with anything but the project's own error type."""

import contextlib
import string

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tpo.envs.maps import map_from_dict, parse_map
from tpo.errors import TPOError
from tpo.graph import ObjectiveGraph

NAMES = ("goal", "avoid", "monitor")
SPEC_CHARS = "GAMgam>, ;-<x\t\n" + string.digits
SLACK = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 5),
                  st.lists(st.floats(allow_nan=True), max_size=4), st.text(max_size=3),
                  st.none(), st.booleans())


@settings(max_examples=400, deadline=None)
@given(spec=st.text(alphabet=SPEC_CHARS, max_size=24), slack=SLACK)
def test_dag_parser_raises_only_its_own_errors(spec, slack):
    try:
        graph = ObjectiveGraph.parse(spec, slack, objectives=NAMES)
    except TPOError:
        return
    assert graph.leaf in NAMES
    assert ObjectiveGraph.parse(graph.spec, list(graph.slacks), objectives=NAMES) == graph


@settings(max_examples=200, deadline=None)
@given(spec=st.text(max_size=30))
def test_dag_parser_survives_any_unicode(spec):
    with contextlib.suppress(TPOError):
        ObjectiveGraph.parse(spec, 0.0)


GRID_CHARS = "#.SGx \t"
VALUES = st.one_of(st.integers(-3, 40), st.floats(allow_nan=True), st.text(max_size=4),
                   st.booleans(), st.none())
RECTS = st.one_of(VALUES, st.lists(st.one_of(VALUES, st.lists(VALUES, max_size=5)),
                                   max_size=3))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rows=st.lists(st.text(alphabet=GRID_CHARS, min_size=0, max_size=8), max_size=6),
       extra=st.dictionaries(st.sampled_from(["avoid", "monitor", "max_steps", "start",
                                              "goal", "name", "description", "other"]),
                             RECTS, max_size=3))
def test_map_loader_raises_only_its_own_errors(rows, extra):
    data = {"grid": "\n".join(rows), **extra}
    try:
        navmap = map_from_dict(data)
    except TPOError:
        return
    assert navmap.walls.shape[0] >= 1 and not navmap.walls[navmap.start]


@settings(max_examples=200, deadline=None)
@given(text=st.text(max_size=60))
def test_map_text_survives_any_unicode(text):
    with contextlib.suppress(TPOError):
        parse_map(text)
