"""Episode statistics of a batch of envs as a pytree with a pure update (the idea
of PureJaxRL's ``LogWrapper``, for vector rewards).

The update uses array operators only, so the same code runs on JAX arrays
inside a compiled rollout and on NumPy arrays in a host-stepped one.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
from flax import struct


@struct.dataclass
class EpisodeStats:
    """Running undiscounted returns ``[E, k]`` and lengths ``[E]`` of the episodes in
    progress, and the totals of the episodes finished since :meth:`clear`."""

    returns: Any
    lengths: Any
    finished: Any  # [] episodes finished
    finished_return: Any  # [k] sum of their returns
    finished_length: Any  # [] sum of their lengths

    @classmethod
    def init(cls, num_envs: int, k: int) -> EpisodeStats:
        return cls(jnp.zeros((num_envs, k)), jnp.zeros(num_envs), jnp.zeros(()),
                   jnp.zeros(k), jnp.zeros(()))

    def update(self, reward: Any, done: Any) -> EpisodeStats:
        """After one step of every env: ``reward [..., E, k]``, ``done [..., E]``
        (float; the episode ended, terminated or truncated); leading axes are
        independent learners' (a population's members)."""
        returns, lengths = self.returns + reward, self.lengths + 1
        return EpisodeStats(returns * (1 - done[..., None]), lengths * (1 - done),
                            self.finished + done.sum(-1),
                            self.finished_return + (returns * done[..., None]).sum(-2),
                            self.finished_length + (lengths * done).sum(-1))

    def clear(self) -> EpisodeStats:
        """The same episodes in progress, no finished ones counted."""
        return self.replace(finished=self.finished * 0,
                            finished_return=self.finished_return * 0,
                            finished_length=self.finished_length * 0)

    def summary(self) -> dict[str, Any]:
        """``episodes`` finished, their mean ``episode_return [k]`` and
        ``episode_length`` (zeros when none finished)."""
        n = jnp.maximum(self.finished, 1.0)
        return {"episodes": jnp.float32(self.finished),
                "episode_return": jnp.asarray(self.finished_return / n, jnp.float32),
                "episode_length": jnp.float32(self.finished_length / n)}
