"""Gymnasium / MO-Gymnasium environments with vector rewards, as TPO trains on them.

:class:`HostEnv` steps ``num_envs`` copies of such an env on the host (the
learner's rollouts come from :class:`tpo.algo.runners.HostRunner`) and describes
them the way the learner reads an env: ``objectives``, reward bounds,
``obs_shape`` and ``action_space``. The reward vector's components are named by
the user (``objectives``), in order.

Observations: ``Box`` (flattened to float32), ``Discrete`` (one-hot), or a
composite space flattened as ``gymnasium.spaces.flatten`` does.
Actions: ``Discrete`` or 1-D ``Box`` (Gaussian samples clipped to the bounds).
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from tpo.errors import TPOError

EnvFactory = Callable[[], gym.Env]


class EnvError(TPOError):
    """A Gymnasium environment TPO cannot train on."""


#: Packages that tpo itself depends on: their envs load without being trusted.
KNOWN_PACKAGES = ("gym", "gymnasium", "mo-gymnasium", "mo_gymnasium")


def env_factory(env: str | EnvFactory, *, trust_module: str | bool = True,
                **kwargs: Any) -> EnvFactory:
    """A factory of the env named ``"package:EnvId"`` (the package is imported to
    register its ids: ``mo-gymnasium:deep-sea-treasure-v0``; ``gym:CartPole-v1``
    for Gymnasium's own), or ``env`` itself when it is already a factory.

    ``trust_module`` says which package may be imported: ``True`` (the name was
    given by the caller), ``False`` (it was read from a file: only tpo's own
    dependencies, :data:`KNOWN_PACKAGES`, or an id already registered), or the
    one module name the caller trusts besides those.
    """
    if callable(env):
        return env
    package, sep, env_id = env.partition(":")
    if not sep or not env_id or ":" in env_id:
        raise EnvError(f"bad env '{env}': write PACKAGE:ENV_ID, e.g. "
                       "mo-gymnasium:deep-sea-treasure-v0 or gym:CartPole-v1")
    module = package.replace("-", "_")
    trusted = trust_module is True or package in KNOWN_PACKAGES or (
        isinstance(trust_module, str) and trust_module.replace("-", "_") == module)
    if package not in ("gym", "gymnasium"):
        if trusted:
            try:
                importlib.import_module(module)
            except ImportError as err:
                raise EnvError(f"cannot import '{package}' for env '{env}': {err}") from None
        elif env_id not in gym.registry:
            raise EnvError(f"env '{env}' is not registered and tpo does not import "
                           f"'{package}', a module named in a file; import it yourself "
                           f"or trust it: trust_env_module='{package}' "
                           f"(tpo: --trust-module {package})")
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

    absolute_tolerance = None  # returns tie scale-free: rewards have any unit

    def __init__(self, make: EnvFactory, objectives: Sequence[str], num_envs: int,
                 env_id: str | None = None, envs: Sequence[gym.Env] | None = None) -> None:
        make = self.make = quiet(make)
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
        self._encode, self.obs_shape = observation_encoder(probe.observation_space,
                                                            self.name)
        #: a Discrete observation's one-hot is one block of one 1 (see GridNav's)
        self.observation_onehots = (((0, self.obs_shape[0]),) if isinstance(
            probe.observation_space, gym.spaces.Discrete) else ())
        space = probe.action_space
        # The policy's action space: a Discrete space counts from 0 for the policy.
        if isinstance(space, gym.spaces.Discrete):
            self.action_space: gym.spaces.Space = gym.spaces.Discrete(int(space.n))
            self._to_env = lambda a: a.astype(np.int64) + int(space.start)
        elif isinstance(space, gym.spaces.Box) and len(space.shape) == 1:
            self.action_space = space
            self._to_env = lambda a: np.clip(a, space.low, space.high)
        else:
            raise EnvError(f"{self.name} has action space {space}: TPO supports "
                           "Discrete and 1-D Box actions")
        self.envs = list(envs) if envs else [probe, *(make() for _ in range(num_envs - 1))]
        self.num_envs = len(self.envs)
        for i, env in enumerate(self.envs[1:], 1):
            if (env.observation_space, env.action_space) != (probe.observation_space, space):
                raise EnvError(f"copy {i} of {self.name} has other observation or action "
                               "spaces than copy 0")

    def to_spec(self) -> dict[str, Any]:
        """What rebuilds this env (:func:`tpo.envs.from_spec`): its registered id."""
        if self.env_id is None:
            raise TPOError("cannot save a model of a Gymnasium env given as an object or "
                           "factory: create the model from its id, e.g. "
                           "TPO('mo-gymnasium:deep-sea-treasure-v0', ...)")
        return {"kind": "gym", "id": self.env_id, "objectives": list(self.objectives)}

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
        action = self._to_env(action)
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


def quiet(make: EnvFactory) -> EnvFactory:
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


def observation_encoder(space: gym.Space, name: str
                        ) -> tuple[Callable[[Any], np.ndarray], tuple[int]]:
    """``(encode, (D,))``: an observation of ``space`` -> the policy's float32 input.
    ``Box`` is flattened, ``Discrete`` one-hot; ``Dict``, ``Tuple``, ``MultiBinary``
    and ``MultiDiscrete`` are flattened the way ``gymnasium.spaces.flatten`` does
    (each ``Discrete`` inside one-hot)."""
    if isinstance(space, gym.spaces.Box):
        size = int(np.prod(space.shape))
        return (lambda o: np.asarray(o, np.float32).reshape(-1)), (size,)
    if isinstance(space, gym.spaces.Discrete):
        n, start = int(space.n), int(space.start)
        return (lambda o: np.eye(n, dtype=np.float32)[int(o) - start]), (n,)
    if isinstance(space, (gym.spaces.Dict, gym.spaces.Tuple, gym.spaces.MultiBinary,
                          gym.spaces.MultiDiscrete)):
        try:
            size = int(gym.spaces.flatdim(space))
        except (ValueError, NotImplementedError) as err:
            raise EnvError(f"{name} has observation space {space}, which cannot be "
                           f"flattened: {err}") from None
        return (lambda o: np.asarray(gym.spaces.flatten(space, o), np.float32).reshape(-1)
                ), (size,)
    raise EnvError(f"{name} has observation space {space}: TPO supports Box, Discrete "
                   "and what gymnasium.spaces.flatten flattens (Dict, Tuple, MultiBinary, "
                   "MultiDiscrete); wrap others")


def host_env(env: str | gym.Env | gym.vector.VectorEnv | EnvFactory,
             objectives: Sequence[str], num_envs: int) -> HostEnv:
    """The :class:`HostEnv` of a Gymnasium env given as an id ``"PACKAGE:ENV_ID"``, a
    ``gym.make``'d env, a factory, or a ``SyncVectorEnv`` (whose copies it steps)."""
    if isinstance(env, gym.vector.VectorEnv):
        # Vector wrappers are bypassed: TPO steps the copies and keeps its own statistics.
        base = env.unwrapped
        copies, makers = getattr(base, "envs", None), getattr(base, "env_fns", None)
        if not copies or not makers:
            raise TPOError(f"{type(base).__name__}: TPO steps a vector env's copies itself, "
                           "so it takes a SyncVectorEnv (e.g. MO-Gymnasium's "
                           "MOSyncVectorEnv); or pass the env id or a factory")
        spec = copies[0].spec
        return HostEnv(makers[0], objectives, len(copies),
                       env_id=None if spec is None else registered_name(spec), envs=copies)
    if isinstance(env, gym.Env):
        if env.spec is None:
            raise TPOError("a Gymnasium env object needs a spec (make it with gym.make) "
                           "or pass a factory: TPO(lambda: MyEnv(), ...)")
        spec = env.spec
        return HostEnv(lambda: gym.make(spec, disable_env_checker=True), objectives, num_envs,
                       env_id=registered_name(spec))
    return HostEnv(env_factory(env), objectives, num_envs,
                   env_id=env if isinstance(env, str) else None)
