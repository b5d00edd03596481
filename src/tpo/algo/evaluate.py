"""Evaluating a learned policy: Monte Carlo returns, and exact values where the env
has a tabular model (the ground truth of :mod:`tpo.tabular`)."""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from tpo.algo.networks import mode, sample
from tpo.tabular import evaluate_policy, softmax


def exact_values(trainer: Any, actor_params: dict, env: Any, gamma: float
                 ) -> dict[str, dict[str, float]]:
    """Exact discounted values at the start state of the greedy and the stochastic
    policy, by objective: ``{"greedy": {...}, "stochastic": {...}}``."""
    grid = env.tabular(gamma)
    logits, _ = trainer.actor.apply({"params": actor_params},
                                    jnp.asarray(env.tabular_observations()))
    logits = np.asarray(logits, np.float64)
    start = grid.model.start
    out = {}
    for name, policy in (("greedy", logits.argmax(axis=1)), ("stochastic", softmax(logits))):
        values = evaluate_policy(grid.model, policy)[start]
        out[name] = {n: float(v) for n, v in zip(grid.model.objectives, values, strict=True)}
    return out


def episode_returns(trainer: Any, env: Any, actor_params: dict, keys: jax.Array,
                    greedy: bool, gamma: float) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Undiscounted ``[N, k]`` and discounted ``[N, k]`` returns and lengths ``[N]`` of
    one episode per key, from the env's reset until it terminates or truncates
    (traceable: jit it, or vmap it over parameters)."""
    continuous = trainer.continuous

    def episode(key):
        k_reset, k_run = jax.random.split(key)
        obs, state = env.reset(k_reset, env.params)

        def body(carry, key):
            obs, state, alive, ret, disc_ret, disc, length = carry
            k_act, k_env = jax.random.split(key)
            out, log_std = trainer.actor.apply({"params": actor_params}, obs)
            action = mode(out, continuous) if greedy else sample(k_act, out, log_std,
                                                                 continuous)
            obs, state, reward, term, trunc = env.step_env(k_env, state, action, env.params)
            ret = ret + alive * reward
            disc_ret = disc_ret + alive * disc * reward
            length = length + alive
            alive = alive * (1.0 - (term | trunc))
            return (obs, state, alive, ret, disc_ret, disc * gamma, length), None

        k = len(env.objectives)
        init = (obs, state, jnp.float32(1), jnp.zeros(k), jnp.zeros(k), jnp.float32(1),
                jnp.float32(0))
        (_, _, _, ret, disc_ret, _, length), _ = jax.lax.scan(
            body, init, jax.random.split(k_run, int(env.params.max_steps)))
        return ret, disc_ret, length

    return jax.vmap(episode)(keys)


def monte_carlo(trainer: Any, actor_params: dict, env: Any, key: jax.Array, episodes: int,
                greedy: bool, gamma: float) -> dict[str, np.ndarray]:
    """:func:`episode_returns` of ``episodes`` episodes as NumPy:
    ``{"undiscounted": [N, k], "discounted": [N, k], "length": [N]}``."""
    run = jax.jit(partial(episode_returns, trainer, env, greedy=greedy, gamma=gamma))
    ret, disc, length = run(actor_params, jax.random.split(key, episodes))
    return {"undiscounted": np.asarray(ret), "discounted": np.asarray(disc),
            "length": np.asarray(length)}


def summarize(returns: np.ndarray, objectives: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Mean and standard deviation of ``[N, k]`` returns, by objective."""
    return {n: {"mean": float(returns[:, i].mean()), "std": float(returns[:, i].std())}
            for i, n in enumerate(objectives)}
