"""The continuous-space navigation env: moves, collisions, rewards, range sensors."""

import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tpo.envs import from_spec, load_map, parse_map
from tpo.envs.continuous import ContinuousNav, ContinuousState, headings
from tpo.errors import MapError
from tpo.sensing import (
    blocked,
    cell_features,
    pad_walls,
    place_features,
    range_readings,
    ray_distances,
)

ROOM = '''
max_steps = 6
grid = """
######
#S...#
#..#.#
#...G#
######
"""
avoid = [[1, 2, 1, 2]]
monitor = [[3, 1, 3, 2]]
'''


def play(env, actions):
    _, state = env.reset(jax.random.key(0), env.params)
    step = jax.jit(env.step_env)
    out = []
    for i, a in enumerate(actions):
        obs, state, reward, term, trunc = step(jax.random.key(i), state, jnp.asarray(a),
                                               env.params)
        out.append((np.asarray(state.pos).tolist(), np.asarray(reward).tolist(), bool(term),
                    bool(trunc), np.asarray(obs)))
    return out


@pytest.fixture(scope="module")
def room():
    return ContinuousNav(parse_map(ROOM), speed=0.5, max_range=4.0)


def test_velocity_moves_and_rewards(room):
    steps = play(room, [[0.0, 1.0], [0.0, 1.0], [0.0, 1.0]])
    assert [s[0] for s in steps] == [[1.5, 2.0], [1.5, 2.5], [1.5, 3.0]]
    # Rewards are paid on the cell where the step starts: (1,1), (1,2) in avoid, (1,2).
    assert [s[1] for s in steps] == [[-1, 0, 0], [-1, -1, 0], [-1, -1, 0]]


def test_long_velocity_is_scaled_to_speed(room):
    (pos, *_), = play(room, [[1.0, 1.0]])
    assert np.allclose(pos, np.array([1.5, 1.5]) + 0.5 / np.sqrt(2))


def test_walls_and_the_border_bump(room):
    steps = play(room, [[-1.0, 0.0], [-1.0, 0.0]])  # up from row 1.5: 1.0 is free, 0.5 is wall
    assert steps[0][0] == [1.0, 1.5] and steps[0][1] == [-1, 0, 0]
    assert steps[1][0] == [1.0, 1.5] and steps[1][1] == [-1, -1, -1]


def test_no_corner_cutting(room):
    # From cell (1, 3) diagonally down-left into the free cell (2, 2) would slip past the
    # corner of the wall at (2, 3): it bumps. The same move one column left is fine.
    _, state = room.reset(jax.random.key(0), room.params)
    move = jnp.array([1.0, -1.0])
    _, nxt, reward, *_ = room.step_env(jax.random.key(0), state.replace(pos=jnp.array([1.9, 3.1])),
                                       move, room.params)
    assert np.allclose(np.asarray(nxt.pos), [1.9, 3.1]) and float(reward[1]) == -1.0
    _, nxt, reward, *_ = room.step_env(jax.random.key(0), state.replace(pos=jnp.array([1.9, 2.1])),
                                       move, room.params)
    assert np.allclose(np.asarray(nxt.pos), [1.9 + 0.5**1.5, 2.1 - 0.5**1.5])


def test_heading_actions(room):
    env = ContinuousNav(parse_map(ROOM), action="heading", speed=0.5)
    steps = play(env, [2, 4])  # right, then down
    assert steps[0][0] == [1.5, 2.0]
    assert steps[1][0] == [2.0, 2.0]
    assert np.allclose(headings(4), [[-1, 0], [0, 1], [1, 0], [0, -1]], atol=1e-6)


def test_goal_terminates_with_the_grid_rewards():
    env = ContinuousNav(parse_map(ROOM), speed=1.0)
    steps = play(env, [[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 1.0], [0.0, 1.0]])
    assert [s[0] for s in steps] == [[2.5, 1.5], [3.5, 1.5], [3.5, 2.5], [3.5, 3.5], [3.5, 4.5]]
    # Steps start in (1,1), (2,1), (3,1) and (3,2) (monitor), (3,3).
    assert [s[1] for s in steps] == [[-1, 0, 0], [-1, 0, 0], [-1, 0, 1], [-1, 0, 1], [-1, 0, 0]]
    assert [s[2] for s in steps] == [False] * 4 + [True]


def test_time_limit_truncates():
    env = ContinuousNav(parse_map(ROOM), speed=1.0)  # max_steps = ceil(6 / speed) = 6
    steps = play(env, [[-1.0, 0.0]] * 6)
    assert [s[3] for s in steps] == [False] * 5 + [True]
    assert not any(s[2] for s in steps)


