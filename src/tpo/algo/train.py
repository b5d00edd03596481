"""Topological policy optimization (paper Algorithm 1), end to end in JAX.

One policy, one critic head per phase. Objectives are trained in topological
order, one PPO phase each, and after its phase a head is frozen; then the extra
phases of :class:`tpo.algo.phases.Problem` (the completion, or a fan's roots'
completion). A phase learns from the constraint terms of
:mod:`tpo.algo.constraints` and keeps its ancestors' slacks in a form of
:mod:`tpo.algo.forms` (the paper's penalty, or the restriction to LAR's
admissible actions); the run's answer is selected by :mod:`tpo.algo.selection`.
With a one-objective graph this is plain PPO, the baseline, in the same code.

The whole run is a loop over updates; the phase of an update is a traced
number, so one compiled update serves every phase and the run is a single
jitted function of the training state and the slack, vmappable over seeds and
slack values::

    trainer = Trainer(env, graph, config, total_timesteps)
    state = trainer.init(key)
    state, metrics = trainer.run(state, slack, trainer.num_updates)

An update is :meth:`Trainer.collect` (a rollout of the JAX env),
:meth:`Trainer.begin_phase`, then :meth:`Trainer.learn`, which reads top to
bottom: compute the phase's targets, run the PPO epochs. The learned policy is
``trainer.policy(trainer.acting(state, slack), obs)``.
"""

from __future__ import annotations

from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from tpo.algo.config import ConfigError, TPOConfig
from tpo.algo.constraints import lagrangian_terms, loose_tolerance, trace_decay
from tpo.algo.distributions import Distribution
from tpo.algo.episodes import EpisodeStats
from tpo.algo.forms import constraint_form
from tpo.algo.losses import clipped_surrogate, normalize, weighted_mean
from tpo.algo.networks import Actor, Critics, ValueNorm, init_params, scale_output
from tpo.algo.phases import Acting, Problem, phase_updates
from tpo.graph import ObjectiveGraph


@struct.dataclass
class TrainState:
    """Everything a run carries from update to update (a pytree)."""

    params: dict  # {"actor": ..., "critics": ...}
    actor_opt: Any
    critic_opt: Any
    env_state: Any  # None for a host-stepped env
    obs: jax.Array  # [E, D]
    key: jax.Array
    update: jax.Array  # int32 [], updates done
    value_norm: ValueNorm
    episodes: EpisodeStats
    snapshots: dict  # the actor as each phase left it, every leaf [P, ...]
    design: jax.Array  # int32 []: 1 for a population's second design, else 0
    view: jax.Array  # int32 []: the row of Trainer.views the learner sees (0: everything)


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
    allowed: jax.Array | None  # [A] bool, the admissible actions (restriction form)
    explore: jax.Array  # float: a uniform random action, not the policy's


class Batch(NamedTuple):
    """One phase's training data, flattened to ``[B, ...]``."""

    obs: jax.Array
    action: jax.Array
    log_prob: jax.Array
    advantage: jax.Array
    target: jax.Array  # of V(s)
    q_target: jax.Array | None  # [P] of every head's Q(s, a) - V(s) (restriction form)
    allowed: jax.Array | None
    weight: jax.Array  # 1 for the policy's own steps, 0 for exploring ones


