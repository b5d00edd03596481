"""What the JAX environments share: auto-reset, the navigation reward vector, and a
Gymnasium front end that steps one of them a transition at a time."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from tpo.envs.maps import OBJECTIVES
from tpo.tabular.judge import ABS_TOL


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
    #: the judge's absolute tolerance (tpo.tabular.judge): 0.5 on the navigation
    #: maps; None, scale-free, where rewards have no such unit
    absolute_tolerance: float | None = ABS_TOL

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


_JITTED: dict[type, tuple[Any, Any]] = {}


def _compiled(cls: type[JaxEnv]) -> tuple[Any, Any]:
    """Jitted ``reset`` and ``step_env`` of an env class, shared by all its instances."""
    if cls not in _JITTED:
        _JITTED[cls] = (jax.jit(cls.reset), jax.jit(cls.step_env))
    return _JITTED[cls]


class JaxGymEnv(gym.Env):
    """A Gymnasium env stepping a pure JAX env one transition at a time, with
    MO-Gymnasium's vector reward (``reward_space``, ``reward_dim``). ``info`` holds
    :meth:`_info` of the state reached."""

    def __init__(self, jax_env: JaxEnv, observation_space: gym.Space,
                 action_space: gym.Space) -> None:
        self.jax_env = jax_env
        self.observation_space = observation_space
        self.action_space = action_space
        self.reward_space = gym.spaces.Box(jax_env.reward_low, jax_env.reward_high,
                                           dtype=np.float32)
        self.reward_dim = len(jax_env.objectives)
        self.objectives = jax_env.objectives
        self._reset, self._step = _compiled(type(jax_env))
        self._state = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        del state["_reset"], state["_step"]  # jitted functions; rebuilt on unpickling
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._reset, self._step = _compiled(type(self.jax_env))

    def _key(self) -> jax.Array:
        return jax.random.key(int(self.np_random.integers(2**31)))

    def reset(self, *, seed: int | None = None, options: dict | None = None
              ) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        obs, self._state = self._reset(self._key(), self.jax_env.params)
        return np.asarray(obs), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, np.ndarray, bool, bool, dict]:
        if self._state is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        obs, self._state, reward, terminated, truncated = self._step(
            self._key(), self._state, self._jax_action(action), self.jax_env.params)
        return (np.asarray(obs), np.asarray(reward, np.float32), bool(terminated),
                bool(truncated), self._info())

    def _jax_action(self, action: Any) -> Any:
        return np.int32(action)

    def _info(self) -> dict[str, Any]:
        return {}
