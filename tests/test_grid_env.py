"""The JAX grid environment: API, dynamics, auto-reset, and agreement with the exact model."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tpo.envs import load_map, parse_map
from tpo.envs.grid import OBSERVATIONS, ONEHOT_CELLS, GridNav, observation_table
from tpo.errors import MapError
from tpo.tabular import evaluate_policy, softmax

TINY = '''
max_steps = 5
grid = """
#####
#S.G#
#...#
#####
"""
avoid = [[1, 2, 1, 2]]
monitor = [[2, 1, 2, 3]]
'''
UP, DOWN, LEFT, RIGHT = range(4)


@pytest.fixture(scope="module")
def tiny():
    return GridNav(parse_map(TINY, "tiny.toml"))


def run(env, actions, key=0):
    _, state = env.reset(jax.random.key(key), env.params)
    out = []
    step = jax.jit(env.step)
    for i, a in enumerate(actions):
        _, state, reward, term, trunc, info = step(jax.random.key(i), state,
                                                     jnp.int32(a), env.params)
        out.append((np.asarray(state.pos).tolist(), np.asarray(reward).tolist(), bool(term),
                    bool(trunc), info))
    return out


def test_rewards_termination_and_auto_reset(tiny):
    steps = run(tiny, [UP, RIGHT, RIGHT])
    assert steps[0][:4] == ([1, 1], [-1, -1, -1], False, False)  # bump: stays
    assert steps[1][:4] == ([1, 2], [-1, 0, 0], False, False)
    # Leaving the avoid cell costs avoid -1; reaching the goal terminates and resets.
    assert steps[2][:4] == ([1, 1], [-1, -1, 0], True, False)
    final = np.asarray(steps[2][4]["final_obs"])
    assert np.array_equal(final, tiny.params.obs_table[1, 3])


def test_truncation_is_kept_apart_from_termination(tiny):
    steps = run(tiny, [DOWN, UP, DOWN, UP, DOWN])
    assert [s[2:4] for s in steps] == [(False, False)] * 4 + [(False, True)]
    assert steps[-1][0] == [1, 1]  # reset to the start after truncation
    assert np.array_equal(np.asarray(steps[-1][4]["final_obs"]), tiny.params.obs_table[2, 1])


def test_monitor_reward_is_paid_on_the_state_where_the_step_starts(tiny):
    steps = run(tiny, [DOWN, RIGHT, DOWN])
    assert [s[1] for s in steps] == [[-1, 0, 0], [-1, 0, 1], [-1, -1, 0]]


def test_slip_moves_in_another_direction_at_the_configured_rate():
    env = GridNav(parse_map(TINY), slip=0.6)
    _, state = env.reset(jax.random.key(0), env.params)
    keys = jax.random.split(jax.random.key(1), 20000)
    step = jax.vmap(env.step_env, in_axes=(0, None, None, None))
    _, nxt, *_ = step(keys, state, jnp.int32(RIGHT), env.params)
    pos = np.asarray(nxt.pos)
    right = np.mean((pos == [1, 2]).all(1))
    down = np.mean((pos == [2, 1]).all(1))
    stay = np.mean((pos == [1, 1]).all(1))  # up or left: bump
    assert right == pytest.approx(0.4, abs=0.015)
    assert down == pytest.approx(0.2, abs=0.015)
    assert stay == pytest.approx(0.4, abs=0.015)


def test_jit_vmap_and_scan():
    env = GridNav(load_map("home"))
    n = 64
    keys = jax.random.split(jax.random.key(0), n)
    obs, states = jax.vmap(env.reset, in_axes=(0, None))(keys, env.params)
    assert obs.shape == (n, *env.obs_shape)

    def body(carry, key):
        states, total = carry
        k_act, k_step = jax.random.split(key)
        actions = jax.random.randint(k_act, (n,), 0, 4)
        _, states, reward, term, trunc, _ = jax.vmap(
            env.step, in_axes=(0, 0, 0, None))(jax.random.split(k_step, n), states, actions,
                                               env.params)
        return (states, total + reward.sum(0)), (term | trunc).sum()

    (states, total), ends = jax.jit(lambda s, k: jax.lax.scan(
        body, (s, jnp.zeros(3)), jax.random.split(k, 450)))(states, jax.random.key(1))
    assert int(ends.sum()) >= n * 2  # every env hit the 200-step limit at least twice
    assert float(total[0]) == -n * 450  # goal pays -1 on every step
    assert np.all(np.asarray(states.time) < 200)


@pytest.mark.parametrize("kind", OBSERVATIONS)
def test_tabular_observations_match_the_env(kind):
    env = GridNav(load_map("home"), observation=kind)
    grid = env.tabular()
    table = env.tabular_observations()
    assert table.shape == (grid.model.n_states, *env.obs_shape)
    for s in [0, 17, grid.model.start, grid.model.n_states - 1]:
        r, c = grid.cells[s]
        state = env.reset(jax.random.key(0), env.params)[1].replace(pos=jnp.array([r, c]))
        assert np.array_equal(np.asarray(env.observe(state, env.params)), table[s])
    assert len(np.unique(table, axis=0)) == len(table)  # every state is told apart


def test_factored_observation_by_hand():
    table = observation_table(parse_map(TINY), "factored")
    # Cell (1, 2): row 1 of 4, column 2 of 5, walls up and down, avoid, no monitor.
    expected = [0, 1, 0, 0] + [0, 0, 1, 0, 0] + [1, 0, 0, 0] + [1, 0]
    assert table[1, 2].tolist() == expected


def test_factored_onehot_observation_by_hand():
    table = observation_table(parse_map(TINY), "factored+onehot")
    # Cell (1, 2): the factored numbers, then the one-hot of free cell 1 of 6
    # (free cells in row-major order: (1, 1), (1, 2), (1, 3), (2, 1), ...).
    assert table.shape == (4, 5, 4 + 5 + 4 + 2 + 6)
    assert table[1, 2].tolist() == [0, 1, 0, 0] + [0, 0, 1, 0, 0] + [1, 0, 0, 0] + [1, 0] + [
        0, 1, 0, 0, 0, 0]
    assert table[2, 3, -6:].tolist() == [0, 0, 0, 0, 0, 1]
    assert not table[0, 0, -6:].any()  # a wall is no free cell


def test_factored_onehot_observation_has_two_views():
    """A population's members may see the free cell's one-hot, or the factored
    numbers, alone: the last 6 and the first 15 of TINY's 21."""
    onehot, factored = GridNav(parse_map(TINY), observation="factored+onehot").observation_views
    assert onehot.tolist() == [False] * 15 + [True] * 6
    assert factored.tolist() == [True] * 15 + [False] * 6
    for kind in ("factored", "onehot", "coords"):
        assert GridNav(parse_map(TINY), observation=kind).observation_views == ()


