"""The policy's action distributions: categorical (discrete actions), and for
continuous actions a diagonal Gaussian or a factorised categorical over evenly
spaced values of each dimension, with one interface, so no caller asks which.

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


@struct.dataclass
class Discretized:
    """A continuous action whose dimensions are independent categoricals over ``K``
    evenly spaced values from ``low`` to ``high`` (Tang & Agrawal, "Discretizing
    Continuous Action Space for On-Policy Optimization", AAAI 2020): ``pi(a | s) =
    prod_i softmax(logits_i)_{k_i}`` with ``a_i = low_i + k_i (high_i - low_i) / (K - 1)``.

    ``logits [..., d, K]``, ``low`` and ``high [d]``. Its support is the action box, so
    no sample lies beyond a bound the env clips to (a Gaussian's mean drifts out there:
    docs/notes/tpo-learning.md, session 13), and it explores as a categorical does.
    """

    logits: jax.Array
    low: jax.Array
    high: jax.Array

    def values(self, index: jax.Array) -> jax.Array:
        """The actions ``[..., d]`` of the value indices ``[..., d]``."""
        step = (self.high - self.low) / (self.logits.shape[-1] - 1)
        return self.low + index * step

    def index(self, action: jax.Array) -> jax.Array:
        """The nearest value's index ``[..., d]`` of each dimension of ``action``."""
        k = self.logits.shape[-1]
        x = (action - self.low) / (self.high - self.low) * (k - 1)
        return jnp.clip(jnp.round(x), 0, k - 1).astype(jnp.int32)

    def sample(self, key: jax.Array) -> jax.Array:
        return self.values(jax.random.categorical(key, self.logits))

    def mode(self) -> jax.Array:
        """The most likely value of each dimension (the lowest among equal logits)."""
        return self.values(jnp.argmax(self.logits, axis=-1))

    def log_prob(self, action: jax.Array) -> jax.Array:
        logp = jax.nn.log_softmax(self.logits)
        return jnp.take_along_axis(logp, self.index(action)[..., None], -1)[..., 0].sum(-1)

    def entropy(self) -> jax.Array:
        logp = jax.nn.log_softmax(self.logits)
        return -jnp.sum(jnp.exp(logp) * logp, axis=(-2, -1))


Distribution = Categorical | DiagGaussian | Discretized
