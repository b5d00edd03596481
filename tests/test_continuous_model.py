"""The continuous env's finite reference TMDP: lattice, bilinear transitions, values
worked out by hand, and the judgement of a continuous policy against it."""

from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from tpo.algo.distributions import Categorical
from tpo.algo.evaluate import reference_evaluation
from tpo.envs import load_map, parse_map
from tpo.envs.continuous import ContinuousNav
from tpo.envs.continuous_model import RESOLUTION, continuous_model, path_category
from tpo.errors import MapError
from tpo.graph import ObjectiveGraph
from tpo.tabular import solve_lar

CORRIDOR = '''
grid = """
#######
#S...G#
#######
"""
avoid = [[1, 3, 1, 3]]
'''
GAMMA = 0.9


@pytest.fixture(scope="module")
def corridor():
    return ContinuousNav(parse_map(CORRIDOR), action="heading", speed=0.5)


def test_the_lattice_has_resolution_squared_points_per_free_cell_and_starts_at_the_centre(
        corridor):
    ref = continuous_model(corridor, GAMMA, resolution=2)
    assert ref.model.n_states == 5 * 4
    assert ref.points[ref.model.start].tolist() == [1.5, 1.5]
    goal = np.floor(ref.points).astype(int)[:, 1] == 5
    assert ref.model.terminal.tolist() == goal.tolist()
    np.testing.assert_allclose(ref.model.probs.sum(-1), 1.0)


def test_heading_right_reaches_the_goal_in_hand_counted_steps(corridor):
    """From column 1.5 at 0.5 per step the goal cell (column 5) is 7 steps away,
    through the avoid cell (3): steps 4 and 5 start in it."""
    ref = continuous_model(corridor, GAMMA, resolution=2)
    sol = solve_lar(ref.model, ObjectiveGraph.parse("goal", objectives=ref.model.objectives))
    values = sol.start_policy_values()
    assert values["goal"] == pytest.approx(-sum(GAMMA**t for t in range(7)))
    assert values["avoid"] == pytest.approx(-(GAMMA**3 + GAMMA**4))
    # Avoid first at slack 0: staying out of the avoid cell, the goal is never reached.
    lex = solve_lar(ref.model, ObjectiveGraph.parse("A>G", 0, objectives=ref.model.objectives))
    assert lex.start_policy_values()["avoid"] == pytest.approx(0.0)
    assert lex.start_policy_values()["goal"] == pytest.approx(-1 / (1 - GAMMA))
    assert ref.category(sol.policy) == {"reaches_goal": True, "enters_avoid": True,
                                        "ends_in_monitor": False}


def test_an_end_point_between_lattice_points_is_split_bilinearly():
    """Heading 1 (up-right) from (1.5, 1.5) at speed 0.5 ends 0.354 up and right:
    on a lattice of 0.5, 0.707 of the way to the next point along each axis."""
    env = ContinuousNav(parse_map(CORRIDOR.replace("#S...G#\n", "#S...G#\n#.....#\n")),
                        action="heading", speed=0.5)
    ref = continuous_model(env, GAMMA, resolution=2)
    s, a = ref.model.start, 3  # heading 3: down-right
    f = 0.5 / np.sqrt(2) / 0.5
    expected = {(1.5, 1.5): (1 - f) ** 2, (2.0, 1.5): f * (1 - f), (1.5, 2.0): (1 - f) * f,
                (2.0, 2.0): f * f}
    got = {}
    for nxt, p in zip(ref.model.successors[s, a], ref.model.probs[s, a], strict=True):
        if p > 0:
            got[tuple(ref.points[nxt].tolist())] = p
    assert got == pytest.approx(expected)


def test_velocity_reference_offers_headings_and_standing_still(corridor):
    env = ContinuousNav(parse_map(CORRIDOR), speed=0.5)
    ref = continuous_model(env, GAMMA, resolution=2, n_headings=8)
    assert ref.actions.shape == (9, 2) and not ref.actions[-1].any()
    s = ref.model.start
    assert ref.model.successors[s, 8, 0] == s and ref.model.probs[s, 8, 0] == 1.0


def test_the_default_lattice_resolves_a_crossing_along_a_wall():
    """On hall, M>A>G at slack 0 crosses the rug hugging the wall above it, in the top
    fifth of a cell: 4 points a cell smear that path into the rug (avoid -8.83), the
    default 8 gets -7.27, within 0.1 of 16 points' -7.20 (and of -7.22, a noise-free
    rollout in the env greedy on the 8-lattice's values)."""
    env = ContinuousNav(load_map(Path(__file__).parents[1] / "benchmarks/maps/hall.toml"))
    graph = ObjectiveGraph.parse("M>A>G", [0.0], objectives=env.objectives)

    def avoid(resolution):
        ref = continuous_model(env, 0.99, resolution=resolution)
        return solve_lar(ref.model, graph).start_policy_values()["avoid"]

    assert RESOLUTION == 8
    assert avoid(RESOLUTION) == pytest.approx(-7.27, abs=0.01)
    assert avoid(4) < -8.8


@pytest.mark.parametrize("resolution", [3, 0, 1.0])
def test_bad_resolutions_are_refused(corridor, resolution):
    with pytest.raises(MapError, match="resolution must be an even number"):
        continuous_model(corridor, GAMMA, resolution=resolution)


def test_path_category_reads_the_cells_of_a_path():
    navmap = parse_map(CORRIDOR)
    assert path_category(navmap, np.array([[1.5, 1.5], [1.5, 2.9]])) == {
        "reaches_goal": False, "enters_avoid": False, "ends_in_monitor": False}
    assert path_category(navmap, np.array([[1.5, 3.1], [1.5, 5.2]]))["reaches_goal"]


def test_a_policy_heading_right_is_judged_correct_and_one_standing_is_not(corridor):
    graph = ObjectiveGraph.parse("goal", objectives=corridor.objectives)

    def heading(index):
        return lambda params, obs: Categorical(jnp.zeros(obs.shape[:-1] + (8,)).at[
            ..., index].set(5.0))

    right = reference_evaluation(heading(2), None, corridor, graph, GAMMA)
    assert right["lar_correct"] and right["path_matches"]
    assert right["mc_noise_free"]["goal"] == pytest.approx(-sum(GAMMA**t for t in range(7)),
                                                           rel=1e-5)
    up = reference_evaluation(heading(0), None, corridor, graph, GAMMA)  # bumps forever
    assert not up["lar_correct"] and not up["path_matches"]
    assert up["path"] == {"reaches_goal": False, "enters_avoid": False,
                          "ends_in_monitor": False}
