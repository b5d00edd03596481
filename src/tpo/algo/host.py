"""TPO and plain PPO on any Gymnasium / MO-Gymnasium environment with vector rewards.

The environment's copies are stepped on the host in turn; choosing actions is
jitted, and the update is the JAX path's own :meth:`Trainer.learn`:
one implementation of the algorithm, two sources of rollouts. The reward
vector's components are named by the user (``objectives``), in order.

Observations: ``Box`` (flattened to float32) or ``Discrete`` (one-hot).
Actions: ``Discrete`` or ``Box`` (Gaussian samples clipped to the bounds).
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from tpo.algo.networks import log_prob, mode, sample
from tpo.algo.train import Rollout, Trainer, TrainState
from tpo.errors import TPOError

EnvFactory = Callable[[], gym.Env]


class EnvError(TPOError):
    """A Gymnasium environment TPO cannot train on."""


def env_factory(env: str | EnvFactory, **kwargs: Any) -> EnvFactory:
    """A factory of the env named ``"package:EnvId"`` (the package is imported to
    register its ids: ``mo-gymnasium:deep-sea-treasure-v0``; ``gym:CartPole-v1``
    for Gymnasium's own), or ``env`` itself when it is already a factory."""
    if callable(env):
        return env
    package, sep, env_id = env.partition(":")
    if not sep or not env_id:
        raise EnvError(f"bad env '{env}': write PACKAGE:ENV_ID, e.g. "
                       "mo-gymnasium:deep-sea-treasure-v0 or gym:CartPole-v1")
    if package not in ("gym", "gymnasium"):
        try:
            importlib.import_module(package.replace("-", "_"))
        except ImportError as err:
            raise EnvError(f"cannot import '{package}' for env '{env}': {err}") from None
    try:
        gym.spec(env_id)
    except gym.error.Error as err:
        raise EnvError(f"unknown env id '{env_id}': {err}") from None
    # Gymnasium's passive env checker assumes scalar rewards and warns on every
    # vector-reward env; TPO checks what it needs itself (HostEnv).
    return lambda: gym.make(env_id, disable_env_checker=True, **kwargs)


def registered_name(spec: gym.envs.registration.EnvSpec) -> str:
    """``"package:EnvId"`` of a registered env (what :func:`env_factory` takes): the
    package is the top module of the spec's entry point."""
    entry = spec.entry_point
    module = entry.partition(":")[0] if isinstance(entry, str) else getattr(
        entry, "__module__", "gymnasium")
    return f"{module.split('.')[0]}:{spec.id}"


class HostEnv:
    """``num_envs`` copies of a Gymnasium env with vector rewards (made by ``make``,
    or the given ``envs``), stepped in turn (auto-reset in the same step, the true
    final observation kept), described the way :class:`Trainer` expects an env.
    (Gymnasium's own vector envs assume scalar rewards, and MO-Gymnasium's reset
    a step late.)"""

    def __init__(self, make: EnvFactory, objectives: Sequence[str], num_envs: int,
                 env_id: str | None = None, envs: Sequence[gym.Env] | None = None) -> None:
        make = self.make = _quiet(make)
        self.env_id = env_id
        probe = envs[0] if envs else make()
        self.name = _name(probe)
        reward_space = getattr(probe.unwrapped, "reward_space", None)
        self.objectives = tuple(objectives)
        if reward_space is None:
            raise EnvError(f"{self.name} has a scalar reward (no reward_space): TPO "
                           "needs a reward vector, one component per objective "
                           "(MO-Gymnasium's convention)")
        width = int(np.prod(reward_space.shape))
        if width != len(self.objectives):
            raise EnvError(f"{self.name} returns {width} reward components but "
                           f"{len(self.objectives)} objectives are named "
                           f"({', '.join(self.objectives)})")
        self.reward_low = np.asarray(reward_space.low, np.float32).reshape(-1)
        self.reward_high = np.asarray(reward_space.high, np.float32).reshape(-1)
        self._encode, self.obs_shape = _observation_encoder(probe.observation_space,
                                                            self.name)
        space = probe.action_space
        if isinstance(space, gym.spaces.Discrete):
            self.num_actions, self.action_dim = int(space.n), None
            self._action_start = int(space.start)
        elif isinstance(space, gym.spaces.Box) and len(space.shape) == 1:
            self.num_actions, self.action_dim = None, int(space.shape[0])
            self._low, self._high = space.low, space.high
        else:
            raise EnvError(f"{self.name} has action space {space}: TPO supports "
                           "Discrete and 1-D Box actions")
        self.envs = list(envs) if envs else [probe, *(make() for _ in range(num_envs - 1))]
        self.num_envs = len(self.envs)
        for i, env in enumerate(self.envs[1:], 1):
            if (env.observation_space, env.action_space) != (probe.observation_space, space):
                raise EnvError(f"copy {i} of {self.name} has other observation or action "
                               "spaces than copy 0")

    def copy(self, num_envs: int) -> HostEnv:
        """Another set of ``num_envs`` copies of the same env."""
        return HostEnv(self.make, self.objectives, num_envs, self.env_id)

    def encode(self, obs: Any) -> np.ndarray:
        """One observation as the env returns it -> the policy's input ``[D]``."""
        return self._encode(obs)

    def reset(self, seed: int) -> np.ndarray:
        """Reset every copy (copy ``i`` with seed ``seed + i``)."""
        return self._observe([env.reset(seed=seed + i)[0] for i, env in enumerate(self.envs)])

    def step(self, action: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(obs, reward [E, k], terminated, truncated, final_obs)``; ``obs`` is the
        next episode's first observation where an episode ended."""
        if self.num_actions is not None:
            action = action.astype(np.int64) + self._action_start
        else:
            action = np.clip(action, self._low, self._high)
        k = len(self.objectives)
        obs, final = [], []
        reward = np.empty((self.num_envs, k), np.float32)
        term, trunc = np.zeros(self.num_envs, bool), np.zeros(self.num_envs, bool)
        for i, env in enumerate(self.envs):
            o, r, term[i], trunc[i], _ = env.step(action[i])
            r = np.asarray(r, np.float32).reshape(-1)
            if r.shape != (k,):
                raise EnvError(f"{self.name} returned a reward of shape {np.shape(r)} "
                               f"for {k} objectives")
            reward[i] = r
            final.append(o)
            if term[i] or trunc[i]:
                o, _ = env.reset()
            obs.append(o)
        return self._observe(obs), reward, term, trunc, self._observe(final)

    def _observe(self, obs: list[Any]) -> np.ndarray:
        encoded = [self._encode(o) for o in obs]
        for e in encoded:
            if e.shape != self.obs_shape:
                raise EnvError(f"{self.name}'s observation shape changed from "
                               f"{self.obs_shape} to {e.shape}")
        return np.stack(encoded)

    def close(self) -> None:
        for env in self.envs:
            env.close()


def _key_stream(key: jax.Array, block: int = 256) -> Iterator[np.ndarray]:
    """Endless raw key data from ``key``, split ``block`` at a time (one JAX call
    per block, not per step)."""
    while True:
        key, sub = jax.random.split(key)
        yield from np.asarray(jax.random.key_data(jax.random.split(sub, block)))


def _quiet(make: EnvFactory) -> EnvFactory:
    """``make`` without Gymnasium's warning that a float64 Box bound was cast to
    float32 (MO-Gymnasium's envs declare their reward spaces so: harmless noise
    on every copy)."""
    def quiet_make() -> gym.Env:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*precision lowered by casting")
            return make()
    return quiet_make


def _name(env: gym.Env) -> str:
    return env.spec.id if env.spec is not None else type(env.unwrapped).__name__


def _observation_encoder(space: gym.Space, name: str
                         ) -> tuple[Callable[[Any], np.ndarray], tuple[int]]:
    if isinstance(space, gym.spaces.Box):
        size = int(np.prod(space.shape))
        return (lambda o: np.asarray(o, np.float32).reshape(-1)), (size,)
    if isinstance(space, gym.spaces.Discrete):
        n, start = int(space.n), int(space.start)
        return (lambda o: np.eye(n, dtype=np.float32)[int(o) - start]), (n,)
    raise EnvError(f"{name} has observation space {space}: TPO supports Box and Discrete "
                   "observations (flatten or wrap others)")


class HostRunner:
    """Runs :class:`Trainer` updates on rollouts stepped on the host."""

    def __init__(self, trainer: Trainer, env: HostEnv) -> None:
        self.trainer, self.env = trainer, env
        continuous = trainer.continuous

        def act(actor: dict, obs: jax.Array, key_data: jax.Array, greedy: jax.Array):
            out, log_std = trainer.actor.apply({"params": actor}, obs)
            key = jax.random.wrap_key_data(key_data)
            return jnp.where(greedy, mode(out, continuous),
                             sample(key, out, log_std, continuous))

        def behaviour_log_prob(actor: dict, obs: jax.Array, action: jax.Array):
            out, log_std = trainer.actor.apply({"params": actor}, obs)
            return log_prob(out, log_std, action, continuous)

        # Keys travel as raw key data (NumPy): indexing typed keys on the host costs
        # an eager JAX dispatch per step; log-probs are computed for the whole
        # rollout at once, so each step syncs with the device only for the action.
        self._act = jax.jit(act)
        self._log_prob = jax.jit(behaviour_log_prob)
        self._learn = jax.jit(trainer.learn)
        self._refit = jax.jit(lambda s: trainer.phase_info(s)[2])

    def run(self, state: TrainState, slack: jax.Array, num_updates: int
            ) -> tuple[TrainState, dict]:
        """``num_updates`` updates; metrics stacked over them as the JAX path's."""
        cfg, env = self.trainer.config, self.env
        k = len(env.objectives)
        history = []
        for _ in range(num_updates):
            greedy = self._refit(state)
            key, k_roll = jax.random.split(state.key)
            keys = np.asarray(jax.random.key_data(jax.random.split(k_roll, cfg.num_steps)))
            obs = np.asarray(state.obs)
            ep_ret, ep_len = np.asarray(state.episode_return), np.asarray(state.episode_length)
            done_ret, done_len, done_n = np.zeros(k), 0.0, 0.0
            steps: list[tuple] = []
            for t in range(cfg.num_steps):
                action = np.asarray(self._act(state.params["actor"], obs, keys[t], greedy))
                nxt, reward, term, trunc, final = env.step(action)
                if not np.isfinite(reward).all():
                    env_i, col = np.argwhere(~np.isfinite(reward))[0]
                    raise EnvError(f"{env.name} returned a non-finite reward "
                                   f"{reward[env_i, col]} for objective "
                                   f"'{env.objectives[col]}' at update "
                                   f"{int(state.update) + 1}, step {t + 1} of its rollout, "
                                   f"in copy {env_i}")
                done = (term | trunc).astype(np.float32)
                ep_ret, ep_len = ep_ret + reward, ep_len + 1
                done_ret += (ep_ret * done[:, None]).sum(0)
                done_len += float((ep_len * done).sum())
                done_n += float(done.sum())
                ep_ret, ep_len = ep_ret * (1 - done[:, None]), ep_len * (1 - done)
                steps.append((obs, action, reward, final, term.astype(np.float32), done))
                obs = nxt
            o, a, r, f, te, d = (jnp.asarray(np.stack(x)) for x in zip(*steps, strict=True))
            rollout = Rollout(o, a, self._log_prob(state.params["actor"], o, a), r, f, te, d)
            n = max(done_n, 1.0)
            episodes = {"episodes": jnp.float32(done_n),
                        "episode_return": jnp.asarray(done_ret / n, jnp.float32),
                        "episode_length": jnp.float32(done_len / n)}
            state = state.replace(obs=jnp.asarray(obs), key=key,
                                  episode_return=jnp.asarray(ep_ret, jnp.float32),
                                  episode_length=jnp.asarray(ep_len, jnp.float32))
            state, metrics = self._learn(state, slack, rollout, episodes)
            history.append(metrics)
        return state, jax.tree.map(lambda *x: jnp.stack(x), *history)

    def monte_carlo(self, actor: dict, episodes: int, greedy: bool, gamma: float,
                    seed: int) -> dict[str, np.ndarray]:
        """Returns of ``episodes`` episodes on the runner's env (the same layout as
        the JAX path's); every copy runs the same number of whole episodes, so short
        episodes are not over-represented."""
        env = self.env
        k, n = len(env.objectives), env.num_envs
        quota = -(-episodes // n)
        found: list[list[tuple]] = [[] for _ in range(n)]
        obs = env.reset(seed)
        r_acc, d_acc = np.zeros((n, k)), np.zeros((n, k))
        g_acc, l_acc = np.ones(n), np.zeros(n)
        keys = _key_stream(jax.random.key(seed))
        while min(len(f) for f in found) < quota:
            action = self._act(actor, obs, next(keys), jnp.bool_(greedy))
            obs, reward, term, trunc, _ = env.step(np.asarray(action))
            r_acc += reward
            d_acc += g_acc[:, None] * reward
            g_acc *= gamma
            l_acc += 1
            for i in np.flatnonzero(term | trunc):
                if len(found[i]) < quota:
                    found[i].append((r_acc[i].copy(), d_acc[i].copy(), l_acc[i]))
                r_acc[i], d_acc[i], g_acc[i], l_acc[i] = 0.0, 0.0, 1.0, 0.0
        runs = [run for f in found for run in f][:episodes]
        return {"undiscounted": np.array([r[0] for r in runs]),
                "discounted": np.array([r[1] for r in runs]),
                "length": np.array([r[2] for r in runs])}