def test_observations_declare_their_one_hot_blocks():
    """TINY (4 x 5, 6 free cells): the row's one-hot is numbers 0-3, the column's 4-8,
    the free cell's the last 6; each block holds one 1 at every free cell, and the
    cell's block none at a wall."""
    blocks = {kind: GridNav(parse_map(TINY), observation=kind).observation_onehots
              for kind in OBSERVATIONS}
    assert blocks == {"factored": ((0, 4), (4, 9)), "onehot": ((0, 20),), "coords": (),
                      "factored+onehot": ((0, 4), (4, 9), (15, 21))}
    table = observation_table(parse_map(TINY), "factored+onehot")
    free = ~parse_map(TINY).walls
    for a, b in blocks["factored+onehot"]:
        assert (table[free][:, a:b].sum(-1) == 1).all()
        assert set(np.unique(table[..., a:b]).tolist()) == {0.0, 1.0}
    assert not table[~free][:, 15:].any()


def test_auto_observation_adds_the_cell_up_to_a_size():
    """"auto" is factored+onehot up to ONEHOT_CELLS free cells, factored beyond, and
    the env records (and saves) the kind it chose."""
    small = GridNav(load_map("small"))
    assert small.observation == "factored+onehot"
    assert small.to_spec()["observation"] == small.observation
    assert small.obs_shape == (8 + 13 + 6 + 44,)
    side = int(ONEHOT_CELLS**0.5) + 3  # (side - 2)**2 free cells, just over the limit
    room = "\n".join(["#" * side, "#S" + "." * (side - 4) + "G#",
                      *["#" + "." * (side - 2) + "#"] * (side - 3), "#" * side])
    large = GridNav(parse_map(f'grid = """\n{room}\n"""'))
    assert (side - 2) ** 2 > ONEHOT_CELLS
    assert large.observation == "factored" and large.obs_shape == (2 * side + 6,)