class Trainer:
    """The compiled pieces of a TPO run (see the module docstring). ``env`` is a
    pure JAX env, or a host-stepped one whose rollouts come from elsewhere
    (:class:`tpo.algo.runners.HostRunner`); either declares ``action_space``,
    ``obs_shape``, ``objectives`` and the reward bounds."""

    def __init__(self, env: Any, graph: ObjectiveGraph, config: TPOConfig,
                 total_timesteps: int) -> None:
        self.env, self.config, self.total_timesteps = env, config, total_timesteps
        space = env.action_space
        self.problem = Problem.build(graph, env.objectives, config)
        #: how the phases keep their constraints, and the constraint terms' sizes
        self.form = constraint_form(config, self.problem, space, env.reward_low,
                                    env.reward_high)
        self.terms = self.form.terms
        #: the observation's blocks of one non-zero number, read by gathers (InputDense)
        onehots = tuple(map(tuple, getattr(env, "observation_onehots", ())))
        try:
            self.actor = Actor.for_space(space, config.hidden, config.activation,
                                         config.action_bins, onehots)
        except ValueError as err:
            raise ConfigError(str(err)) from None
        #: the steps per env whose ``s_{t+1}`` gets its own critic call: the last and
        #: every truncation (:meth:`rollout_values`), all without a time limit
        limit = getattr(env, "max_steps", None)
        self.own_next = config.num_steps if limit is None else min(
            config.num_steps, (config.num_steps - 1) // limit + 2)
        #: the views a learner may see, ``[V, D]``: the whole, then the env's own
        whole = np.ones((1, *env.obs_shape), np.float32)
        self.views = np.concatenate([whole, *[np.asarray(v, np.float32)[None] for v in
                                              getattr(env, "observation_views", ())]])
        n_phases = self.problem.n_phases
        self.critics = Critics(config.hidden, n_phases, self.form.n_out, config.activation,
                               onehots)
        self.phase_updates = phase_updates(config, n_phases, total_timesteps)
        self.phase_start = np.concatenate([[0], np.cumsum(self.phase_updates)]).astype(np.int32)
        self.num_updates = int(self.phase_start[-1])
        # The learning rate anneals to 0 within every phase (or stays constant), the
        # entropy weight from ent_coef to ent_coef_end.
        self.learning_rate = self._per_phase(
            config.learning_rate, 0.0 if config.anneal_lr else config.learning_rate)
        self.ent_coef = self._per_phase(config.ent_coef, config.ent_coef_end)
        # Actor and critics clip their gradient norms apart; Adam's state restarts
        # with every phase.
        self.optimizer = optax.chain(
            optax.clip_by_global_norm(config.max_grad_norm),
            optax.inject_hyperparams(optax.adam)(learning_rate=config.learning_rate, eps=1e-5))

    def _per_phase(self, start: float, end: float) -> optax.Schedule:
        """A schedule over updates that goes linearly from ``start`` to ``end`` within
        every phase."""
        return optax.join_schedules(
            [optax.linear_schedule(start, end, max(1, int(n))) for n in self.phase_updates],
            [int(b) for b in self.phase_start[1:-1]])

    # ------------------------------------------------------------------ init
    def init_params(self, key: jax.Array) -> dict:
        """Network parameters of one seed (outside any jit or vmap: their QRs run on
        the host, docs/design.md §5)."""
        return init_params(key, self.actor, self.critics, self.env.obs_shape)

    def init(self, key: jax.Array, params: dict | None = None,
             obs: jax.Array | None = None, design: int = 0, view: int = 0) -> TrainState:
        """A fresh run; ``params`` default to :meth:`init_params` of ``key``. A JAX
        env resets itself; a host-stepped env passes its first observations ``obs``
        ``[E, D]`` (the state then holds no env state). ``design`` 1 learns a
        population's second design (:mod:`tpo.algo.constraints`); ``view`` is the row
        of :attr:`views` the learner sees (:meth:`see_only`)."""
        k_params, k_env, k_run = jax.random.split(key, 3)
        params = self.init_params(k_params) if params is None else params
        env_state = None
        if obs is None:
            obs, env_state = self._reset(k_env)
        return self._init_state(params, env_state, jnp.asarray(obs, jnp.float32), k_run,
                                jnp.int32(design), jnp.int32(view))

    @partial(jax.jit, static_argnums=0)
    def _reset(self, key: jax.Array) -> tuple[jax.Array, Any]:
        return jax.vmap(self.env.reset, in_axes=(0, None))(
            jax.random.split(key, self.config.num_envs), self.env.params)

    @partial(jax.jit, static_argnums=0)
    def _init_state(self, params: dict, env_state: Any, obs: jax.Array, k_run: jax.Array,
                    design: jax.Array, view: jax.Array) -> TrainState:
        params = self.see_only(params, view)
        return TrainState(params, self.optimizer.init(params["actor"]),
                          self.optimizer.init(params["critics"]), env_state, obs, k_run,
                          jnp.zeros((), jnp.int32), ValueNorm.init(self.problem.n_phases),
                          EpisodeStats.init(self.config.num_envs,
                                            len(self.problem.objectives)),
                          jax.tree.map(lambda x: jnp.stack([x] * self.problem.n_phases),
                                       params["actor"]), design, view)

    def see_only(self, params: dict, view: jax.Array) -> dict:
        """``params`` (or their gradient) with the first layers' weights from the inputs
        outside ``views[view]`` zeroed: networks of that part of the observation alone
        (zero weights get zero gradients, and Adam moves them by zero)."""
        if len(self.views) == 1:
            return params
        mask = jnp.asarray(self.views)[view][:, None]  # [D, 1]

        def first(net: dict) -> dict:
            return {**net, "layer_0": {**net["layer_0"], "kernel": net["layer_0"]["kernel"] * mask}}

        return {"actor": first(params["actor"]),
                "critics": {**params["critics"], "heads": first(params["critics"]["heads"])}}

    # -------------------------------------------------------------- policy
    def acting(self, state: TrainState, slack: jax.Array,
               phase: jax.Array | None = None) -> Acting:
        """What the policy of ``state`` needs to act at ``slack`` under the constraints of
        ``phase`` (by default the last update's, at most the reference's)."""
        if phase is None:
            phase = jnp.minimum(self.phase_of(jnp.maximum(state.update - 1, 0)),
                                self.problem.reference)
        return Acting(state.params["actor"], state.params["critics"], state.value_norm,
                      jnp.asarray(slack, jnp.float32), jnp.asarray(phase, jnp.int32))

    def policy(self, acting: Acting, obs: jax.Array) -> Distribution:
        """``pi(. | obs)``: the actor's distribution, within the admissible actions in
        the restriction form."""
        return self.restricted(acting.actor, obs, self.form.allowed(self.critics, acting, obs))

    def restricted(self, actor_params: dict, obs: jax.Array,
                   allowed: jax.Array | None) -> Distribution:
        """The actor's distribution at ``obs``, within ``allowed`` (the form's)."""
        return self.form.restrict(self.actor.apply({"params": actor_params}, obs), allowed)

    def values(self, state: TrainState, obs: jax.Array) -> jax.Array:
        """Every critic head's outputs ``[..., P, n_out]`` at ``obs``, as values
        (``[..., 0]`` is ``V``, ``[..., 1 + a]`` is ``Q(., a) - V``)."""
        return state.value_norm.denormalize(
            self.critics.apply({"params": state.params["critics"]}, obs))

    # ---------------------------------------------------------------- update
    def phase_of(self, update: jax.Array) -> jax.Array:
        """The phase of an update (the last phase beyond the run's end)."""
        phase = jnp.sum(update >= jnp.asarray(self.phase_start[1:])).astype(jnp.int32)
        return jnp.minimum(phase, self.problem.n_phases - 1)

    def update(self, state: TrainState, slack: jax.Array) -> tuple[TrainState, dict]:
        """One PPO update of the current phase: a rollout of the JAX env, then
        :meth:`begin_phase` and :meth:`learn`."""
        state, rollout, episodes = self.collect(state, slack)
        return self.learn(self.begin_phase(state), slack, rollout, episodes)

    def collect(self, state: TrainState, slack: jax.Array) -> tuple[TrainState, Rollout, dict]:
        """``num_steps`` steps of every env under the current policy, and the
        statistics of the episodes that finished."""
        env, cfg = self.env, self.config
        acting = self.acting(state, slack, self.phase_of(state.update))

        def step(carry, key):
            env_state, obs, stats = carry
            k_act, k_env = jax.random.split(key)
            action, log_prob, allowed, explore = self.behave(acting, obs, k_act)
            obs2, env_state, reward, term, trunc, info = jax.vmap(
                env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(k_env, cfg.num_envs), env_state, action, env.params)
            done = (term | trunc).astype(jnp.float32)
            out = Rollout(obs, action, log_prob, reward, info["final_obs"],
                          term.astype(jnp.float32), done, allowed, explore)
            return (env_state, obs2, stats.update(reward, done)), out

        key, k_roll = jax.random.split(state.key)
        (env_state, obs, stats), rollout = jax.lax.scan(
            step, (state.env_state, state.obs, state.episodes.clear()),
            jax.random.split(k_roll, cfg.num_steps))
        state = state.replace(env_state=env_state, obs=obs, key=key, episodes=stats)
        return state, rollout, stats.summary()

    def behave(self, acting: Acting, obs: jax.Array, key: jax.Array
               ) -> tuple[jax.Array, jax.Array, jax.Array | None, jax.Array]:
        """The actions of a rollout step at ``obs [E, D]``, their log-probabilities
        under the policy, the admissible actions and the exploring flags (float;
        :meth:`tpo.algo.forms.RestrictionForm.explore`)."""
        k_pi, k_explore, k_uniform = jax.random.split(key, 3)
        allowed = self.form.allowed(self.critics, acting, obs)
        pi = self.restricted(acting.actor, obs, allowed)
        action, explore = self.form.explore(pi.sample(k_pi), allowed, k_explore, k_uniform)
        return action, pi.log_prob(action), allowed, explore

    def learn(self, state: TrainState, slack: jax.Array, rollout: Rollout,
              episodes: dict) -> tuple[TrainState, dict]:
        """The update from one rollout (of any source), after :meth:`begin_phase`."""
        phase = self.phase_of(state.update)
        batch, penalty, value_norm = self.lagrangian_targets(state, slack, rollout, phase)
        lr = jnp.asarray(self.learning_rate(state.update), jnp.float32)
        ent_coef = jnp.asarray(self.ent_coef(state.update), jnp.float32)
        state, losses = self.ppo_epochs(state, batch, phase, value_norm, lr, ent_coef)
        snapshots = jax.tree.map(lambda s, a: s.at[phase].set(a), state.snapshots,
                                 state.params["actor"])
        state = state.replace(snapshots=snapshots)
        # A phase that starts from another phase's final policy than the one before it
        # (Problem.start) gets it now, so that its first rollout is already its own.
        start = self.problem.start
        if np.any(start != np.arange(len(start)) - 1):
            after = self.phase_of(state.update)
            source = jnp.asarray(start)[after]
            switch = (state.update == jnp.asarray(self.phase_start)[after]) & (source != phase)
            actor = _where_tree(switch, jax.tree.map(lambda s: s[source], state.snapshots),
                                state.params["actor"])
            state = state.replace(params={**state.params, "actor": actor})
        excluded = self.form.excluded(rollout.allowed)
        metrics = {"phase": phase, "lr": lr,
                   "penalty": penalty.mean(), "violation_rate": (penalty > 0).mean(),
                   "excluded": excluded, **episodes, **jax.tree.map(jnp.mean, losses)}
        return state, metrics

    def begin_phase(self, state: TrainState) -> TrainState:
        """At a phase's first update, between its rollout (the previous policy's,
        sharp) and :meth:`learn`: restart both optimisers and soften the policy
        (logits divided by ``carry_temperature``); else the state unchanged."""
        phase = self.phase_of(state.update)
        first = state.update == jnp.asarray(self.phase_start)[phase]
        soften = first & (phase > 0)
        actor = scale_output(state.params["actor"],
                             jnp.where(soften, 1.0 / self.config.carry_temperature, 1.0))
        params = {**state.params, "actor": actor}
        return state.replace(
            params=params,
            actor_opt=_where_tree(first, self.optimizer.init(actor), state.actor_opt),
            critic_opt=_where_tree(first, self.optimizer.init(params["critics"]),
                                   state.critic_opt))

    def lagrangian_targets(self, state: TrainState, slack: jax.Array, rollout: Rollout,
                           phase: jax.Array) -> tuple[Batch, jax.Array, ValueNorm]:
        """The phase's training batch (:func:`tpo.algo.constraints.lagrangian_terms`),
        the penalty of every transition ``[T, E]`` and the value statistics with the
        new targets folded in."""
        cfg, terms = self.config, self.terms
        value, next_value = self.rollout_values(state, rollout)
        advantage, target, penalty = lagrangian_terms(
            terms, phase, slack, rollout.reward, value, next_value, rollout.terminated,
            rollout.done, rollout.explore, self.loose_tolerance(state),
            trace_decay(terms, state.design))
        q_target = self.form.q_target(rollout.reward, value, next_value, rollout.terminated)
        batch = Batch(rollout.obs, rollout.action, rollout.log_prob, advantage, target,
                      q_target, rollout.allowed, 1.0 - rollout.explore)
        batch = jax.tree.map(lambda x: x.reshape(cfg.batch_size, *x.shape[2:]), batch)
        return batch, penalty, state.value_norm.update(
            target, jax.nn.one_hot(phase, self.problem.n_phases))

    def loose_tolerance(self, state: TrainState) -> jax.Array:
        """The loose constraints' tolerance ``[C]`` of ``state``'s design
        (:func:`tpo.algo.constraints.loose_tolerance`)."""
        return loose_tolerance(self.terms, state.design, state.value_norm.stats()[1])

    def rollout_values(self, state: TrainState, rollout: Rollout
                       ) -> tuple[jax.Array, jax.Array]:
        """Every head's ``V(s_t)`` and ``V(s_{t+1})`` ``[T, E, P]`` in one critic call on
        ``T + own_next`` rows a copy: ``s_{t+1}`` is the next step's observation, but
        after a truncation and at the last step the true ``final_obs``."""
        obs, final_obs = rollout.obs, rollout.final_obs
        steps, envs = obs.shape[:2]
        needed = (rollout.done > rollout.terminated).at[-1].set(True)  # truncated, or last
        slots = jnp.argsort(~needed, axis=0, stable=True)[:self.own_next]  # [K, E], needed first
        extra = jnp.take_along_axis(
            final_obs, slots.reshape(*slots.shape, *[1] * (final_obs.ndim - 2)), axis=0)
        out = self.values(state, jnp.concatenate([obs, extra]))[..., 0]  # [T + K, E, P]
        value = out[:steps]
        next_value = jnp.concatenate([value[1:], value[-1:]]).at[
            slots, jnp.arange(envs)].set(out[steps:])
        return value, next_value

    def ppo_epochs(self, state: TrainState, batch: Batch, phase: jax.Array,
                   value_norm: ValueNorm, lr: jax.Array, ent_coef: jax.Array
                   ) -> tuple[TrainState, dict]:
        """``update_epochs`` passes of minibatch steps over ``batch`` at learning rate
        ``lr`` and entropy weight ``ent_coef``: the clipped surrogate of the actor and
        the phase critic's normalised value loss."""
        cfg = self.config
        scale = value_norm.stats()

        def minibatch(carry, mb: Batch):
            params, actor_opt, critic_opt = carry
            grads, info = jax.grad(self._loss, has_aux=True)(params, mb, phase, scale,
                                                              ent_coef)
            grads = self.see_only(grads, state.view)
            a_up, actor_opt = self.optimizer.update(grads["actor"], actor_opt)
            c_up, critic_opt = self.optimizer.update(
                self.form.trainable(grads["critics"], phase), critic_opt)
            params = {"actor": optax.apply_updates(params["actor"], a_up),
                      "critics": optax.apply_updates(params["critics"], c_up)}
            return (params, actor_opt, critic_opt), info

        def epoch(carry, key):
            perm = jax.random.permutation(key, cfg.batch_size)
            shuffled = jax.tree.map(
                lambda x: x[perm].reshape(cfg.num_minibatches, -1, *x.shape[1:]), batch)
            return jax.lax.scan(minibatch, carry, shuffled)

        key, k_epochs = jax.random.split(state.key)
        carry = (state.params,
                 optax.tree_utils.tree_set(state.actor_opt, learning_rate=lr),
                 optax.tree_utils.tree_set(state.critic_opt, learning_rate=lr))
        (params, actor_opt, critic_opt), losses = jax.lax.scan(
            epoch, carry, jax.random.split(k_epochs, cfg.update_epochs))
        state = state.replace(params=params, actor_opt=actor_opt, critic_opt=critic_opt,
                              key=key, update=state.update + 1, value_norm=value_norm)
        return state, losses

    def _loss(self, params: dict, mb: Batch, phase: jax.Array,
              scale: tuple[jax.Array, jax.Array], ent_coef: jax.Array
              ) -> tuple[jax.Array, dict]:
        cfg = self.config
        pi = self.restricted(params["actor"], mb.obs, mb.allowed)
        log_ratio = pi.log_prob(mb.action) - mb.log_prob
        pg = clipped_surrogate(log_ratio, normalize(mb.advantage, mb.weight), cfg.clip_eps,
                               mb.weight)
        ent = pi.entropy().mean()
        mean, std = scale
        value, adv_loss = self.form.critic_outputs(self.critics, params["critics"], mb, phase,
                                                   std)
        vl = 0.5 * weighted_mean((value - (mb.target - mean[phase]) / std[phase]) ** 2,
                                 mb.weight) + 0.5 * adv_loss
        total = pg - ent_coef * ent + cfg.vf_coef * vl
        kl = weighted_mean((jnp.exp(log_ratio) - 1) - log_ratio, mb.weight)
        return total, {"policy_loss": pg, "value_loss": vl, "entropy": ent, "approx_kl": kl}

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


def _where_tree(cond: jax.Array, a: Any, b: Any) -> Any:
    return jax.tree.map(lambda x, y: jnp.where(cond, x, y), a, b)
