"""PPO's pieces as small pure functions (time-major ``[T, ...]`` arrays).

Each is tested against numbers worked out by hand in ``tests/test_losses.py``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def check_shapes(reference: jax.Array, **arrays: jax.Array) -> None:
    """Raise ``ValueError`` naming the first of ``arrays`` whose shape is not
    ``reference``'s (checked when tracing: it costs nothing at run time)."""
    for name, x in arrays.items():
        if jnp.shape(x) != jnp.shape(reference):
            raise ValueError(f"{name} has shape {jnp.shape(x)}, expected "
                             f"{jnp.shape(reference)}")


def gae(rewards: jax.Array, values: jax.Array, next_values: jax.Array, terminated: jax.Array,
        done: jax.Array, gamma: float, lam: float) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimation with bootstrapping at truncation.

        delta_t = r_t + gamma (1 - terminated_t) V(s_{t+1}) - V(s_t)
        A_t     = delta_t + gamma lambda (1 - done_t) A_{t+1}

    ``next_values`` is ``V`` of the *true* next state (the final observation
    when an episode ended), so a truncated episode bootstraps from its last
    state while a terminated one does not; ``done`` (terminated or truncated)
    cuts the trace. The rollout's last step bootstraps through ``next_values``.

    Returns ``(advantages, value targets = advantages + values)``.
    """
    check_shapes(values, next_values=next_values, rewards=rewards, terminated=terminated,
                 done=done)
    deltas = rewards + gamma * (1.0 - terminated) * next_values - values
    advantages = discounted_cumsum(deltas, gamma * lam, done)
    return advantages, advantages + values


def discounted_cumsum(x: jax.Array, discount: float, done: jax.Array) -> jax.Array:
    """``y_t = x_t + discount (1 - done_t) y_{t+1}``, ``y_T = 0``, backwards over time."""
    def step(carry, inputs):
        x_t, done_t = inputs
        carry = x_t + discount * (1.0 - done_t) * carry
        return carry, carry

    _, out = jax.lax.scan(step, jnp.zeros_like(x[0]), (x, done.astype(x.dtype)), reverse=True)
    return out


def weighted_mean(x: jax.Array, weight: jax.Array | None = None) -> jax.Array:
    """The mean of ``x``, or ``sum(weight x) / sum(weight)`` (0 if no weight)."""
    if weight is None:
        return x.mean()
    check_shapes(x, weight=weight)
    return jnp.sum(weight * x) / jnp.maximum(jnp.sum(weight), 1e-8)


def normalize(x: jax.Array, weight: jax.Array | None = None, eps: float = 1e-8) -> jax.Array:
    """``(x - mean) / (std + eps)`` over the batch (the samples of nonzero ``weight``)."""
    mean = weighted_mean(x, weight)
    return (x - mean) / (jnp.sqrt(weighted_mean((x - mean) ** 2, weight)) + eps)


def clipped_surrogate(log_ratio: jax.Array, advantages: jax.Array, clip: float,
                      weight: jax.Array | None = None) -> jax.Array:
    """PPO's policy loss ``-E[min(rho A, clip(rho, 1 - eps, 1 + eps) A)]`` (a
    ``weight``-ed mean if given)."""
    ratio = jnp.exp(log_ratio)
    return -weighted_mean(jnp.minimum(ratio * advantages,
                                      jnp.clip(ratio, 1.0 - clip, 1.0 + clip) * advantages),
                          weight)
