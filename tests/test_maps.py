"""Navigation maps: loading, every bad map, and the exact grid model's dynamics and rewards."""

import numpy as np
import pytest

from tpo.envs import OBJECTIVES, bundled_maps, grid_model, load_map, parse_map
from tpo.errors import MapError, ModelError
from tpo.graph import ObjectiveGraph
from tpo.tabular import evaluate_policy, solve_lar

TINY = '''
name = "tiny"
max_steps = 20
grid = """
#####
#S.G#
#...#
#####
"""
avoid = [[1, 2, 1, 2]]
monitor = [[2, 1, 2, 3]]
'''


def test_bundled_maps_load():
    assert "home" in bundled_maps()
    for name in bundled_maps():
        m = load_map(name)
        assert m.name == name
        assert not m.walls[m.start] and not m.walls[m.goal]


def test_home_map_objectives_conflict():
    """The shortest way crosses the avoid room and the monitor room lies off it."""
    grid = grid_model(load_map("home"), gamma=0.99)
    fastest = solve_lar(grid.model, ObjectiveGraph.parse("goal"))
    path = grid.rollout(fastest.policy)
    home = grid.navmap
    assert home.avoid_mask[path[:, 0], path[:, 1]].any()
    assert not home.monitor_mask[path[:, 0], path[:, 1]].any()
    detour = solve_lar(grid.model, ObjectiveGraph.parse("A>G", 0, objectives=OBJECTIVES))
    assert len(grid.rollout(detour.policy)) > len(path)


def test_tiny_map_parses():
    m = parse_map(TINY)
    assert m.shape == (4, 5) and m.start == (1, 1) and m.goal == (1, 3)
    assert m.avoid_mask.sum() == 1 and m.monitor_mask.sum() == 3
    assert parse_map(m.to_toml()).to_toml() == m.to_toml()


def test_start_and_goal_may_be_keys():
    text = TINY.replace("#S.G#", "#...#") + "start = [1, 1]\ngoal = [1, 3]\n"
    m = parse_map(text)
    assert m.start == (1, 1) and m.goal == (1, 3)


def variant(old: str, new: str) -> str:
    assert old in TINY
    return TINY.replace(old, new)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (variant("#...#\n", "#....#\n"), "ragged grid: row 2 has 6 cells, row 0 has 5"),
        (variant("#...#\n", "#.x.#\n"), "unknown character(s) 'x' in grid row 2"),
        (variant("#S.G#", "#..G#"), "exactly one 'S' (start), found no"),
        (variant("#...#\n", "#S..#\n"), "exactly one 'S' (start), found 2"),
        (variant("#S.G#", "#S..#"), "exactly one 'G' (goal), found no"),
        (variant("#...#\n", "#.GG#\n"), "exactly one 'G' (goal), found 3"),
        (variant("#S.G#", "#..G#") + "start = [0, 0]\n", "start [0, 0] is on a wall"),
        (variant("#S.G#", "#S..#") + "goal = [3, 4]\n", "goal [3, 4] is on a wall"),
        (variant("#S.G#", "#S..#") + "goal = [9, 9]\n", "goal [9, 9] is outside the 4x5 grid"),
        (variant("#S.G#", "#S..#") + "goal = [1, 3]\nstart = [1, 1]\n",
         "start given both as 'S' in the grid and as a 'start' key"),
        (variant("avoid = [[1, 2, 1, 2]]", "avoid = [[1, 3, 1, 2]]"),
         "avoid rectangle [1, 3, 1, 2] is inverted"),
        (variant("monitor = [[2, 1, 2, 3]]", "monitor = [[2, 1, 4, 3]]"),
         "monitor rectangle [2, 1, 4, 3] lies outside the 4x5 grid"),
        (variant("avoid = [[1, 2, 1, 2]]", "avoid = [[1, 2, 1]]"), "must be 4 integers"),
        (variant("avoid = [[1, 2, 1, 2]]", "avoid = 3"), "'avoid' must be a list"),
        (variant("#S.G#\n#...#", "#S#G#\n###.#"), "goal [1, 3] is unreachable from start [1, 1]"),
        (variant("max_steps = 20", "max_steps = 0"), "max_steps must be an integer from 1 to"),
        (variant("max_steps = 20", "max_step = 20"), "unknown key(s) max_step"),
        (variant('name = "tiny"', 'name = "tiny'), "bad TOML"),
        ('name = "x"\n', "needs a 'grid' string"),
        ('grid = """\n\n"""\n', "empty grid"),
    ],
)
def test_bad_maps_are_rejected_with_a_clear_message(text, message):
    with pytest.raises(MapError) as err:
        parse_map(text, "bad.toml")
    assert message in str(err.value)
    assert str(err.value).startswith("bad.toml: ")


