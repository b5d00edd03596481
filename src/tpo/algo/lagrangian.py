"""Generalized Lagrangian advantage estimation (paper §IV, Eq. 10; docs/design.md §5).

Objective ``i``'s PPO phase penalises each transition by
``beta * sum_{(w,v) in E_i} C_wv(s_t, a_t)`` with
``C_wv = max(0, -A_w(s_t, a_t) - eta_wv)``, where the ancestral advantage comes
from the frozen critic of ``w``: ``A_w = r_w + gamma V_w(s_{t+1}) - V_w(s_t)``.

Three forms of the advantage:

- ``"penalized"`` (the paper's): GAE on the Lagrangian reward
  ``r_i - beta * penalty`` (Eq. 6's reward) with critic ``V_i`` trained on its
  returns. Its gradient is Prop. 3's; a violating action's own advantage carries
  its penalty.
- ``"traced"`` (the grid's default; the continuous robot takes ``"immediate"``):
  ``GAE(r_t) - beta sum_l (gamma lambda)^l penalty_{t+l}``, the penalized form's
  advantage with critic ``V_i`` on the raw returns (GAE is linear in the reward):
  a frozen critic values its objective, not its Lagrangian, so the constraints its
  descendants read from it measure that objective alone; the penalties ahead are
  summed over GAE's horizon, not bootstrapped.
- ``"immediate"``: ``GAE(r_t) - beta penalty_t``: each violation on the action that
  commits it and on no other (Prop. 1's ``C_wv(s, a)`` as a per-state price, never
  summed along the path), and critic ``V_i`` learns the raw returns. The policy's
  fixed point compares actions state by state, as LAR's admissible sets and its
  relaxation of an infeasible state do (docs/design.md §2).
"""

from __future__ import annotations

from typing import Literal

import jax
import jax.numpy as jnp

from tpo.algo.losses import check_shapes, discounted_cumsum, gae

#: tpo.algo.config.ADVANTAGE_FORMS
AdvantageForm = Literal["traced", "immediate", "penalized"]


def ancestral_advantages(rewards: jax.Array, values: jax.Array, next_values: jax.Array,
                         terminated: jax.Array, gamma: float) -> jax.Array:
    """One-step advantages ``A_w = r_w + gamma (1 - term) V_w(s') - V_w(s)`` of every
    objective, ``[..., k]``."""
    return rewards + gamma * (1.0 - terminated[..., None]) * next_values - values


def violations(advantages: jax.Array, parents: jax.Array, slack: jax.Array,
               telescope: bool | jax.Array = False, dead_zone: float | jax.Array = 0.0
               ) -> jax.Array:
    """``C_wv = max(0, -A_w - eta_wv)`` for every constraint (an edge ``(w, v)``, whose
    parent's advantage is column ``parents[c]``): ``[..., k] -> [..., C]`` (Prop. 1
    with the one-step advantage standing in for ``Q_w - V_w``). Where ``telescope``
    (one flag, or one per constraint ``[C]``), ``C_wv = -A_w`` where ``eta_wv`` is 0:
    equal under the parent's optimal critic (``A_w <= 0``), and a learned critic's
    errors then cancel along a path; soft-thresholded by ``dead_zone`` ``d`` (one value,
    or one per constraint), ``C_wv = sign(-A_w) max(0, |A_w| - d)``: an advantage
    within ``d`` of 0 charges nothing."""
    if jnp.ndim(parents) != 1 or jnp.shape(slack) != jnp.shape(parents):
        raise ValueError(f"parents {jnp.shape(parents)} and slack {jnp.shape(slack)} must "
                         "be [C] each")
    adv = advantages[..., parents]
    c = jnp.maximum(0.0, -adv - slack)
    shrunk = -jnp.sign(adv) * jnp.maximum(0.0, jnp.abs(adv) - dead_zone)
    return jnp.where(jnp.asarray(telescope) & (slack <= 0), shrunk, c)


def below_best(advantages: jax.Array, allowed: jax.Array) -> jax.Array:
    """``Q(s, a) - max_{a' in allowed} Q(s, a')`` from advantages ``Q - V`` (any ``V``:
    it cancels), ``[..., A]`` each: how far each action falls below the best allowed
    one. LAR measures violations this way (``V_w = max_{A_w} Q_w``); on learned
    critics it also cancels any error the advantages share at a state."""
    check_shapes(advantages, allowed=allowed)
    return advantages - jnp.max(jnp.where(allowed, advantages, -jnp.inf), axis=-1,
                                keepdims=True)


def admissible(advantages: jax.Array, slack: jax.Array, active: jax.Array) -> jax.Array:
    """LAR's admissible actions from learned advantages (docs/design.md §2): the
    actions of least total violation

        sum_c active_c max(0, -(Q_c(s, a) - V_c(s)) - slack_c),

    which are the actions of zero violation whenever there are any, and otherwise
    the relaxed solver's choice. ``advantages [..., C, A]`` are ``Q - V`` of the
    critic each constraint ``c`` reads; ``slack [C]`` includes any tolerance;
    ``active [C]`` selects the constraints that hold. Returns ``[..., A]`` bool.
    """
    if jnp.shape(slack) != jnp.shape(active) or jnp.shape(advantages)[-2:-1] != jnp.shape(slack):
        raise ValueError(f"advantages {jnp.shape(advantages)}, slack {jnp.shape(slack)} and "
                         f"active {jnp.shape(active)} must be [..., C, A], [C] and [C]")
    excess = jnp.maximum(0.0, -advantages - slack[:, None])
    total = jnp.einsum("...ca,c->...a", excess, active)
    return total <= total.min(axis=-1, keepdims=True) + 1e-6


def lagrangian_advantages(form: AdvantageForm, reward: jax.Array, value: jax.Array,
                          next_value: jax.Array, penalty: jax.Array, beta: jax.Array,
                          terminated: jax.Array, done: jax.Array, gamma: float, lam: float,
                          trace_decay: float | jax.Array | None = None
                          ) -> tuple[jax.Array, jax.Array]:
    """Advantages and critic targets of the phase's objective (time-major ``[T, ...]``).

    ``penalty`` is ``sum_{E_i} C`` per transition; ``beta`` the multiplier;
    ``trace_decay`` the traced form's ``gamma lambda'`` (by default ``gamma lambda``)::

        penalized: A_t = GAE(r_t - beta penalty_t)
        immediate: A_t = GAE(r_t) - beta penalty_t
        traced:    A_t = GAE(r_t) - beta sum_l (gamma lambda')^l penalty_{t+l}
    """
    check_shapes(reward, value=value, next_value=next_value, penalty=penalty,
                 terminated=terminated, done=done)
    if jnp.ndim(beta) != 0:
        raise ValueError(f"beta must be a scalar, got shape {jnp.shape(beta)}")
    if form == "penalized":
        return gae(reward - beta * penalty, value, next_value, terminated, done, gamma, lam)
    advantages, targets = gae(reward, value, next_value, terminated, done, gamma, lam)
    if form == "immediate":
        return advantages - beta * penalty, targets
    decay = gamma * lam if trace_decay is None else trace_decay
    return advantages - beta * discounted_cumsum(penalty, decay, done), targets
