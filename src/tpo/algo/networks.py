"""Policy and critics: one actor, one critic per objective (Flax linen).

Orthogonal initialisation as in PPO implementations (hidden gain sqrt(2),
policy head 0.01, value heads 1). Parameters are created by :func:`init_params`
*outside* any vmapped function: DESIGN.md §6 saw ``jit(vmap(train))`` with the
orthogonal initialiser inside deadlock in a batched QR.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

ACTIVATIONS = {"tanh": nn.tanh, "relu": nn.relu}


class MLP(nn.Module):
    hidden: Sequence[int]
    out: int
    out_gain: float
    activation: str = "tanh"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        act = ACTIVATIONS[self.activation]
        for width in self.hidden:
            x = act(nn.Dense(width, kernel_init=nn.initializers.orthogonal(np.sqrt(2)),
                             bias_init=nn.initializers.zeros)(x))
        return nn.Dense(self.out, kernel_init=nn.initializers.orthogonal(self.out_gain),
                        bias_init=nn.initializers.zeros)(x)


class Actor(nn.Module):
    """Categorical logits ``[A]``, or a diagonal Gaussian's mean ``[d]`` and log-std."""

    hidden: Sequence[int]
    n_out: int
    continuous: bool
    activation: str = "tanh"

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        out = MLP(self.hidden, self.n_out, 0.01, self.activation)(obs)
        if not self.continuous:
            return out, jnp.zeros(())
        log_std = self.param("log_std", nn.initializers.zeros, (self.n_out,))
        return out, log_std


class Critics(nn.Module):
    """``k`` independent value networks (stacked parameters ``[k, ...]``): ``[..., k]``.

    Each head predicts its objective's *normalised* value; :class:`ValueNorm`
    turns it into a value.
    """

    hidden: Sequence[int]
    k: int
    activation: str = "tanh"

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        heads = nn.vmap(MLP, variable_axes={"params": 0}, split_rngs={"params": True},
                        in_axes=None, out_axes=-1, axis_size=self.k)
        return heads(self.hidden, 1, 1.0, self.activation)(obs)[..., 0, :]

    def head(self, params: dict, column: jax.Array, obs: jax.Array) -> jax.Array:
        """Head ``column``'s output ``[...]`` alone (one MLP instead of ``k``; the
        gradient reaches only that head's slice of ``params``)."""
        one = jax.tree.map(lambda x: x[column], params["VmapMLP_0"])
        mlp = MLP(self.hidden, 1, 1.0, self.activation, parent=None)
        return mlp.apply({"params": one}, obs)[..., 0]


class ValueNorm(NamedTuple):
    """Running statistics of each objective's value targets, ``[k]`` each.

    A critic head learns ``(V - mean) / std``; the statistics of objective ``i``
    move only during its own phase, so they freeze with its critic.
    """

    mean: jax.Array
    mean_sq: jax.Array
    weight: jax.Array  # debiasing weight of the exponential averages

    @classmethod
    def init(cls, k: int) -> ValueNorm:
        return cls(jnp.zeros(k), jnp.zeros(k), jnp.zeros(k))

    def stats(self) -> tuple[jax.Array, jax.Array]:
        w = jnp.maximum(self.weight, 1e-6)
        mean = jnp.where(self.weight > 0, self.mean / w, 0.0)
        var = jnp.where(self.weight > 0, self.mean_sq / w - mean**2, 1.0)
        return mean, jnp.sqrt(jnp.maximum(var, 1e-4))

    def denormalize(self, out: jax.Array) -> jax.Array:
        mean, std = self.stats()
        return out * std + mean

    def normalize(self, values: jax.Array) -> jax.Array:
        mean, std = self.stats()
        return (values - mean) / std

    def update(self, targets: jax.Array, pick: jax.Array, decay: float = 0.9) -> ValueNorm:
        """Fold the batch ``targets`` (of the objective ``pick`` one-hots) into the stats."""
        d = 1.0 - (1.0 - decay) * pick
        return ValueNorm(self.mean * d + (1 - d) * targets.mean(),
                         self.mean_sq * d + (1 - d) * jnp.mean(targets**2),
                         self.weight * d + (1 - d))


def init_params(key: jax.Array, actor: Actor, critics: Critics,
                obs_shape: tuple[int, ...]) -> dict:
    """``{"actor": ..., "critics": ...}`` for one seed (call outside vmap)."""
    k_actor, k_critic = jax.random.split(key)
    dummy = jnp.zeros(obs_shape, jnp.float32)
    return {"actor": actor.init(k_actor, dummy)["params"],
            "critics": critics.init(k_critic, dummy)["params"]}


# ------------------------------------------------------------- distributions
def log_prob(logits_or_mean: jax.Array, log_std: jax.Array, action: jax.Array,
             continuous: bool) -> jax.Array:
    if continuous:
        z = (action - logits_or_mean) / jnp.exp(log_std)
        return jnp.sum(-0.5 * z**2 - log_std - 0.5 * jnp.log(2 * jnp.pi), axis=-1)
    logp = jax.nn.log_softmax(logits_or_mean)
    return jnp.take_along_axis(logp, action[..., None].astype(jnp.int32), -1)[..., 0]


def entropy(logits_or_mean: jax.Array, log_std: jax.Array, continuous: bool) -> jax.Array:
    if continuous:
        return jnp.sum(log_std + 0.5 * jnp.log(2 * jnp.pi * jnp.e)) * jnp.ones(
            logits_or_mean.shape[:-1])
    logp = jax.nn.log_softmax(logits_or_mean)
    return -jnp.sum(jnp.exp(logp) * logp, axis=-1)


def sample(key: jax.Array, logits_or_mean: jax.Array, log_std: jax.Array,
           continuous: bool) -> jax.Array:
    if continuous:
        noise = jax.random.normal(key, logits_or_mean.shape)
        return logits_or_mean + jnp.exp(log_std) * noise
    return jax.random.categorical(key, logits_or_mean)


def mode(logits_or_mean: jax.Array, continuous: bool) -> jax.Array:
    """The greedy action."""
    return logits_or_mean if continuous else jnp.argmax(logits_or_mean, axis=-1)