def test_unknown_map_name():
    with pytest.raises(MapError, match="no bundled map or file named 'nowhere'"):
        load_map("nowhere")


def test_grid_model_dynamics_and_rewards_by_hand():
    grid = grid_model(parse_map(TINY), gamma=0.5)
    model = grid.model
    s = grid.index
    start = s[1, 1]
    assert model.start == start
    # From the start: up and left bump (stay), right moves into the avoid cell, down to (2, 1).
    assert model.successors[start, :, 0].tolist() == [start, s[2, 1], start, s[1, 2]]
    # goal -1 always; avoid -1 per bump (start is outside avoid); monitor -1 per bump.
    assert model.rewards[start, :, 0].tolist() == [-1, -1, -1, -1]
    assert model.rewards[start, :, 1].tolist() == [-1, 0, -1, 0]
    assert model.rewards[start, :, 2].tolist() == [-1, 0, -1, 0]
    # In the avoid cell (1, 2): -1 avoid per step, plus the bump going up.
    assert model.rewards[s[1, 2], :, 1].tolist() == [-2, -1, -1, -1]
    # In the monitor row (2, 2): +1 monitor per step, -1 bumping down.
    assert model.rewards[s[2, 2], :, 2].tolist() == [1, 0, 1, 1]
    assert model.terminal.tolist() == [i == s[1, 3] for i in range(model.n_states)]
    assert model.objectives == OBJECTIVES
    assert not model.rewards[s[1, 3]].any()


def test_slip_spreads_over_the_other_directions():
    grid = grid_model(parse_map(TINY), gamma=0.5, slip=0.3)
    model, s = grid.model, grid.index
    start = s[1, 1]
    # Action right: 0.7 right, 0.1 each of up/down/left. up and left bump.
    succ, probs = model.successors[start, 3], model.probs[start, 3]
    dist = {}
    for nxt, p in zip(succ, probs, strict=True):
        dist[int(nxt)] = dist.get(int(nxt), 0) + p
    assert dist == pytest.approx({s[1, 2]: 0.7, s[2, 1]: 0.1, start: 0.2})
    assert model.rewards[start, 3, 1] == pytest.approx(-0.2)  # expected bumps


def test_slip_must_be_a_probability():
    with pytest.raises(MapError, match="slip must be a probability"):
        grid_model(parse_map(TINY), slip=1.5)
    with pytest.raises(ModelError, match="gamma must be"):
        grid_model(parse_map(TINY), gamma=1.0)


def test_tiny_map_values_by_hand():
    # Fastest: right, right = 2 steps: V_goal = -1 - 0.5 = -1.5 at gamma 0.5.
    grid = grid_model(parse_map(TINY), gamma=0.5)
    sol = solve_lar(grid.model, ObjectiveGraph.parse("goal"))
    assert sol.start_values()["goal"] == pytest.approx(-1.5)
    # Through the avoid cell: avoid pays -1 at the second step: -0.5.
    assert sol.start_policy_values()["avoid"] == pytest.approx(-0.5)
    # Avoid first at slack 0: go down, right, right, up = 4 steps, never in avoid.
    sol = solve_lar(grid.model, ObjectiveGraph.parse("A>G", 0, objectives=OBJECTIVES))
    assert sol.start_policy_values()["avoid"] == pytest.approx(0.0)
    assert sol.start_policy_values()["goal"] == pytest.approx(-(1 + 0.5 + 0.25 + 0.125))
    cells = grid.rollout(sol.policy)
    assert [tuple(c) for c in cells] == [(1, 1), (2, 1), (2, 2), (2, 3), (1, 3)]
    # Monitor's +1 in row 2 is worth 0.5 * 1 + 0.25 * 1 + 0.125 * 1 = 0.875 on that path.
    assert evaluate_policy(grid.model, sol.policy)[grid.model.start, 2] == pytest.approx(0.875)
    assert np.allclose(sol.policy_values["monitor"][grid.model.start], 0.875)
