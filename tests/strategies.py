"""Hypothesis strategies: small random TMDPs and DAGs over four objectives."""

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from tpo.graph import ObjectiveGraph
from tpo.tabular import TabularTMDP

# Solver properties: no deadline (a solve takes milliseconds to seconds); models are
# filtered (assume) where a property needs a feasible problem.
SOLVER_SETTINGS = settings(max_examples=60, deadline=None,
                           suppress_health_check=[HealthCheck.filter_too_much])
NAMES = ("a", "b", "c", "d")
SHAPES = {
    "chain": "a>b>c>d",
    "fan": "a>d, b>d, c>d",
    "diamond": "a>b, a>c, b>d, c>d",
    "mixed": "a>b>d, c>d",
}


@st.composite
def models(draw, max_states: int = 6, max_actions: int = 3) -> TabularTMDP:
    """A random model: small integer rewards (so ties happen), 1–2 successors per action,
    some terminal states."""
    n_states = draw(st.integers(2, max_states))
    n_actions = draw(st.integers(2, max_actions))
    branching = draw(st.integers(1, 2))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    succ = rng.integers(0, n_states, size=(n_states, n_actions, branching))
    probs = rng.dirichlet(np.ones(branching), size=(n_states, n_actions))
    probs = np.round(probs, 2)
    probs[..., -1] = 1.0 - probs[..., :-1].sum(-1)
    rewards = rng.integers(-2, 3, size=(n_states, n_actions, len(NAMES))).astype(float)
    terminal = rng.random(n_states) < 0.25
    terminal[0] = False
    rewards[terminal] = 0.0
    gamma = draw(st.sampled_from([0.0, 0.5, 0.9]))
    return TabularTMDP(succ, probs, rewards, NAMES, gamma=gamma, start=0, terminal=terminal)


@st.composite
def graphs(draw, shapes=tuple(SHAPES)) -> ObjectiveGraph:
    shape = draw(st.sampled_from(shapes))
    graph = ObjectiveGraph.parse(SHAPES[shape])
    slack = draw(st.lists(st.sampled_from([0.0, 0.5, 2.0]), min_size=len(graph.edges),
                          max_size=len(graph.edges)))
    return graph.with_slack(slack)