def test_range_sensors_by_hand(room):
    obs, _ = room.reset(jax.random.key(0), room.params)
    obs = np.asarray(obs)
    assert np.allclose(obs[:2], [1.5 / 5, 1.5 / 6])
    beams = obs[2:10] * 4.0  # max_range 4
    # Up and left: the wall face at 1.0 is 0.5 away; right: 3.5 to column 5; down: 2.5.
    assert np.allclose(beams[[0, 2, 4, 6]], [0.5, 3.5, 2.5, 0.5])
    assert beams[1] == pytest.approx(np.sqrt(0.5), abs=0.15)  # up-right, sampled every 0.2
    assert obs[10:12].tolist() == [0.0, 0.0]  # not in avoid or monitor
    # The factored observation's tents: the centre of cell (1, 1) is its row's and
    # column's one-hot (the map is 5 x 6).
    assert obs[12:].tolist() == [0, 1, 0, 0, 0] + [0, 1, 0, 0, 0, 0]
    coords = ContinuousNav(room.navmap, max_range=4.0, observation="coords")
    assert coords.obs_shape == (12,) and room.obs_shape == (12 + 5 + 6,)
    assert np.array_equal(np.asarray(coords.reset(jax.random.key(0), coords.params)[0]),
                          obs[:12])


def test_cell_features_by_hand():
    # Between the centres of rows 1 and 2, a quarter of the way from column 1's centre
    # to column 0's: the tents share the weight linearly.
    f = cell_features(np.array([2.0, 1.25], np.float32), (4, 3))
    assert np.allclose(f, [0, 0.5, 0.5, 0] + [0.25, 0.75, 0])
    # Any position's row tents and column tents each sum to one inside the centres.
    f = cell_features(np.array([1.9, 0.7], np.float32), (4, 3))
    assert np.isclose(f[:4].sum(), 1.0) and np.isclose(f[4:].sum(), 1.0)


def test_place_features_by_hand(room):
    # At cell (1, 1)'s centre: its one-hot. Between the centres of rows 1 and 2, a
    # quarter of the way from column 1's centre to column 0's: the bilinear weights
    # of the four nearest centres (row 1 or 2 by 0.5, column 1 by 0.75 or 0 by 0.25).
    assert place_features(np.array([1.5, 1.5], np.float32), (4, 3)).tolist() == [
        0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0]
    f = place_features(np.array([2.0, 1.25], np.float32), (4, 3)).reshape(4, 3)
    assert np.allclose(f, [[0, 0, 0], [0.125, 0.375, 0], [0.125, 0.375, 0], [0, 0, 0]])
    # The env's observation: the factored one's, then these (5 x 6 map).
    places = ContinuousNav(room.navmap, max_range=4.0, observation="factored+onehot")
    assert places.observation == "factored+onehot"
    assert places.obs_shape == (room.obs_shape[0] + 30,)
    obs = np.asarray(places.reset(jax.random.key(0), places.params)[0])
    assert np.array_equal(obs[:room.obs_shape[0]],
                          np.asarray(room.reset(jax.random.key(0), room.params)[0]))
    assert obs[room.obs_shape[0]:].reshape(5, 6)[1, 1] == 1 and obs[-30:].sum() == 1
    assert from_spec(places.to_spec()).obs_shape == places.obs_shape


def test_auto_is_the_place_tents_up_to_place_cells_cells_and_a_run_s_default():
    from tpo.envs.continuous import PLACE_CELLS
    from tpo.experiments.runspec import RunSpec

    wide = PLACE_CELLS // 6 + 1  # 4 rows inside a border: more than PLACE_CELLS cells
    big = parse_map('grid = """\n' + "\n".join(
        ["#" * wide, "#S" + "." * (wide - 3) + "#", *["#" + "." * (wide - 2) + "#"] * 2,
         "#" + "." * (wide - 3) + "G#", "#" * wide]) + '\n"""\n')
    assert big.shape == (6, wide) and 6 * wide > PLACE_CELLS
    env = ContinuousNav(big, observation="auto")
    assert env.observation == "factored" and env.obs_shape == (4 + 8 + 6 + wide,)
    assert from_spec(env.to_spec()).observation == "factored"
    home = ContinuousNav(load_map("home"), observation="auto")
    assert home.observation == "factored+onehot" and home.obs_shape == (4 + 8 + 41 + 330,)
    run = RunSpec.from_settings({"dynamics": "continuous", "map": "home"})
    assert run.model().env.observation == "factored+onehot"


def test_bad_settings_are_rejected():
    m = load_map("home")
    with pytest.raises(MapError, match="unknown action kind 'torque'"):
        ContinuousNav(m, action="torque")
    with pytest.raises(MapError, match="unknown continuous observation 'onehot'"):
        ContinuousNav(m, observation="onehot")
    with pytest.raises(MapError, match="speed must be in"):
        ContinuousNav(m, speed=1.5)
    with pytest.raises(MapError, match="noise must be"):
        ContinuousNav(m, noise=-1.0)