def test_unknown_observation_is_an_error():
    with pytest.raises(MapError, match="unknown observation 'pixels'"):
        GridNav(parse_map(TINY), observation="pixels")
    with pytest.raises(MapError, match="unknown observation None; choose one of auto, "):
        GridNav(parse_map(TINY), observation=None)


@pytest.mark.parametrize("slip", [0.0, 0.2])
def test_monte_carlo_returns_agree_with_exact_evaluation(slip):
    """A fixed stochastic policy: discounted MC returns in JAX vs the exact linear solve."""
    gamma, horizon, episodes = 0.95, 400, 4000
    env = GridNav(load_map("home"), slip=slip, max_steps=10_000)
    grid = env.tabular(gamma)
    logits = np.random.default_rng(0).normal(size=(grid.model.n_states, 4)) * 2
    logits[:, RIGHT] += 1.0  # drift towards the goal so that some episodes end
    policy = softmax(logits)
    exact = evaluate_policy(grid.model, policy)[grid.model.start]
    index = jnp.asarray(grid.index)
    log_pi = jnp.log(jnp.asarray(policy))

    def episode(key):
        _, state = env.reset(key, env.params)

        def body(carry, key):
            state, ret, alive, disc = carry
            k_a, k_s = jax.random.split(key)
            action = jax.random.categorical(k_a, log_pi[index[state.pos[0], state.pos[1]]])
            _, state, reward, term, _ = env.step_env(k_s, state, action, env.params)
            ret = ret + alive * disc * reward
            return (state, ret, alive * (1 - term), disc * gamma), None

        init = (state, jnp.zeros(3), jnp.float32(1), jnp.float32(1))
        (_, ret, _, _), _ = jax.lax.scan(body, init, jax.random.split(key, horizon))
        return ret

    returns = np.asarray(jax.jit(jax.vmap(episode))(jax.random.split(jax.random.key(0),
                                                                     episodes)))
    mean, se = returns.mean(0), returns.std(0) / np.sqrt(episodes)
    assert np.all(np.abs(mean - exact) <= 4 * se + 1e-3), (mean, exact, se)


def test_random_starts_cover_every_free_cell_but_the_goal():
    env = GridNav(parse_map(TINY), random_start=True)
    keys = jax.random.split(jax.random.key(0), 400)
    _, states = jax.vmap(env.reset, in_axes=(0, None))(keys, env.params)
    cells = {tuple(p) for p in np.asarray(states.pos).tolist()}
    assert cells == {(1, 1), (1, 2), (2, 1), (2, 2), (2, 3)}  # 6 free cells minus the goal
    fixed = GridNav(parse_map(TINY))
    _, states = jax.vmap(fixed.reset, in_axes=(0, None))(keys, fixed.params)
    assert {tuple(p) for p in np.asarray(states.pos).tolist()} == {(1, 1)}


def test_a_grid_run_saved_before_auto_keeps_the_factored_observation():
    """A grid run's settings without an observation (written before "auto") mean the
    factored one; a new run asks for "auto" and keeps asking for it when resumed."""
    import tomllib

    from tpo.experiments.runspec import RunSpec

    assert RunSpec.from_settings({}, saved=True).observation == "factored"
    run = RunSpec.from_settings({})
    assert run.observation == "auto" and run.model().env.observation == "factored+onehot"
    assert RunSpec.from_settings(tomllib.loads(run.to_toml()), saved=True) == run
