"""Evaluating a policy: Monte Carlo returns on a JAX env, exact values where the
env has a tabular model (the ground truth of :mod:`tpo.tabular`), and for the
continuous env a judgement against its finite reference
(:mod:`tpo.envs.continuous_model`).

Free functions over a *policy function* ``policy(params, obs) -> Distribution``
(e.g. :meth:`tpo.algo.train.Trainer.policy`), as SB3's ``evaluate_policy``.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from tpo.algo.distributions import Distribution
from tpo.envs.continuous import ContinuousNav
from tpo.envs.continuous_model import continuous_model, path_category
from tpo.envs.spec import from_spec
from tpo.graph import ObjectiveGraph
from tpo.tabular import Judge, evaluate_policy, softmax, solve_lar
from tpo.tabular.judge import ABS_TOL

Policy = Callable[[Any, jax.Array], Distribution]


def exact_evaluation(policy: Policy, params: Any, env: Any, graph: ObjectiveGraph,
                     gamma: float) -> dict[str, Any]:
    """The exact judgement of a policy on ``env``'s tabular model (a tabular env's
    actions are discrete, so the policy is categorical): the values at the start
    state of its greedy and stochastic policies, LAR's solution of the same
    problem (relaxed if infeasible), and the greedy policy's verdicts
    (:class:`tpo.tabular.Judge`)."""
    model = env.tabular(gamma).model
    pi = policy(params, jnp.asarray(env.tabular_observations()))
    lar = solve_lar(model, graph, relax=True)
    verdict = Judge(lar, env.absolute_tolerance)(np.asarray(pi.mode()))
    stochastic = evaluate_policy(model, softmax(np.asarray(pi.logits, np.float64)))
    return {"exact": {"greedy": verdict.values,
                      "stochastic": dict(zip(model.objectives,
                                             map(float, stochastic[model.start]), strict=True))},
            "lar": {"values": lar.start_values(), "policy_values": lar.start_policy_values(),
                    "feasible": lar.feasible, "floors": verdict.floors},
            "lar_correct": verdict.lar_correct, "strict": verdict.strict,
            "same_values": verdict.same_values,
            "outside": list(verdict.outside)}


class Episodes(NamedTuple):
    """One episode per key, time-major within it: ``[N, T, ...]`` with ``T`` the env's
    step limit; steps after the episode's end are masked by ``alive``."""

    obs: jax.Array  # s_t
    next_obs: jax.Array  # s_{t+1}
    reward: jax.Array  # [N, T, k]
    terminated: jax.Array  # float: s_{t+1} is terminal
    alive: jax.Array  # float: step t is part of the episode


def episodes(policy: Policy, params: Any, env: Any, keys: jax.Array, greedy: bool
             ) -> Episodes:
    """One episode per key from the env's reset until it terminates or truncates
    (traceable: jit it, or vmap it over parameters)."""

    def episode(key):
        k_reset, k_run = jax.random.split(key)
        obs, state = env.reset(k_reset, env.params)

        def body(carry, key):
            obs, state, alive = carry
            k_act, k_env = jax.random.split(key)
            pi = policy(params, obs)
            action = pi.mode() if greedy else pi.sample(k_act)
            nxt, state, reward, term, trunc = env.step_env(k_env, state, action, env.params)
            step = (obs, nxt, reward, term.astype(jnp.float32), alive)
            return (nxt, state, alive * (1.0 - (term | trunc))), step

        _, steps = jax.lax.scan(body, (obs, state, jnp.float32(1)),
                                jax.random.split(k_run, int(env.params.max_steps)))
        return Episodes(*steps)

    return jax.vmap(episode)(keys)


def discounted(values: jax.Array, alive: jax.Array, gamma: float) -> jax.Array:
    """``sum_t gamma^t alive_t values_t`` over the time axis of ``[N, T, ...]``."""
    weight = alive * gamma ** jnp.arange(alive.shape[1], dtype=jnp.float32)
    return jnp.einsum("nt,nt...->n...", weight, values)