@pytest.mark.parametrize("xp", [np, jnp])
def test_blocked_is_off_the_map_or_in_a_wall_by_hand(xp):
    """One flat gather in the padded walls (tpo.sensing) gives what the definition
    says, on a map whose edge is open: off the map, however far, is blocked."""
    walls = np.array([[False, True, False],
                      [False, False, False]])
    points = np.array([[0.5, 0.5], [0.5, 1.99], [1.99, 2.99], [0.0, 1.0],  # free, wall, free, wall
                       [-0.01, 0.5], [2.0, 0.5], [1.5, 3.0], [1.5, -1e-6],  # just off each edge
                       [-1e9, 1e9], [1e9, 0.5], [0.5, -7.5]], np.float32)  # far off
    padded = xp.asarray(pad_walls(walls))
    assert padded.shape == (4, 5)
    got = np.asarray(blocked(xp.asarray(points), padded, xp)).tolist()
    assert got == [False, True, False, True] + [True] * 7


@pytest.mark.parametrize("xp", [np, jnp])
def test_range_readings_by_hand(xp):
    """From (1.5, 0.5) on a 3 x 4 map with a wall at (1, 3), beams clockwise from up,
    samples every 0.2: the first blocked sample less half a step. Up: row 1.5 - t
    leaves the map at t = 1.6; right: column 0.5 + t enters the wall at 2.6; down-left
    and up-left leave through column -1 at 0.8, left at 0.6; the down-right and
    up-right diagonals leave through row 3 and row -1 at 2.2."""
    walls = np.zeros((3, 4), bool)
    walls[1, 3] = True
    got = range_readings(xp.asarray(np.array([1.5, 0.5], np.float32)),
                         xp.asarray(pad_walls(walls)), xp.asarray(headings(8)),
                         xp.asarray(ray_distances(6.0)), xp)
    np.testing.assert_allclose(np.asarray(got), [1.5, 2.1, 2.5, 2.1, 1.5, 0.7, 0.5, 0.7],
                               atol=1e-5)


@pytest.mark.parametrize("xp", [np, jnp])
def test_range_readings_are_the_first_blocked_sample(xp):
    """Equivalence with the definition, sample by sample along every beam with
    :func:`blocked`, at 3000 positions on ``home`` (a third on the 0.1 lattice, so
    on cell edges), with a short and a long reach."""
    navmap = load_map("home")
    rng = np.random.default_rng(0)
    free = np.argwhere(~navmap.walls)
    pos = (free[rng.integers(len(free), size=3000)] + rng.random((3000, 2))).astype(np.float32)
    pos[:1000] = np.floor(pos[:1000] * 10) / 10
    padded, beams = pad_walls(navmap.walls), headings(8)
    for reach in (2.0, 6.0):
        ray_t = ray_distances(reach)
        hit = blocked(pos[:, None, None] + beams[:, None, :] * ray_t[None, :, None], padded)
        first = np.where(hit.any(-1), ray_t[hit.argmax(-1)] - 0.1, ray_t[-1])  # [N, K]
        if xp is np:
            readings = [range_readings(p, padded, beams, ray_t) for p in pos]
        else:  # as the env computes them: vmapped, jitted
            readings = jax.jit(jax.vmap(lambda p, t=ray_t: range_readings(
                p, jnp.asarray(padded), jnp.asarray(beams), jnp.asarray(t), jnp)))(pos)
        np.testing.assert_array_equal(np.asarray(readings), first)


def test_what_was_saved_before_the_factored_observation_reads_as_coords():
    """A continuous env spec, a run's settings and an exported observer written before
    the factored observation existed mean the coordinates alone; new ones say which."""
    from tpo.deploy import _observer
    from tpo.experiments.runspec import RunSpec

    env = ContinuousNav(load_map("small"))
    spec = env.to_spec()
    assert spec["observation"] == "factored" and from_spec(spec).observation == "factored"
    old = {k: v for k, v in spec.items() if k != "observation"}
    assert from_spec(old).observation == "coords"
    assert RunSpec.from_settings({"dynamics": "continuous"}, saved=True).observation == "coords"
    assert RunSpec.from_settings({"dynamics": "continuous"}).observation == "auto"
    run = RunSpec.from_settings({"dynamics": "continuous", "observation": "coords"})
    assert RunSpec.from_settings(tomllib.loads(run.to_toml()), saved=True) == run
    arrays = {f"observer/{n}": np.asarray(getattr(env.params, n)) for n in
              ("avoid", "monitor", "beams", "ray_t")}
    arrays["observer/walls"] = np.asarray(env.navmap.walls)
    assert not _observer("continuous", arrays).factored
    assert _observer("continuous", {**arrays, "observer/factored": np.asarray(True)}).factored


def test_the_deployed_observer_computes_the_place_tents():
    from tpo.deploy import _observer

    env = ContinuousNav(load_map("small"), observation="factored+onehot")
    arrays = {f"observer/{n}": np.asarray(getattr(env.params, n)) for n in
              ("avoid", "monitor", "beams", "ray_t", "factored", "places")}
    arrays["observer/walls"] = np.asarray(env.navmap.walls)
    pos = np.asarray(env.navmap.start, np.float32) + [0.3, 0.7]
    state = ContinuousState(pos=jnp.asarray(pos), time=jnp.int32(0))
    np.testing.assert_allclose(_observer("continuous", arrays).observe(pos),
                               np.asarray(env.observe(state, env.params)), atol=1e-6)
