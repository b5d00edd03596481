"""What the JAX navigation environments share: auto-reset and the reward vector."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from tpo.envs.maps import OBJECTIVES


def nav_reward(avoid: jax.Array, monitor: jax.Array, cell: jax.Array,
               bump: jax.Array) -> jax.Array:
    """``[goal, avoid, monitor]`` of a step that starts in ``cell`` (docs/design.md §3):
    goal -1; avoid -1 inside an avoid region, -1 per bump; monitor +1 inside, -1 per bump."""
    in_avoid = avoid[cell[0], cell[1]].astype(jnp.float32)
    in_monitor = monitor[cell[0], cell[1]].astype(jnp.float32)
    bumped = bump.astype(jnp.float32)
    return jnp.stack([jnp.float32(-1.0), -(in_avoid + bumped), in_monitor - bumped])


class JaxEnv:
    """A pure functional environment: subclasses define ``reset`` and ``step_env``
    as static methods ``(key, [state, action,] params)``; ``step`` adds auto-reset."""

    objectives = OBJECTIVES
    reward_low = np.array([-1.0, -2.0, -1.0], np.float32)  # per-step bounds of nav_reward
    reward_high = np.array([-1.0, 0.0, 1.0], np.float32)
    params: Any  # the env's parameters, with ``max_steps``

    @property
    def max_steps(self) -> int:
        """The time limit: an episode is truncated after this many steps."""
        return int(self.params.max_steps)

    @classmethod
    def step(cls, key: jax.Array, state: Any, action: jax.Array, params: Any
             ) -> tuple[jax.Array, Any, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        """One step with auto-reset: ``(obs, state, reward[k], terminated, truncated, info)``.

        When the episode ends the returned observation and state are the next
        episode's first; ``info["final_obs"]`` holds the true next observation.
        """
        k_step, k_reset = jax.random.split(key)
        obs, nxt, reward, terminated, truncated = cls.step_env(k_step, state, action, params)
        obs_reset, state_reset = cls.reset(k_reset, params)
        done = terminated | truncated
        state = jax.tree.map(lambda r, n: jnp.where(done, r, n), state_reset, nxt)
        return (jnp.where(done, obs_reset, obs), state, reward, terminated, truncated,
                {"final_obs": obs})
