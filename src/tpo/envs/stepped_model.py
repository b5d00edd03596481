"""Exact tabular models of finite Gymnasium envs, built by stepping the env itself
from every reachable state: the ground truth a learned policy on such an env is
judged by (``tpo.tabular.Judge``).

:func:`stepped_model` takes an :class:`Access` (how to read the env's state as a
hashable key, put the env into a state, and observe it) and explores by breadth
first from the reset state, stepping each action once per random outcome. A
step may draw at most one number from ``env.np_random.random()`` and compare it
with a threshold (``random() < p``, MO-Gymnasium's way): the two outcomes are
found by drawing 0 and almost 1, and ``p`` by bisection on the drawn number, to
the last bit. Rewards are the branches' expectation; every terminating step
leads to one absorbing terminal state. Time limits are truncations, not part of
the model: its values are those of the infinite-horizon discounted problem.

:data:`ACCESS` knows MO-Gymnasium's finite envs: ``deep-sea-treasure-v0``,
``deep-sea-treasure-concave-v0``, ``resource-gathering-v0``,
``breakable-bottles-v0`` and ``fruit-tree-v0``; :func:`mo_gym_model` builds one.
:meth:`SteppedModel.env` serves a model as a pure JAX env.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import gymnasium as gym
import numpy as np

from tpo.envs.gym_adapter import HostEnv, observation_encoder, quiet
from tpo.envs.tabular_env import TabularEnv
from tpo.errors import TPOError
from tpo.tabular import TabularTMDP

MAX_STATES = 200_000  # a breadth-first search that grows past this is refused


@dataclass(frozen=True)
class Access:
    """How :func:`stepped_model` reaches inside one env class (``env.unwrapped``).

    Attributes:
        objectives: a name for each reward component, in order.
        get: the env's current state as a hashable key.
        put: puts the env into the state of a key.
        observe: the observation of the env's current state (what ``step`` returns).
    """

    objectives: tuple[str, ...]
    get: Callable[[Any], Hashable]
    put: Callable[[Any, Hashable], None]
    observe: Callable[[Any], Any]


@dataclass(frozen=True, eq=False)
class SteppedModel:
    """An env's exact model.

    Attributes:
        model: the finite TMDP; state 0 is the reset state, the last the terminal one.
        keys: each non-terminal state's key (``Access.get``).
        observations: ``[S, D]`` each state's observation as the learner reads it
            (the terminal state's is zeros).
        branch_rewards: ``[S, A, B, k]`` the reward of each random outcome
            (``model.rewards`` is their expectation).
    """

    model: TabularTMDP
    keys: tuple[Hashable, ...]
    observations: np.ndarray
    branch_rewards: np.ndarray

    def index(self, key: Hashable) -> int:
        """The state of a key."""
        return self._states[key]

    @cached_property
    def _states(self) -> dict[Hashable, int]:
        return {k: i for i, k in enumerate(self.keys)}

    def env(self, random_start: bool = False, max_steps: int = 100) -> TabularEnv:
        """The model as a pure JAX env (vmappable; exploring starts with
        ``random_start``), observed as the real env is; MO-Gymnasium's time limit
        is 100 steps."""
        return TabularEnv(self.model, self.observations, max_steps, random_start)


class _Draw:
    """Stands in for ``env.np_random``: ``random()`` returns ``u`` and is counted."""

    def __init__(self, u: float) -> None:
        self.u, self.calls = u, 0

    def random(self) -> float:
        self.calls += 1
        return self.u


def _outcome(env: Any, access: Access, key: Hashable, action: int, u: float
             ) -> tuple[tuple, int]:
    """``((next key or None if terminated, reward), draws)`` of one step drawn at ``u``."""
    access.put(env, key)
    env.np_random = draw = _Draw(u)
    _, reward, terminated, _, _ = env.step(action)
    reward = tuple(np.asarray(reward, np.float64).reshape(-1).tolist())
    return (None if terminated else access.get(env), reward), draw.calls


def _branches(env: Any, access: Access, key: Hashable, action: int
              ) -> list[tuple[float, tuple]]:
    """``[(probability, (next key, reward)), ...]`` of one state and action."""
    low, calls = _outcome(env, access, key, action, 0.0)
    if calls == 0:
        return [(1.0, low)]
    if calls > 1:
        raise TPOError(f"{type(env).__name__}.step draws {calls} random numbers in one "
                       "step: a stepped model supports at most one")
    high, _ = _outcome(env, access, key, action, float(np.nextafter(1.0, 0.0)))
    if high == low:
        return [(1.0, low)]
    lo, hi = 0.0, float(np.nextafter(1.0, 0.0))  # outcome(lo) = low, outcome(hi) = high
    while np.nextafter(lo, 1.0) < hi:
        mid = (lo + hi) / 2
        if _outcome(env, access, key, action, mid)[0] == low:
            lo = mid
        else:
            hi = mid
    return [(hi, low), (1.0 - hi, high)]


def stepped_model(make: Callable[[], gym.Env], access: Access, gamma: float = 0.99,
                  seed: int = 0) -> SteppedModel:
    """The exact model of the env ``make()`` builds, from its reset state (seed
    ``seed``), explored by stepping it (module docstring)."""
    wrapped = make()
    env = wrapped.unwrapped
    encode, (width,) = observation_encoder(wrapped.observation_space, type(env).__name__)
    wrapped.reset(seed=seed)
    n_actions = int(wrapped.action_space.n)
    keys, index, observations, rows = [], {}, [], []
    frontier: deque[Hashable] = deque()

    def visit(key: Hashable) -> int:
        if key not in index:
            if len(keys) >= MAX_STATES:
                raise TPOError(f"{type(env).__name__} has more than {MAX_STATES} "
                               "reachable states: too many for a stepped model")
            index[key] = len(keys)
            keys.append(key)
            access.put(env, key)
            observations.append(encode(access.observe(env)))
            frontier.append(key)
        return index[key]

    visit(access.get(env))
    while frontier:
        key = frontier.popleft()
        row = []
        for a in range(n_actions):
            row.append([(p, None if nxt is None else visit(nxt), r)
                        for p, (nxt, r) in _branches(env, access, key, a)])
        rows.append(row)
    wrapped.close()
    end, k = len(keys), len(access.objectives)
    width_b = max(len(b) for row in rows for b in row)
    successors = np.full((end + 1, n_actions, width_b), end)
    probs = np.zeros((end + 1, n_actions, width_b))
    branch_rewards = np.zeros((end + 1, n_actions, width_b, k))
    for s, row in enumerate(rows):
        for a, branches in enumerate(row):
            for b, (p, nxt, r) in enumerate(branches):
                if len(r) != k:
                    raise TPOError(f"{type(env).__name__} returned {len(r)} reward "
                                   f"components for {k} objectives")
                successors[s, a, b] = end if nxt is None else nxt
                probs[s, a, b] = p
                branch_rewards[s, a, b] = r
    probs[end, :, 0] = 1.0
    rewards = np.einsum("sab,sabk->sak", probs, branch_rewards)
    observations.append(np.zeros(width, np.float32))
    model = TabularTMDP(successors, probs, rewards, access.objectives, gamma, 0,
                        np.arange(end + 1) == end)
    return SteppedModel(model, tuple(keys), np.stack(observations), branch_rewards)


def _put_cell(attribute: str) -> Callable[[Any, Hashable], None]:
    def put(env: Any, key: Hashable) -> None:
        setattr(env, attribute, np.array(key, np.int32))
    return put


_DEEP_SEA = Access(("treasure", "time"), lambda env: tuple(int(x) for x in env.current_state),
                   _put_cell("current_state"), lambda env: env._get_state())


def _put_resources(env: Any, key: Hashable) -> None:
    env.current_pos = np.array(key[:2], np.int32)
    env.has_gold, env.has_gem = key[2], key[3]


def _put_bottles(env: Any, key: Hashable) -> None:
    env.location, env.bottles_carrying, env.bottles_delivered = key[:3]
    env.bottles_dropped = list(key[3])


#: MO-Gymnasium's finite envs. Breakable bottles' key keeps whether a bottle lies
#: at each place, not how many: with breakable bottles nothing else depends on it.
ACCESS: dict[str, Access] = {
    "deep-sea-treasure-v0": _DEEP_SEA,
    "deep-sea-treasure-concave-v0": _DEEP_SEA,
    "resource-gathering-v0": Access(
        ("enemy", "gold", "gem"),
        lambda env: (*(int(x) for x in env.current_pos), int(env.has_gold), int(env.has_gem)),
        _put_resources, lambda env: env.get_state()),
    "breakable-bottles-v0": Access(
        ("time", "bottles", "impact"),
        lambda env: (env.location, env.bottles_carrying, env.bottles_delivered,
                     tuple(int(d > 0) for d in env.bottles_dropped)),
        _put_bottles, lambda env: env._get_obs()),
    "fruit-tree-v0": Access(
        tuple(f"nutrient{i}" for i in range(1, 7)),
        lambda env: tuple(int(x) for x in env.current_state),
        _put_cell("current_state"), lambda env: env.current_state.copy()),
}


def mo_gym_model(env_id: str, gamma: float = 0.99,
                 objectives: Sequence[str] | None = None, **kwargs: Any) -> SteppedModel:
    """The exact model of one of MO-Gymnasium's finite envs (:data:`ACCESS`), its
    objectives named ``objectives`` (by default :data:`ACCESS`'s names); ``kwargs``
    go to ``gym.make``."""
    if env_id not in ACCESS:
        raise TPOError(f"no stepped model of '{env_id}': known are {', '.join(ACCESS)}")
    import mo_gymnasium  # noqa: F401  (registers the envs)
    access = ACCESS[env_id]
    if objectives is not None:
        access = dataclasses.replace(access, objectives=tuple(objectives))
    return stepped_model(quiet(lambda: gym.make(env_id, disable_env_checker=True, **kwargs)),
                         access, gamma)


def host_model_env(env: HostEnv) -> TabularEnv | None:
    """The stepped model, as a JAX env, of a host env of one of :data:`ACCESS`'s
    envs (built by the host env's own factory, so with its arguments), its
    objectives named as the host env's; else None."""
    env_id = (env.env_id or "").partition(":")[2]
    if env_id not in ACCESS:
        return None
    access = dataclasses.replace(ACCESS[env_id], objectives=tuple(env.objectives))
    return stepped_model(env.make, access).env()
