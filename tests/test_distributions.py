"""The policy's distributions against numbers worked out by hand, and the episode
statistics' pure update on JAX and NumPy arrays alike."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tpo.algo.distributions import Categorical, DiagGaussian, Discretized
from tpo.algo.episodes import EpisodeStats


def test_categorical_by_hand():
    # logits log(1, 2, 1): probabilities (1/4, 1/2, 1/4)
    pi = Categorical(jnp.log(jnp.array([[1.0, 2.0, 1.0]])))
    assert pi.mode().tolist() == [1]
    assert float(pi.log_prob(jnp.array([0]))[0]) == pytest.approx(np.log(0.25), abs=1e-6)
    h = -(2 * 0.25 * np.log(0.25) + 0.5 * np.log(0.5))  # 1.0397
    assert float(pi.entropy()[0]) == pytest.approx(h, abs=1e-6)
    draws = jax.vmap(pi.sample)(jax.random.split(jax.random.key(0), 4000))
    assert np.mean(np.asarray(draws) == 1) == pytest.approx(0.5, abs=0.03)


def test_a_restricted_categorical_renormalises_over_the_allowed_actions():
    # logits (log 2, log 6, log 2) restricted to {0, 2}: probabilities (1/2, 0, 1/2)
    pi = Categorical(jnp.log(jnp.array([[2.0, 6.0, 2.0]]))).restrict(
        jnp.array([[True, False, True]]))
    assert pi.mode().tolist() == [0]  # the best allowed action, not action 1
    assert float(pi.log_prob(jnp.array([2]))[0]) == pytest.approx(np.log(0.5), abs=1e-6)
    assert float(pi.entropy()[0]) == pytest.approx(np.log(2), abs=1e-6)
    draws = np.asarray(jax.vmap(pi.sample)(jax.random.split(jax.random.key(0), 2000)))
    assert not (draws == 1).any()


def test_diagonal_gaussian_by_hand():
    # mean (1, -1), std (1, e): log N(a) at a = (2, -1) is -1/2 - 1 - log(2 pi)
    pi = DiagGaussian(jnp.array([1.0, -1.0]), jnp.array([0.0, 1.0]))
    assert pi.mode().tolist() == [1.0, -1.0]
    expected = -0.5 - 1.0 - np.log(2 * np.pi)
    assert float(pi.log_prob(jnp.array([2.0, -1.0]))) == pytest.approx(expected, abs=1e-6)
    assert float(pi.entropy()) == pytest.approx(1.0 + np.log(2 * np.pi * np.e), abs=1e-6)
    draws = jax.vmap(pi.sample)(jax.random.split(jax.random.key(1), 4000))
    assert np.std(np.asarray(draws), axis=0) == pytest.approx([1.0, np.e], rel=0.05)


def test_discretized_by_hand():
    # Two dimensions of 3 values in [-1, 1] and [0, 4]: (-1, 0, 1) and (0, 2, 4).
    logits = jnp.log(jnp.array([[0.2, 0.3, 0.5], [0.6, 0.3, 0.1]]))
    pi = Discretized(logits, jnp.array([-1.0, 0.0]), jnp.array([1.0, 4.0]))
    assert pi.mode().tolist() == [1.0, 0.0]
    assert float(pi.log_prob(jnp.array([0.0, 4.0]))) == pytest.approx(np.log(0.3 * 0.1),
                                                                      abs=1e-6)
    # An action between two values counts as the nearest (what the env was sent).
    assert float(pi.log_prob(jnp.array([-0.9, 2.4]))) == pytest.approx(np.log(0.2 * 0.3),
                                                                       abs=1e-6)
    h = -sum(p * np.log(p) for p in (0.2, 0.3, 0.5, 0.6, 0.3, 0.1))
    assert float(pi.entropy()) == pytest.approx(h, abs=1e-6)
    draws = np.asarray(jax.vmap(pi.sample)(jax.random.split(jax.random.key(1), 4000)))
    assert set(draws[:, 0]) == {-1.0, 0.0, 1.0} and set(draws[:, 1]) == {0.0, 2.0, 4.0}
    assert np.mean(draws[:, 0] == 1.0) == pytest.approx(0.5, abs=0.03)
    assert np.mean(draws[:, 1] == 0.0) == pytest.approx(0.6, abs=0.03)
    # Batch axes lead: [B, d, K] logits give [B, d] actions and [B] log-probabilities.
    batch = Discretized(jnp.zeros((5, 2, 4)), jnp.array([-1.0, -1.0]), jnp.array([1.0, 1.0]))
    assert batch.sample(jax.random.key(0)).shape == (5, 2)
    assert batch.log_prob(jnp.zeros((5, 2))).shape == (5,)
    assert float(batch.entropy()[0]) == pytest.approx(2 * np.log(4), abs=1e-6)


def test_episode_statistics_update_on_jax_and_numpy_alike():
    # Two envs, two objectives; env 0 ends at step 2, env 1 at steps 1 and 3.
    rewards = [[[1, 0], [2, 1]], [[1, 0], [0, 1]], [[0, 0], [3, 3]]]
    dones = [[0, 1], [1, 0], [0, 1]]
    for xp in (jnp, np):
        stats = EpisodeStats.init(2, 2)
        stats = stats.replace(**{k: xp.asarray(v) for k, v in vars(stats).items()})
        for r, d in zip(rewards, dones, strict=True):
            stats = stats.update(xp.asarray(r, xp.float32), xp.asarray(d, xp.float32))
        summary = stats.summary()
        # finished: env 1 (2, 1) in 1 step, env 0 (2, 0) in 2 steps, env 1 (3, 4) in 2 steps
        assert float(summary["episodes"]) == 3
        np.testing.assert_allclose(summary["episode_return"], [7 / 3, 5 / 3], atol=1e-6)
        assert float(summary["episode_length"]) == pytest.approx(5 / 3)
        np.testing.assert_array_equal(stats.returns, [[0, 0], [0, 0]])
        cleared = stats.clear().summary()
        assert float(cleared["episodes"]) == 0 and float(cleared["episode_length"]) == 0