def episode_returns(policy: Policy, params: Any, env: Any, keys: jax.Array, greedy: bool,
                    gamma: float) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Undiscounted ``[N, k]`` and discounted ``[N, k]`` returns and lengths ``[N]`` of
    :func:`episodes` (traceable)."""
    ep = episodes(policy, params, env, keys, greedy)
    return (jnp.einsum("nt,ntk->nk", ep.alive, ep.reward), discounted(ep.reward, ep.alive, gamma),
            ep.alive.sum(1))


def monte_carlo(policy: Policy, params: Any, env: Any, key: jax.Array, episodes: int,
                greedy: bool, gamma: float) -> dict[str, np.ndarray]:
    """:func:`episode_returns` of ``episodes`` episodes as NumPy:
    ``{"undiscounted": [N, k], "discounted": [N, k], "length": [N]}``."""
    run = jax.jit(partial(episode_returns, policy, env=env, greedy=greedy, gamma=gamma))
    ret, disc, length = run(params, keys=jax.random.split(key, episodes))
    return {"undiscounted": np.asarray(ret), "discounted": np.asarray(disc),
            "length": np.asarray(length)}


def summarize(returns: np.ndarray, objectives: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Mean and standard deviation of ``[N, k]`` returns, by objective."""
    return {n: {"mean": float(returns[:, i].mean()), "std": float(returns[:, i].std())}
            for i, n in enumerate(objectives)}


CONTINUOUS_TOL = 0.05  # the continuous verdict's relative tolerance (issue 16)


def reference_evaluation(policy: Policy, params: Any, env: ContinuousNav,
                         graph: ObjectiveGraph, gamma: float) -> dict[str, Any]:
    """A continuous policy judged against the env's finite reference: the
    noise-free greedy policy's discounted return (one episode: it is
    deterministic; run until the discount makes the rest negligible) beside the
    reference's LAR solution (relaxed if infeasible), the LAR-correct verdict at
    value level (the leaf within 5 % (or 0.5) of the reference's ``V*_leaf`` or
    above it; every ancestor at or above its floor less 5 %), and the path's
    category beside the reference path's."""
    ref = continuous_model(env, gamma)
    lar = solve_lar(ref.model, graph, relax=True)
    judge = Judge(lar, ABS_TOL)
    run = jax.jit(partial(greedy_path, policy, env=noise_free(env, gamma), gamma=gamma))
    positions, alive, returns = map(np.asarray, run(params))
    values = dict(zip(env.objectives, map(float, returns), strict=True))
    learned = path_category(env.navmap, positions[alive])
    reference = ref.category(lar.policy)
    return {"mc_noise_free": values,
            "reference": {"values": lar.start_values(),
                          "policy_values": lar.start_policy_values(),
                          "feasible": lar.feasible, "floors": judge.floors,
                          "resolution": ref.resolution, "path": reference},
            "lar_correct": judge.lar_correct(values, CONTINUOUS_TOL),
            "path": learned, "path_matches": learned == reference}


def noise_free(env: ContinuousNav, gamma: float) -> ContinuousNav:
    """``env`` without noise, its step limit long enough that a discounted return is
    the reference's infinite-horizon value to 1e-4 of its scale."""
    horizon = int(np.ceil(np.log(1e-4) / np.log(gamma))) if gamma > 0 else 1
    spec = env.to_spec()
    return from_spec({**spec, "noise": 0.0, "max_steps": max(spec["max_steps"], horizon)})


def greedy_path(policy: Policy, params: Any, env: ContinuousNav, gamma: float,
                key: jax.Array | None = None) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The greedy policy's episode on ``env`` from its reset (by ``key``; the map's start
    for an env without random starts): positions ``[T + 1, 2]``, whether the robot
    is still there at each ``[T + 1]`` (false after the goal), and the discounted
    return ``[k]``."""
    obs, state = env.reset(jax.random.key(0) if key is None else key, env.params)

    def body(carry, key):
        obs, state, alive, disc_ret, disc = carry
        obs, nxt, reward, term, trunc = env.step_env(key, state, policy(params, obs).mode(),
                                                     env.params)
        disc_ret = disc_ret + alive * disc * reward
        alive_next = alive * (1.0 - (term | trunc))
        return (obs, nxt, alive_next, disc_ret, disc * gamma), (nxt.pos, alive * 1.0)

    init = (obs, state, jnp.float32(1), jnp.zeros(len(env.objectives)), jnp.float32(1))
    (_, _, _, disc_ret, _), (pos, alive) = jax.lax.scan(
        body, init, jax.random.split(jax.random.key(0), int(env.params.max_steps)))
    positions = jnp.concatenate([state.pos[None], pos])
    return positions, jnp.concatenate([jnp.ones(1, bool), alive > 0]), disc_ret
