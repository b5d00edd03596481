"""The policy's action distributions: categorical (discrete actions) and diagonal
Gaussian (continuous actions), with one interface, so no caller asks which.

Both are pytrees (``flax.struct``), so they pass through ``jit``, ``vmap`` and
``scan``; leading axes are batch axes.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

MASKED = -1e9  # the logit of an action outside the allowed set (finite: no NaN in 0 * log 0)


@struct.dataclass
class Categorical:
    """``pi(a | s) = softmax(logits)_a`` over ``A`` actions; ``logits [..., A]``."""

    logits: jax.Array

    def restrict(self, allowed: jax.Array) -> Categorical:
        """``pi`` renormalised over the actions where ``allowed [..., A]`` is true
        (the others get probability 0; at least one per row must be allowed)."""
        return Categorical(jnp.where(allowed, self.logits, MASKED))

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.categorical(key, self.logits)

    def mode(self) -> jax.Array:
        """The greedy action (the lowest index among equal logits)."""
        return jnp.argmax(self.logits, axis=-1)

    def log_prob(self, action: jax.Array) -> jax.Array:
        logp = jax.nn.log_softmax(self.logits)
        return jnp.take_along_axis(logp, action[..., None].astype(jnp.int32), -1)[..., 0]

    def entropy(self) -> jax.Array:
        logp = jax.nn.log_softmax(self.logits)
        return -jnp.sum(jnp.exp(logp) * logp, axis=-1)


@struct.dataclass
class DiagGaussian:
    """``N(mean, diag(exp(log_std)^2))``; ``mean [..., d]``, ``log_std [d]`` (shared
    by every state, as in PPO)."""

    mean: jax.Array
    log_std: jax.Array

    def sample(self, key: jax.Array) -> jax.Array:
        return self.mean + jnp.exp(self.log_std) * jax.random.normal(key, self.mean.shape)

    def mode(self) -> jax.Array:
        return self.mean

    def log_prob(self, action: jax.Array) -> jax.Array:
        z = (action - self.mean) / jnp.exp(self.log_std)
        return jnp.sum(-0.5 * z**2 - self.log_std - 0.5 * jnp.log(2 * jnp.pi), axis=-1)

    def entropy(self) -> jax.Array:
        return jnp.sum(self.log_std + 0.5 * jnp.log(2 * jnp.pi * jnp.e)) * jnp.ones(
            self.mean.shape[:-1])


Distribution = Categorical | DiagGaussian
