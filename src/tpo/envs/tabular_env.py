"""Any finite TMDP (:class:`tpo.tabular.TabularTMDP`) as a pure JAX environment
(gymnax style), so that seeds, slacks and a population vmap over it as they do on
a map, and every learned policy is judged exactly on the same model.

A state is the model's state index and the episode's time; a step samples the
next state from the model's successor list, pays ``rewards[s, a]``, terminates
in a terminal state and truncates after ``max_steps``. Observations are rows of
a table ``[S, D]``: a one-hot of the state, or any features of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from tpo.envs.base import JaxEnv, JaxGymEnv
from tpo.errors import TPOError
from tpo.graph import ObjectiveGraph
from tpo.tabular import TabularTMDP

MAX_TABLE = 2**24  # numbers of an observation table (64 MB of float32)


@struct.dataclass
class TabularParams:
    """The model's arrays, as the compiled step reads them."""

    successors: jax.Array  # int32 [S, A, B]
    log_probs: jax.Array  # float32 [S, A, B], -inf where a successor has probability 0
    rewards: jax.Array  # float32 [S, A, k]
    terminal: jax.Array  # bool [S]
    obs_table: jax.Array  # float32 [S, D]
    starts: jax.Array  # int32 [N]: the states an episode starts in, uniformly
    max_steps: jax.Array  # int32 []


@struct.dataclass
class TabularState:
    state: jax.Array  # int32 []
    time: jax.Array  # int32 []


@dataclass(frozen=True)
class Tabular:
    """The exact model of a tabular env at a discount (:meth:`TabularEnv.tabular`)."""

    model: TabularTMDP


class TabularEnv(JaxEnv):
    """A :class:`TabularTMDP` as a pure JAX env with discrete actions.

    Args:
        model: the finite TMDP (its ``gamma`` is the default of :meth:`tabular`).
        observations: ``[S, D]`` features of every state, or None for a one-hot.
        max_steps: the time limit of an episode.
        random_start: start every episode in a uniformly random non-terminal state
            (exploring starts, for training) instead of the model's start.
        spec: what rebuilds the env (:func:`tpo.envs.from_spec`), e.g. a
            generator's parameters; by default the model's arrays.
    """

    absolute_tolerance = None  # judged scale-free: rewards have any unit

    def __init__(self, model: TabularTMDP, observations: np.ndarray | None = None,
                 max_steps: int = 200, random_start: bool = False,
                 spec: dict[str, Any] | None = None) -> None:
        n = model.n_states
        table = np.eye(n, dtype=np.float32) if observations is None else np.asarray(
            observations, np.float32)
        if table.ndim != 2 or table.shape[0] != n or table.size > MAX_TABLE \
                or not np.isfinite(table).all():
            raise TPOError(f"observations must be a finite [S={n}, D] table of at most "
                           f"{MAX_TABLE} numbers, got shape {table.shape}")
        if isinstance(max_steps, bool) or not isinstance(max_steps, int) \
                or not 1 <= max_steps <= 10**6:
            raise TPOError(f"max_steps must be an integer from 1 to 1000000, got {max_steps!r}")
        self.model, self.random_start, self._spec = model, random_start, spec
        self._onehot = observations is None
        live = ~model.terminal
        self.objectives = model.objectives
        self.reward_low = model.rewards[live].min(axis=(0, 1)).astype(np.float32)
        self.reward_high = model.rewards[live].max(axis=(0, 1)).astype(np.float32)
        self.action_space = gym.spaces.Discrete(model.n_actions)
        starts = np.flatnonzero(live) if random_start else np.array([model.start])
        with np.errstate(divide="ignore"):
            log_probs = np.log(model.probs).astype(np.float32)
        self.params = TabularParams(
            successors=jnp.asarray(model.successors, jnp.int32),
            log_probs=jnp.asarray(log_probs), rewards=jnp.asarray(model.rewards, jnp.float32),
            terminal=jnp.asarray(model.terminal), obs_table=jnp.asarray(table),
            starts=jnp.asarray(starts, jnp.int32), max_steps=jnp.asarray(max_steps, jnp.int32))

    @property
    def obs_shape(self) -> tuple[int]:
        return (int(self.params.obs_table.shape[-1]),)

    @property
    def observation_onehots(self) -> tuple[tuple[int, int], ...]:
        """A one-hot observation is one block of a single 1 (read by gathers)."""
        return ((0, self.model.n_states),) if self._onehot else ()

    def to_spec(self) -> dict[str, Any]:
        """What rebuilds this env: the spec it was made with, or the model's arrays."""
        if self._spec is not None:
            return {**self._spec, "random_start": self.random_start}
        m = self.model
        return {"kind": "tabular", "successors": m.successors.tolist(),
                "probs": m.probs.tolist(), "rewards": m.rewards.tolist(),
                "terminal": m.terminal.tolist(), "objectives": list(m.objectives),
                "gamma": m.gamma, "start": m.start,
                "observations": None if self._onehot else np.asarray(
                    self.params.obs_table).tolist(),
                "max_steps": int(self.params.max_steps), "random_start": self.random_start}

    # ------------------------------------------------------------ pure JAX API
    @staticmethod
    def reset(key: jax.Array, params: TabularParams) -> tuple[jax.Array, TabularState]:
        """The first observation and state of an episode."""
        s = params.starts[jax.random.randint(key, (), 0, params.starts.shape[0])]
        state = TabularState(state=s, time=jnp.zeros((), jnp.int32))
        return params.obs_table[s], state

    @staticmethod
    def step_env(key: jax.Array, state: TabularState, action: jax.Array, params: TabularParams
                 ) -> tuple[jax.Array, TabularState, jax.Array, jax.Array, jax.Array]:
        """One step without auto-reset: ``(obs, state, reward[k], terminated, truncated)``."""
        s, a = state.state, jnp.asarray(action, jnp.int32)
        b = jax.random.categorical(key, params.log_probs[s, a])
        nxt = params.successors[s, a, b]
        time = state.time + 1
        terminated = params.terminal[nxt]
        truncated = (time >= params.max_steps) & ~terminated
        return (params.obs_table[nxt], TabularState(state=nxt, time=time), params.rewards[s, a],
                terminated, truncated)

    # ------------------------------------------------------- exact evaluation
    def tabular(self, gamma: float | None = None) -> Tabular:
        """The exact model (at ``gamma``, by default the model's own)."""
        return Tabular(self.model if gamma is None else self.model.with_gamma(gamma))

    def tabular_observations(self) -> np.ndarray:
        """``[S, D]``: the observation of every state of the model."""
        return np.asarray(self.params.obs_table)


class TabularGymEnv(JaxGymEnv):
    """A Gymnasium front end of a :class:`TabularEnv` with MO-Gymnasium's vector
    reward; the observation is the state's row of the env's table, ``info["state"]``
    the state's index, and ``graph`` the problem's DAG if it has one."""

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 (Gymnasium's own)

    def __init__(self, jax_env: TabularEnv, graph: ObjectiveGraph | None = None) -> None:
        d = jax_env.obs_shape[0]
        super().__init__(jax_env, gym.spaces.Box(-np.inf, np.inf, (d,), np.float32),
                         jax_env.action_space)
        self.graph = graph

    def _info(self) -> dict[str, Any]:
        return {"state": int(self._state.state)}
