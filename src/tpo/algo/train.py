"""Topological policy optimization (paper Algorithm 1), end to end in JAX.

One policy, one critic per objective. Objectives are trained in topological
order, one PPO phase each; phase ``i`` uses the generalized Lagrangian
advantages of :mod:`tpo.algo.lagrangian`, whose penalty reads the frozen
critics of the objectives already trained. After the phase, critic ``i`` is
frozen too (no later phase trains it). With a one-objective graph this is
plain PPO, the baseline, in the same code.

The whole run is a ``lax.scan`` over updates; the phase of an update is
``update // updates_per_phase``, a traced number, so one compiled update
serves every phase and the run is a single jitted function of a PRNG key,
parameters and slack, vmappable over seeds and slack values::

    trainer = Trainer(env, graph, config, total_timesteps)
    state = trainer.init(key)
    state, metrics = trainer.run(state, slack, trainer.num_updates)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from tpo.algo.config import ConfigError, TPOConfig
from tpo.algo.lagrangian import ancestral_advantages, lagrangian_advantages, violations
from tpo.algo.losses import clipped_surrogate, clipped_value_loss, normalize
from tpo.algo.networks import (
    Actor,
    Critics,
    ValueNorm,
    entropy,
    init_params,
    log_prob,
    mode,
    sample,
)
from tpo.graph import ObjectiveGraph


@struct.dataclass
class TrainState:
    """Everything a run carries from update to update (a pytree)."""

    params: dict
    initial_actor: dict  # the actor's parameters at the start of the run
    actor_opt: Any
    critic_opt: Any
    env_state: Any
    obs: jax.Array  # [E, D]
    key: jax.Array
    update: jax.Array  # int32 [], updates done
    value_norm: ValueNorm
    episode_return: jax.Array  # [E, k] running undiscounted returns
    episode_length: jax.Array  # [E]


class Rollout(NamedTuple):
    """Experience of one update, time-major ``[T, E, ...]``: what any source of
    rollouts (the jitted JAX env, or a host-stepped Gymnasium env) hands to
    :meth:`Trainer.learn`."""

    obs: jax.Array  # s_t
    action: jax.Array
    log_prob: jax.Array  # of the action under the acting policy
    reward: jax.Array  # [k]
    final_obs: jax.Array  # the true s_{t+1} (before any auto-reset)
    terminated: jax.Array  # float: s_{t+1} is terminal (no bootstrap)
    done: jax.Array  # float: the episode ended (terminated or truncated)


@dataclass(frozen=True)
class Problem:
    """The static structure of a TMDP that the compiled program needs.

    Attributes:
        objectives: the env's objective names (reward columns).
        order: reward column of each phase, in topological order.
        parents: reward column of every edge's parent, ``[n_edges]``.
        active: ``[n_phases, n_edges]``, 1 where the edge is in the phase's ``E_i``.
        beta: multiplier of every phase, ``[n_phases]``.
    """

    objectives: tuple[str, ...]
    graph: ObjectiveGraph
    order: np.ndarray
    parents: np.ndarray
    active: np.ndarray
    beta: np.ndarray

    @classmethod
    def build(cls, graph: ObjectiveGraph, objectives: Sequence[str], config: TPOConfig,
              reward_low: np.ndarray, reward_high: np.ndarray) -> Problem:
        graph = graph.bind(tuple(objectives))
        col = {n: i for i, n in enumerate(objectives)}
        order = np.array([col[n] for n in graph.order], np.int32)
        parents = np.array([col[e.parent] for e in graph.edges], np.int32)
        active = np.array([[e in graph.ancestral_edges(n) for e in graph.edges]
                           for n in graph.order], np.float32).reshape(len(order), len(parents))
        if config.beta == "auto":
            beta = value_bounds(reward_low, reward_high, config.gamma)[order].astype(np.float32)
        else:
            beta = np.full(len(order), float(config.beta), np.float32)
        return cls(tuple(objectives), graph, order, parents, active, beta)


class Trainer:
    """The compiled pieces of a TPO run on a pure JAX env (see the module docstring)."""

    def __init__(self, env: Any, graph: ObjectiveGraph, config: TPOConfig,
                 total_timesteps: int) -> None:
        self.env, self.config, self.total_timesteps = env, config, total_timesteps
        self.problem = Problem.build(graph, env.objectives, config, env.reward_low,
                                     env.reward_high)
        self.continuous = getattr(env, "num_actions", None) is None
        n_out = env.action_dim if self.continuous else env.num_actions
        self.actor = Actor(config.hidden, n_out, self.continuous, config.activation)
        self.critics = Critics(config.hidden, len(env.objectives), config.activation)
        n_phases = len(self.problem.order)
        if config.phase_fractions is not None and len(config.phase_fractions) != n_phases:
            raise ConfigError(f"phase_fractions has {len(config.phase_fractions)} values for "
                              f"{n_phases} phase(s)")
        fractions = np.asarray(config.phase_fractions or [1.0] * n_phases, float)
        per_update = config.batch_size
        if isinstance(total_timesteps, bool) or not isinstance(total_timesteps, int) \
                or total_timesteps < per_update * n_phases:
            raise ConfigError(f"total_timesteps must be an integer >= {per_update * n_phases} "
                              f"(one update of {per_update} steps per phase), "
                              f"got {total_timesteps!r}")
        shares = np.maximum(1, np.floor(total_timesteps / per_update * fractions
                                        / fractions.sum())).astype(np.int32)
        self.phase_updates = shares
        self.phase_start = np.concatenate([[0], np.cumsum(shares)]).astype(np.int32)
        refit = np.floor(shares * config.critic_refit).astype(np.int32)
        self.policy_updates = np.maximum(1, shares - refit).astype(np.int32)
        self.num_updates = int(self.phase_start[-1])
        self._actor_tx = self._optimizer()
        self._critic_tx = self._optimizer()

    def _optimizer(self) -> optax.GradientTransformation:
        return optax.chain(optax.clip_by_global_norm(self.config.max_grad_norm),
                           optax.scale_by_adam(eps=1e-5))

    # ------------------------------------------------------------------ init
    def init_params(self, key: jax.Array) -> dict:
        """Network parameters of one seed (outside any vmap: DESIGN.md §6)."""
        return init_params(key, self.actor, self.critics, self.env.obs_shape)

    def init(self, key: jax.Array, params: dict | None = None,
             obs: jax.Array | None = None) -> TrainState:
        """A fresh run; ``params`` default to :meth:`init_params` of ``key``. A JAX
        env resets itself; a host-stepped env passes its first observations ``obs``
        ``[E, D]`` (the state then holds no env state)."""
        k_params, k_env, k_run = jax.random.split(key, 3)
        params = self.init_params(k_params) if params is None else params
        env_state = None
        if obs is None:
            obs, env_state = self._reset(k_env)
        return self._init_state(params, env_state, jnp.asarray(obs, jnp.float32), k_run)

    @partial(jax.jit, static_argnums=0)
    def _reset(self, key: jax.Array) -> tuple[jax.Array, Any]:
        return jax.vmap(self.env.reset, in_axes=(0, None))(
            jax.random.split(key, self.config.num_envs), self.env.params)

    @partial(jax.jit, static_argnums=0)
    def _init_state(self, params: dict, env_state: Any, obs: jax.Array, k_run: jax.Array
                    ) -> TrainState:
        e, k = self.config.num_envs, len(self.problem.objectives)
        return TrainState(params, params["actor"], self._actor_tx.init(params["actor"]),
                          self._critic_tx.init(params["critics"]), env_state, obs, k_run,
                          jnp.zeros((), jnp.int32), ValueNorm.init(k), jnp.zeros((e, k)),
                          jnp.zeros((e,)))

    # ---------------------------------------------------------------- update
    def phase_of(self, update: jax.Array) -> jax.Array:
        return jnp.sum(update >= jnp.asarray(self.phase_start[1:])).astype(jnp.int32)

    def phase_info(self, state: TrainState) -> tuple[jax.Array, jax.Array, jax.Array]:
        """The current phase, its first update, and whether this update refits the
        critic with greedy rollouts (``critic_refit``)."""
        phase = jnp.minimum(self.phase_of(state.update), len(self.problem.order) - 1)
        start = jnp.asarray(self.phase_start)[phase]
        refit = (state.update - start) >= jnp.asarray(self.policy_updates)[phase]
        return phase, start, refit

    def update(self, state: TrainState, slack: jax.Array) -> tuple[TrainState, dict]:
        """One PPO update of the current phase: a rollout of the JAX env, then
        :meth:`learn`."""
        _, _, refit = self.phase_info(state)
        state, rollout, episodes = self._rollout(state, greedy=refit)
        return self.learn(state, slack, rollout, episodes)

    def learn(self, state: TrainState, slack: jax.Array, rollout: Rollout,
              episodes: dict) -> tuple[TrainState, dict]:
        """The update from one rollout: Lagrangian advantages, then PPO epochs."""
        cfg, prob = self.config, self.problem
        phase, start, refit = self.phase_info(state)
        column = jnp.asarray(prob.order)[phase]
        pick = jax.nn.one_hot(column, len(prob.objectives))
        # The critics see the whole rollout at once (one batched call, not one per step).
        value, next_value = self.values(state, jnp.stack([rollout.obs, rollout.final_obs]))
        adv_all = ancestral_advantages(rollout.reward, value, next_value, rollout.terminated,
                                       cfg.gamma)
        c = violations(adv_all, jnp.asarray(prob.parents), slack)
        penalty = c @ jnp.asarray(prob.active)[phase]  # [T, E]; zeros when no edges
        beta = jnp.asarray(prob.beta)[phase]
        advantages, targets = lagrangian_advantages(
            cfg.advantage, rollout.reward @ pick, value @ pick, next_value @ pick,
            penalty, beta, rollout.terminated, rollout.done, cfg.gamma, cfg.gae_lambda)

        first = state.update == start
        if cfg.reset_actor:
            state = state.replace(params={**state.params, "actor": _where_tree(
                first, state.initial_actor, state.params["actor"])})
        elif cfg.carry_temperature != 1.0:
            soften = first & (phase > 0)
            state = state.replace(params={**state.params, "actor": self._soften(
                state.params["actor"], jnp.where(soften, 1.0 / cfg.carry_temperature, 1.0))})
        actor_opt = _where_tree(first, self._actor_tx.init(state.params["actor"]),
                                state.actor_opt)
        critic_opt = _where_tree(first, self._critic_tx.init(state.params["critics"]),
                                 state.critic_opt)
        progress = (state.update - start) / jnp.asarray(self.policy_updates)[phase]
        annealed = cfg.learning_rate * ((1.0 - progress) if cfg.anneal_lr else 1.0)
        lr = (jnp.where(refit, 0.0, annealed), jnp.where(refit, cfg.learning_rate, annealed))

        value_norm = state.value_norm.update(targets, pick)
        mean, std = value_norm.stats()
        scale = (mean @ pick, std @ pick)
        flat = jax.tree.map(lambda x: x.reshape(cfg.batch_size, *x.shape[2:]),
                            (rollout.obs, rollout.action, rollout.log_prob, value @ pick,
                             advantages, targets))
        key, k_epochs = jax.random.split(state.key)
        (params, actor_opt, critic_opt), losses = jax.lax.scan(
            partial(self._epoch, column=column, lr=lr, scale=scale, data=flat),
            (state.params, actor_opt, critic_opt), jax.random.split(k_epochs, cfg.update_epochs))

        state = state.replace(params=params, actor_opt=actor_opt, critic_opt=critic_opt,
                              key=key, update=state.update + 1, value_norm=value_norm)
        violating = (penalty > 0).mean()
        metrics = {"phase": phase, "refit": refit, "lr": lr[0], "penalty": penalty.mean(),
                   "violation_rate": violating, **episodes,
                   **jax.tree.map(jnp.mean, losses)}
        return state, metrics

    def _soften(self, actor: dict, factor: jax.Array) -> dict:
        """The actor with its output layer scaled by ``factor`` (logits / temperature)."""
        mlp = actor["MLP_0"]
        head = f"Dense_{len(self.config.hidden)}"
        return {**actor, "MLP_0": {**mlp, head: jax.tree.map(lambda x: x * factor, mlp[head])}}

    def _rollout(self, state: TrainState, greedy: jax.Array
                 ) -> tuple[TrainState, Rollout, dict]:
        cfg, env = self.config, self.env
        actor_p = state.params["actor"]

        def step(carry, key):
            env_state, obs, ep_ret, ep_len, done_ret, done_len, done_n = carry
            k_act, k_env = jax.random.split(key)
            out, log_std = self.actor.apply({"params": actor_p}, obs)
            action = jnp.where(greedy, mode(out, self.continuous),
                               sample(k_act, out, log_std, self.continuous))
            logp = log_prob(out, log_std, action, self.continuous)
            obs2, env_state, reward, term, trunc, info = jax.vmap(
                env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(k_env, cfg.num_envs), env_state, action, env.params)
            done = term | trunc
            ep_ret, ep_len = ep_ret + reward, ep_len + 1
            d = done.astype(jnp.float32)
            done_ret = done_ret + (ep_ret * d[:, None]).sum(0)
            done_len = done_len + (ep_len * d).sum()
            done_n = done_n + d.sum()
            ep_ret, ep_len = ep_ret * (1 - d[:, None]), ep_len * (1 - d)
            out = Rollout(obs, action, logp, reward, info["final_obs"],
                          term.astype(jnp.float32), d)
            return (env_state, obs2, ep_ret, ep_len, done_ret, done_len, done_n), out

        key, k_roll = jax.random.split(state.key)
        k = len(self.problem.objectives)
        init = (state.env_state, state.obs, state.episode_return, state.episode_length,
                jnp.zeros(k), jnp.zeros(()), jnp.zeros(()))
        (env_state, obs, ep_ret, ep_len, done_ret, done_len, done_n), rollout = jax.lax.scan(
            step, init, jax.random.split(k_roll, cfg.num_steps))
        n = jnp.maximum(done_n, 1.0)
        episodes = {"episodes": done_n, "episode_return": done_ret / n,
                    "episode_length": done_len / n}
        state = state.replace(env_state=env_state, obs=obs, key=key, episode_return=ep_ret,
                              episode_length=ep_len)
        return state, rollout, episodes

    def _epoch(self, carry, key, *, column, lr, scale, data):
        cfg = self.config
        perm = jax.random.permutation(key, cfg.batch_size)
        shuffled = jax.tree.map(
            lambda x: x[perm].reshape(cfg.num_minibatches, -1, *x.shape[1:]), data)
        return jax.lax.scan(partial(self._minibatch, column=column, lr=lr,
                                    scale=scale), carry, shuffled)

    def _minibatch(self, carry, mb, *, column, lr, scale):
        cfg = self.config
        params, actor_opt, critic_opt = carry
        obs, action, old_logp, old_value, advantages, targets = mb

        def loss_fn(p):
            out, log_std = self.actor.apply({"params": p["actor"]}, obs)
            logp = log_prob(out, log_std, action, self.continuous)
            ent = entropy(out, log_std, self.continuous).mean()
            pg = clipped_surrogate(logp - old_logp, normalize(advantages), cfg.clip_eps)
            mean, std = scale
            out = self.critics.head(p["critics"], column, obs)
            goal, old = (targets - mean) / std, (old_value - mean) / std
            vl = (clipped_value_loss(out, old, goal, cfg.clip_eps) if cfg.clip_value
                  else 0.5 * jnp.mean((out - goal) ** 2))
            total = pg - cfg.ent_coef * ent + cfg.vf_coef * vl
            kl = jnp.mean((jnp.exp(logp - old_logp) - 1) - (logp - old_logp))
            return total, {"policy_loss": pg, "value_loss": vl, "entropy": ent,
                           "approx_kl": kl}

        grads, info = jax.grad(loss_fn, has_aux=True)(params)
        a_up, actor_opt = self._actor_tx.update(grads["actor"], actor_opt)
        c_up, critic_opt = self._critic_tx.update(grads["critics"], critic_opt)
        actor_lr, critic_lr = lr
        params = {"actor": optax.apply_updates(params["actor"], jax.tree.map(
                      lambda u: -actor_lr * u, a_up)),
                  "critics": optax.apply_updates(params["critics"], jax.tree.map(
                      lambda u: -critic_lr * u, c_up))}
        return (params, actor_opt, critic_opt), info

    def values(self, state: TrainState, obs: jax.Array) -> jax.Array:
        """Every critic's value ``[..., k]`` at ``obs``."""
        return state.value_norm.denormalize(
            self.critics.apply({"params": state.params["critics"]}, obs))

    # ------------------------------------------------------------------- run
    def run(self, state: TrainState, slack: jax.Array, num_updates: int
            ) -> tuple[TrainState, dict]:
        """``num_updates`` updates from ``state`` with their metrics (jit or vmap it)."""
        return self.run_chunk(state, slack, num_updates, num_updates)

    def run_chunk(self, state: TrainState, slack: jax.Array, num_updates: jax.Array,
                  length: int) -> tuple[TrainState, dict]:
        """``num_updates`` updates (traced; at most ``length``, the rows beyond are not
        written); metrics in ``length`` rows of which the first ``num_updates`` are
        filled. One compiled program serves every chunk of a run, the short last
        one too."""
        _, shapes = jax.eval_shape(self.update, state, slack)
        rows = jax.tree.map(lambda x: jnp.zeros((length, *x.shape), x.dtype), shapes)

        def body(i, carry):
            state, rows = carry
            state, metrics = self.update(state, slack)
            return state, jax.tree.map(lambda r, m: r.at[i].set(m), rows, metrics)

        return jax.lax.fori_loop(0, num_updates, body, (state, rows))

    def slack_array(self) -> jax.Array:
        """The graph's slack as the ``[n_edges]`` vector :meth:`run` takes."""
        return jnp.asarray(self.problem.graph.slacks, jnp.float32)


def value_bounds(reward_low: np.ndarray, reward_high: np.ndarray, gamma: float) -> np.ndarray:
    """The largest value difference of every objective,
    ``max(|r_lo|, |r_hi|, r_hi - r_lo) / (1 - gamma)`` (1 where a bound is unknown)."""
    lo, hi = np.asarray(reward_low, float), np.asarray(reward_high, float)
    bound = np.maximum.reduce([np.abs(lo), np.abs(hi), hi - lo]) / (1 - gamma)
    return np.where(np.isfinite(bound) & (bound > 0), bound, 1.0)


def _where_tree(cond: jax.Array, a: Any, b: Any) -> Any:
    return jax.tree.map(lambda x, y: jnp.where(cond, x, y), a, b)
