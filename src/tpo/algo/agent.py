"""A Stable-Baselines3-style front end: ``TPO(env, graph).learn(n)``, ``predict``,
``save`` / ``TPO.load``, ``evaluate``.

Saved models are a directory holding ``model.json`` (format version, config,
DAG spec and slack, the environment's constructor arguments with the map's
TOML text, seed, the training program's length and progress) and
``state.msgpack``: Flax ``serialization.to_bytes`` of the whole
:class:`~tpo.algo.train.TrainState` (parameters, optimiser states, value
normalisation, environment states, PRNG key as raw key data), so a saved model
both acts and resumes training exactly where it stopped (:meth:`TPO.resume`).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from tpo.algo.config import TPOConfig
from tpo.algo.evaluate import exact_values, monte_carlo, summarize
from tpo.algo.host import EnvFactory, HostEnv, HostRunner, env_factory, registered_name
from tpo.algo.networks import mode, sample
from tpo.algo.train import Trainer, TrainState
from tpo.atomic import UMASK
from tpo.envs import load_map, parse_map
from tpo.envs.continuous import ContinuousNav
from tpo.envs.grid import GridNav
from tpo.errors import MapError, TPOError
from tpo.graph import ObjectiveGraph
from tpo.tabular import solve_lar

FORMAT = 2


class NonFiniteError(TPOError):
    """Training produced NaN or infinity."""


Callback = Callable[[dict[str, np.ndarray], int], bool | None]


def env_spec(env: GridNav | ContinuousNav | HostEnv) -> dict[str, Any]:
    """Constructor arguments that rebuild ``env`` (the map travels as TOML text; a
    Gymnasium env by its id)."""
    if isinstance(env, HostEnv):
        if env.env_id is None:
            raise TPOError("cannot save a model of a Gymnasium env given as an object or "
                           "factory: create the model from its id, e.g. "
                           "TPO('mo-gymnasium:deep-sea-treasure-v0', ...)")
        return {"kind": "gym", "id": env.env_id, "objectives": list(env.objectives)}
    if isinstance(env, GridNav):
        return {"kind": "grid", "map": env.navmap.to_toml(), "slip": float(env.params.slip),
                "observation": env.observation, "max_steps": int(env.params.max_steps),
                "random_start": env.random_start}
    if isinstance(env, ContinuousNav):
        return {"kind": "continuous", "map": env.navmap.to_toml(), "action": env.action,
                "speed": float(env.params.speed), "noise": float(env.params.noise),
                "n_beams": int(env.params.beams.shape[0]), "max_range": env.max_range,
                "max_steps": int(env.params.max_steps)}
    raise TPOError(f"cannot describe environment {type(env).__name__} for saving")


def make_env(spec: dict[str, Any], *, evaluation: bool = False) -> GridNav | ContinuousNav:
    """The environment of :func:`env_spec`; ``evaluation`` drops random starts."""
    spec = dict(spec)
    kind, navmap = spec.pop("kind"), parse_map(spec.pop("map"))
    if kind == "grid":
        if evaluation:
            spec["random_start"] = False
        return GridNav(navmap, **spec)
    if kind == "continuous":
        return ContinuousNav(navmap, **spec)
    raise TPOError(f"unknown environment kind '{kind}'")


def _host_env(env: str | gym.Env | gym.vector.VectorEnv | EnvFactory,
              objectives: Sequence[str], num_envs: int) -> HostEnv:
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


ChunkRunner = Callable[[TrainState, jax.Array, int, int], tuple[TrainState, dict]]


def _chunk_runner(trainer: Trainer) -> ChunkRunner:
    """``run(state, slack, n, length)``: ``n`` updates by one jitted program per
    ``length`` (so the last, shorter chunk compiles nothing new); metrics of ``n``."""
    chunk = jax.jit(trainer.run_chunk, static_argnums=3)

    def run(state: TrainState, slack: jax.Array, n: int, length: int):
        state, rows = chunk(state, slack, jnp.int32(n), length)
        return state, jax.tree.map(lambda x: x[:n], rows)

    return run


def _host_runner(trainer: Trainer, env: HostEnv) -> ChunkRunner:
    runner = HostRunner(trainer, env)
    return lambda state, slack, n, length: runner.run(state, slack, n)


class TPO:
    """Topological policy optimization.

    Args:
        env: a JAX navigation env (:class:`GridNav`, :class:`ContinuousNav`), a
            bundled map name or TOML path (a grid with random starts), or a
            Gymnasium env with vector rewards, stepped on the host: an id
            ``"PACKAGE:ENV_ID"`` (``"mo-gymnasium:deep-sea-treasure-v0"``), a
            ``gymnasium.Env`` made by ``gym.make``, a factory of envs, or a
            ``SyncVectorEnv`` such as MO-Gymnasium's ``MOSyncVectorEnv`` (its
            copies are stepped, and their number replaces ``config.num_envs``).
        graph: an :class:`ObjectiveGraph` or a spec string such as ``"M>A>G"``
            (a single name, e.g. ``"goal"``, is plain PPO).
        slack: one slack or one per edge (ignored when ``graph`` is a graph).
        config: hyperparameters.
        seed: PRNG seed of the parameters, the run and a Gymnasium env's resets.
        objectives: names of a Gymnasium env's reward components, in order.
    """

    def __init__(self, env: GridNav | ContinuousNav | str | gym.Env | gym.vector.VectorEnv
                 | EnvFactory,
                 graph: ObjectiveGraph | str, slack: float | list[float] = 0.0,
                 config: TPOConfig | None = None, seed: int = 0,
                 objectives: Sequence[str] | None = None) -> None:
        self.config = config or TPOConfig()
        host = isinstance(env, gym.Env | gym.vector.VectorEnv) or callable(env) or (
            isinstance(env, str) and ":" in env and not Path(env).exists())
        if host:
            if objectives is None:
                raise TPOError("name the Gymnasium env's reward components in order: "
                               "objectives=[...]")
            env = _host_env(env, objectives, self.config.num_envs)
            if env.num_envs != self.config.num_envs:  # a vector env's copies decide
                self.config = dataclasses.replace(self.config, num_envs=env.num_envs)
        elif isinstance(env, str | Path):
            try:
                navmap = load_map(env)
            except MapError as err:
                if Path(env).exists():
                    raise
                raise MapError(f"{err}; a Gymnasium env is named PACKAGE:ENV_ID, e.g. "
                               "mo-gymnasium:deep-sea-treasure-v0") from None
            env = GridNav(navmap, random_start=True)
        self.env = env
        self.eval_env = None if host else make_env(env_spec(env), evaluation=True)
        if isinstance(graph, str):
            graph = ObjectiveGraph.parse(graph, slack, objectives=env.objectives)
        self.graph = graph.bind(env.objectives)
        self.seed = seed
        self._fresh_env = False
        self.state: TrainState | None = None
        self.trainer: Trainer | None = None
        self._run: Callable | None = None
        self.num_timesteps = 0

    # ----------------------------------------------------------------- train
    def learn(self, total_timesteps: int, callback: Callback | None = None,
              chunk_updates: int = 16) -> TPO:
        """Train all phases, starting from the current parameters, for
        ``total_timesteps`` environment steps.

        ``callback(metrics, updates_done)`` is called after every chunk of
        ``chunk_updates`` updates with that chunk's metrics (arrays over its
        updates); ``self.state`` is then the state after the chunk, so the
        callback may :meth:`save` a checkpoint. Returning ``False`` stops training
        (:meth:`resume` continues it).
        """
        trainer = Trainer(self.env, self.graph, self.config, total_timesteps)
        params = None if self.state is None else self.state.params
        obs = self.env.reset(self.seed) if self.host else None
        state = trainer.init(jax.random.key(self.seed), params, obs)
        if self.state is not None:
            state = state.replace(value_norm=self.state.value_norm)
        self.trainer, self.state, self._run = trainer, state, None
        return self.resume(callback, chunk_updates)

    def resume(self, callback: Callback | None = None, chunk_updates: int = 16) -> TPO:
        """Continue the current training program (of :meth:`learn`, or of a model
        saved mid-training) to its end. Chunks stay aligned to multiples of
        ``chunk_updates``, so a resumed run computes exactly what an uninterrupted
        one does."""
        state, trainer = self._need_state(), self._need_trainer()
        if self.host and self._fresh_env:  # a loaded model: the env's episodes restart
            e, k = self.config.num_envs, len(self.env.objectives)
            state = state.replace(obs=jnp.asarray(self.env.reset(self.seed + int(state.update))),
                                  episode_return=jnp.zeros((e, k)), episode_length=jnp.zeros(e))
            self._fresh_env = False
        if self._run is None:
            self._run = _host_runner(trainer, self.env) if self.host else _chunk_runner(trainer)
        slack = trainer.slack_array()
        done = int(state.update)
        while done < trainer.num_updates:
            n = min(chunk_updates - done % chunk_updates, trainer.num_updates - done)
            new_state, metrics = self._run(state, slack, n,
                                           min(chunk_updates, trainer.num_updates))
            metrics = jax.tree.map(np.asarray, metrics)
            self._check_finite(new_state, metrics, done)
            state, done = new_state, done + n
            self.state = state
            self.num_timesteps += n * self.config.batch_size
            if callback is not None and callback(metrics, done) is False:
                break
        return self

    def _check_finite(self, state: TrainState, metrics: dict[str, np.ndarray],
                      done: int) -> None:
        """Stop on a non-finite loss, return or parameter, naming the phase, the
        update and the quantity; ``self.state`` keeps the last good state."""
        for name in ("policy_loss", "value_loss", "entropy", "episode_return", "penalty"):
            values = np.asarray(metrics[name]).reshape(len(metrics["phase"]), -1)
            bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
            if bad.size:
                i = int(bad[0])
                raise NonFiniteError(f"non-finite {name} in phase "
                                     f"'{self.graph.order[int(metrics['phase'][i])]}' at update "
                                     f"{done + i + 1}; the last good state (update {done}) "
                                     "is kept")
        finite = jax.tree.map(lambda x: bool(jnp.isfinite(x).all()), state.params)
        for path, ok in jax.tree_util.tree_flatten_with_path(finite)[0]:
            if not ok:
                raise NonFiniteError(f"non-finite parameters {jax.tree_util.keystr(path)} "
                                     f"after update {int(state.update)}; the last good state "
                                     f"(update {done}) is kept")

    @property
    def host(self) -> bool:
        """Whether the env is a Gymnasium env stepped on the host."""
        return isinstance(self.env, HostEnv)

    @property
    def finished(self) -> bool:
        """Whether the current training program has run all its updates."""
        return self.state is not None and self.trainer is not None and \
            int(self.state.update) >= self.trainer.num_updates

    def _need_state(self) -> TrainState:
        if self.state is None:
            raise TPOError("the model has no parameters yet: call learn() or TPO.load()")
        return self.state

    def _need_trainer(self) -> Trainer:
        if self.trainer is None:
            raise TPOError("the model has no training program yet: call learn() or TPO.load()")
        return self.trainer

    # ---------------------------------------------------------------- policy
    def predict(self, obs: np.ndarray, deterministic: bool = True,
                key: jax.Array | None = None) -> np.ndarray:
        """Actions for a single observation ``[D]`` or a batch ``[N, D]`` (for a
        Gymnasium env, also one observation as the env returns it)."""
        state, trainer = self._need_state(), self._need_trainer()
        if self.host and np.shape(obs)[-1:] != tuple(self.env.obs_shape):
            obs = self.env.encode(obs)
        obs = jnp.asarray(obs, jnp.float32)
        if obs.shape[-1:] != tuple(self.env.obs_shape):
            raise TPOError(f"observation has shape {tuple(obs.shape)}, expected "
                           f"[..., {self.env.obs_shape[0]}]")
        out, log_std = trainer.actor.apply({"params": state.params["actor"]}, obs)
        if deterministic:
            return np.asarray(mode(out, trainer.continuous))
        key = jax.random.key(0) if key is None else key
        return np.asarray(sample(key, out, log_std, trainer.continuous))

    def evaluate(self, episodes: int = 100, seed: int = 0) -> dict[str, Any]:
        """Monte Carlo returns (undiscounted and discounted, greedy and stochastic,
        mean and std by objective) and, for grid maps, the exact values of the
        greedy and stochastic policy beside LAR's solution of the same problem."""
        state, trainer = self._need_state(), self._need_trainer()
        gamma, objectives = self.config.gamma, self.env.objectives
        actor = state.params["actor"]
        result: dict[str, Any] = {"mc": {}}
        if self.host and self.eval_env is None:
            self.eval_env = self.env.copy(min(episodes, self.config.num_envs))
        for i, greedy in enumerate((True, False)):
            if self.host:
                returns = HostRunner(trainer, self.eval_env).monte_carlo(
                    actor, episodes, greedy, gamma, seed + i)
            else:
                returns = monte_carlo(trainer, actor, self.eval_env,
                                      jax.random.key(seed + i), episodes, greedy, gamma)
            result["mc"]["greedy" if greedy else "stochastic"] = {
                "undiscounted": summarize(returns["undiscounted"], objectives),
                "discounted": summarize(returns["discounted"], objectives),
                "length": float(returns["length"].mean())}
        if isinstance(self.eval_env, GridNav):
            result["exact"] = exact_values(trainer, actor, self.eval_env, gamma)
            lar = solve_lar(self.eval_env.tabular(gamma).model, self.graph, relax=True)
            result["lar"] = {"values": lar.start_values(),
                             "policy_values": lar.start_policy_values(),
                             "feasible": lar.feasible}
        return result

    # ----------------------------------------------------------- persistence
    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the model to the directory ``path`` (atomically: a kill leaves the
        old directory or none, never a half-written one)."""
        state, trainer = self._need_state(), self._need_trainer()
        path = Path(path)
        if path.exists() and not overwrite:
            raise TPOError(f"{path} exists; pass overwrite=True to replace it")
        meta = {"format": FORMAT, "config": self.config.to_dict(), "dag": self.graph.spec,
                "slack": list(self.graph.slacks), "env": env_spec(self.env),
                "seed": self.seed, "num_timesteps": self.num_timesteps,
                "total_timesteps": trainer.total_timesteps, "updates_done": int(state.update),
                "num_updates": trainer.num_updates}
        blob = serialization.to_bytes(state.replace(key=jax.random.key_data(state.key)))
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
        tmp.chmod(0o777 & ~UMASK)  # a plain mkdir's permissions, not mkdtemp's 0700
        (tmp / "model.json").write_text(json.dumps(meta, indent=2))
        (tmp / "state.msgpack").write_bytes(blob)
        for f in tmp.iterdir():
            with open(f, "rb") as fh:
                os.fsync(fh.fileno())
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old.", dir=path.parent))
            os.replace(path, old / path.name)
            os.replace(tmp, path)
            shutil.rmtree(old)
        else:
            os.replace(tmp, path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> TPO:
        """A model saved by :meth:`save`: it acts, and :meth:`resume` finishes its
        training program if it was saved mid-way."""
        path = Path(path)
        try:
            meta = json.loads((path / "model.json").read_text())
            blob = (path / "state.msgpack").read_bytes()
        except (OSError, json.JSONDecodeError) as err:
            raise TPOError(f"{path} is not a saved tpo model: {err}") from None
        if meta.get("format") != FORMAT:
            raise TPOError(f"{path}: unknown model format {meta.get('format')!r} "
                           f"(this version reads {FORMAT})")
        spec, config = meta["env"], TPOConfig.from_dict(meta["config"])
        if spec["kind"] == "gym":
            model = cls(spec["id"], meta["dag"], meta["slack"], config, meta["seed"],
                        objectives=spec["objectives"])
            model._fresh_env = True
        else:
            env = make_env(spec)
            model = cls(env, meta["dag"], meta["slack"], config, meta["seed"])
        env = model.env
        model.trainer = Trainer(env, model.graph, model.config, meta["total_timesteps"])
        blank = np.zeros((config.num_envs, *env.obs_shape), np.float32) if model.host else None
        template = model.trainer.init(jax.random.key(0), obs=blank)
        try:
            state = serialization.from_bytes(
                template.replace(key=jax.random.key_data(template.key)), blob)
        except (ValueError, KeyError, TypeError) as err:
            raise TPOError(f"{path}/state.msgpack is damaged or does not match "
                           f"model.json: {err}") from None
        model.state = state.replace(key=jax.random.wrap_key_data(state.key))
        model.num_timesteps = meta["num_timesteps"]
        return model
