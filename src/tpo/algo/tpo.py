"""The :class:`TPO` model, in the manner of Stable-Baselines3: ``TPO(env,
graph).learn(n)``, ``predict``, ``evaluate``, ``save`` / ``TPO.load``."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from functools import cached_property, partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from tpo.algo.config import MAX_POPULATION, TPOConfig
from tpo.algo.evaluate import exact_evaluation, monte_carlo, reference_evaluation, summarize
from tpo.algo.guard import check_finite
from tpo.algo.persist import read_model, restore_state, save_model
from tpo.algo.phases import Problem
from tpo.algo.runners import HostRunner, Runner, jax_runner
from tpo.algo.selection import select
from tpo.algo.train import Trainer, TrainState
from tpo.envs.continuous import ContinuousNav
from tpo.envs.gym_adapter import EnvFactory, HostEnv
from tpo.envs.spec import Env, from_spec, make_env
from tpo.envs.stepped_model import host_model_env
from tpo.errors import DamagedModel, TPOError
from tpo.graph import ObjectiveGraph

Callback = Callable[[dict[str, np.ndarray], int], bool | None]


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
        config: hyperparameters (default :meth:`TPOConfig.from_profile` for the env's
            action space: for a ``Box``, the discretized policy's if its bounds are
            finite, else a Gaussian's; the ``continuous`` profile for
            :class:`ContinuousNav`, else ``grid``).
        seed: PRNG seed of the parameters, the run and a Gymnasium env's resets.
        objectives: names of a Gymnasium env's reward components, in order.
        population: independent learners trained at once (one program, vmapped; a
            JAX env only), each on ``total_timesteps`` steps; the model answers with
            the one whose policy LAR's rule prefers on their greedy Monte Carlo
            returns (:func:`tpo.algo.selection.select`). Member 0 is seeded as a
            lone learner is; with ``config.mixed_population`` the members differ
            in design and in the part of the observation they see
            (:meth:`_member_design`).
    """

    def __init__(self, env: Env | str | gym.Env | gym.vector.VectorEnv | EnvFactory,
                 graph: ObjectiveGraph | str, slack: float | list[float] = 0.0,
                 config: TPOConfig | None = None, seed: int = 0,
                 objectives: Sequence[str] | None = None, population: int = 1) -> None:
        if isinstance(population, bool) or not isinstance(population, int) \
                or not 1 <= population <= MAX_POPULATION:
            raise TPOError(f"population must be an integer from 1 to {MAX_POPULATION}, "
                           f"got {population!r:.60}")
        self.population = population
        self.config = config or TPOConfig()
        self.env = env = make_env(env, objectives, self.config.num_envs)
        if config is None:
            kind = "categorical"
            if isinstance(env.action_space, gym.spaces.Box):
                bounded = np.all(np.isfinite(env.action_space.low)) and np.all(
                    np.isfinite(env.action_space.high))
                kind = "discretized" if bounded else "gaussian"
            profile = "continuous" if isinstance(env, ContinuousNav) else "grid"
            self.config = TPOConfig.from_profile(profile, kind)
        if self.host and env.num_envs != self.config.num_envs:  # a vector env's copies
            self.config = dataclasses.replace(self.config, num_envs=env.num_envs)
        if self.host and population > 1:  # each member steps its own copies
            self.env = env = env.copy(population * self.config.num_envs)
        self.eval_env = None if self.host else from_spec(env.to_spec(), evaluation=True)
        if isinstance(graph, str):
            graph = ObjectiveGraph.parse(graph, slack, objectives=env.objectives)
        self.graph = graph.bind(env.objectives)
        self.seed = seed
        self._fresh_env = False
        self.state: TrainState | None = None
        self.trainer: Trainer | None = None
        self._run: Runner | None = None
        self._select: Callable[[TrainState, jax.Array], TrainState] | None = None
        self.num_timesteps = 0

    @property
    def host(self) -> bool:
        """Whether the env is a Gymnasium env stepped on the host."""
        return isinstance(self.env, HostEnv)

    @cached_property
    def phases(self) -> tuple[str, ...]:
        """The objective of every training phase, in order (completion phases marked)."""
        return Problem.build(self.graph, self.env.objectives, self.config).phase_names

    @property
    def finished(self) -> bool:
        """Whether the current training program has run all its updates."""
        return self.state is not None and self.trainer is not None and \
            self.updates_done >= self.trainer.num_updates

    @property
    def updates_done(self) -> int:
        """Updates of the current training program done (by every member)."""
        return int(np.min(self._need_state().update))

    @property
    def stacked(self) -> bool:
        """Whether the state holds the population's members (``[M, ...]``), as during
        training; once finished it holds the answer alone."""
        return self.state is not None and np.ndim(self.state.update) == 1

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
        obs = self._host_obs(self.env.reset(self.seed)) if self.host else None
        members = []
        for m in range(self.population):
            key = jax.random.key(self.seed)
            key = jax.random.fold_in(key, m) if m else key
            old = None if self.state is None else self.member(m)
            design, view = self._member_design(m, len(trainer.views))
            state = trainer.init(key, None if old is None else old.params,
                                 None if obs is None else obs[m], design, view)
            members.append(state if old is None else state.replace(value_norm=old.value_norm))
        state = members[0] if self.population == 1 else _stack(members)
        self.trainer, self.state, self._run = trainer, state, None
        return self.resume(callback, chunk_updates)

    def _member_design(self, m: int, views: int) -> tuple[int, int]:
        """Member ``m``'s design and observation view (:meth:`Trainer.init`): with
        ``mixed_population`` the odd members learn the second design, and each pair
        of members the next of the env's ``views`` (0: the whole observation)."""
        if not self.config.mixed_population:
            return 0, 0
        return m % 2, (m // 2) % views

    def resume(self, callback: Callback | None = None, chunk_updates: int = 16) -> TPO:
        """Continue the current training program (of :meth:`learn`, or of a model
        saved mid-training) to its end. Chunks stay aligned to multiples of
        ``chunk_updates``, so a resumed run computes exactly what an uninterrupted
        one does."""
        state, trainer = self._need_state(), self._need_trainer()
        if self.host and self._fresh_env:  # a loaded model: the env's episodes restart
            obs = self._host_obs(self.env.reset(self.seed + self.updates_done))
            state = state.replace(
                obs=jnp.asarray(obs if self.stacked else obs[0]),
                episodes=jax.tree.map(jnp.zeros_like, state.episodes))
            self._fresh_env = False
        if self._run is None:
            self._run = (HostRunner(trainer, self.env, self.population * self.stacked)
                         if self.host else jax_runner(trainer, self.stacked))
            self._select = (partial(select, trainer, env=self._run) if self.host
                            else jax.jit(partial(select, trainer, env=self.eval_env)))
        slack = trainer.slack_array()
        done = self.updates_done
        while done < trainer.num_updates:
            n = min(chunk_updates - done % chunk_updates, trainer.num_updates - done)
            new_state, metrics = self._run(state, slack, n,
                                           min(chunk_updates, trainer.num_updates))
            if done + n >= trainer.num_updates:  # the run's end: its answer
                new_state = self._select(new_state, slack)
            metrics = jax.tree.map(np.asarray, metrics)
            if self.stacked:  # the members' mean (the phase is every member's)
                metrics = {k: v.mean(0).astype(v.dtype) for k, v in metrics.items()}
            check_finite(new_state.params, metrics, done, trainer.problem.phase_names)
            state, done = new_state, done + n
            self.state = state
            self.num_timesteps += n * self.config.batch_size
            if callback is not None and callback(metrics, done) is False:
                break
        return self

    def _host_obs(self, obs: np.ndarray) -> np.ndarray:
        """A host env's observations ``[M * N, D]`` as each member's ``[M, N, D]``."""
        return obs.reshape(self.population, -1, *obs.shape[1:])

    def _need_state(self) -> TrainState:
        if self.state is None:
            raise TPOError("the model has no parameters yet: call learn() or TPO.load()")
        return self.state

    def member(self, m: int) -> TrainState:
        """Member ``m``'s state while the population trains; the state once finished."""
        state = self._need_state()
        return jax.tree.map(lambda x: x[m], state) if self.stacked else state

    def _need_trainer(self) -> Trainer:
        if self.trainer is None:
            raise TPOError("the model has no training program yet: call learn() or TPO.load()")
        return self.trainer

    # ---------------------------------------------------------------- policy
    def predict(self, obs: np.ndarray, deterministic: bool = True,
                key: jax.Array | None = None) -> np.ndarray:
        """Actions for a single observation ``[D]`` or a batch ``[N, D]`` (for a
        Gymnasium env, also one observation as the env returns it)."""
        state, trainer = self.member(0), self._need_trainer()
        if self.host and np.shape(obs)[-1:] != tuple(self.env.obs_shape):
            obs = self.env.encode(obs)
        obs = jnp.asarray(obs, jnp.float32)
        if obs.shape[-1:] != tuple(self.env.obs_shape):
            raise TPOError(f"observation has shape {tuple(obs.shape)}, expected "
                           f"[..., {self.env.obs_shape[0]}]")
        pi = trainer.policy(trainer.acting(state, trainer.slack_array()), obs)
        if deterministic:
            return np.asarray(pi.mode())
        return np.asarray(pi.sample(jax.random.key(0) if key is None else key))

    def evaluate(self, episodes: int = 100, seed: int = 0) -> dict[str, Any]:
        """Monte Carlo returns (undiscounted and discounted, greedy and stochastic,
        mean and std by objective) and, for grid maps, tabular envs and
        MO-Gymnasium's finite envs (:mod:`tpo.envs.stepped_model`), the exact judgement
        (:func:`tpo.algo.evaluate.exact_evaluation`): exact values of the greedy and
        stochastic policy, LAR's solution of the same problem, and the verdicts
        ``lar_correct``, ``strict`` and ``same_values``; for the continuous env, the
        judgement against its finite reference
        (:func:`tpo.algo.evaluate.reference_evaluation`)."""
        state, trainer = self.member(0), self._need_trainer()
        gamma, objectives = self.config.gamma, self.env.objectives
        acting = trainer.acting(state, trainer.slack_array())
        if self.host and self.eval_env is None:
            self.eval_env = self.env.copy(min(episodes, self.config.num_envs))
        result: dict[str, Any] = {"mc": {}}
        runner = HostRunner(trainer, self.eval_env) if self.host else None
        for i, greedy in enumerate((True, False)):
            if runner is not None:
                returns = runner.monte_carlo(acting, episodes, greedy, gamma, seed + i)
            else:
                returns = monte_carlo(trainer.policy, acting, self.eval_env,
                                      jax.random.key(seed + i), episodes, greedy, gamma)
            result["mc"]["greedy" if greedy else "stochastic"] = {
                "undiscounted": summarize(returns["undiscounted"], objectives),
                "discounted": summarize(returns["discounted"], objectives),
                "length": float(returns["length"].mean())}
        exact = self.eval_env if hasattr(self.eval_env, "tabular") else (
            host_model_env(self.env) if self.host else None)
        if exact is not None:
            result.update(exact_evaluation(trainer.policy, acting, exact, self.graph, gamma))
        elif isinstance(self.eval_env, ContinuousNav):
            result.update(reference_evaluation(trainer.policy, acting, self.eval_env,
                                               self.graph, gamma))
        return result

    # ----------------------------------------------------------- persistence
    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the model to the directory ``path`` (atomically: a kill leaves the
        old directory or none, never a half-written one)."""
        state, trainer = self._need_state(), self._need_trainer()
        meta = {"config": self.config.to_dict(), "dag": self.graph.spec,
                "slack": list(self.graph.slacks), "env": self.env.to_spec(),
                "seed": self.seed, "num_timesteps": self.num_timesteps,
                "total_timesteps": trainer.total_timesteps, "updates_done": self.updates_done,
                "population": self.population,
                "num_updates": trainer.num_updates}
        return save_model(path, meta, state, overwrite)

    @classmethod
    def load(cls, path: str | Path, trust_env_module: str | None = None) -> TPO:
        """A model saved by :meth:`save`: it acts, and :meth:`resume` finishes its
        training program if it was saved mid-way.

        Loading runs no code that the files name: ``model.json`` is checked against
        its schema, and a Gymnasium env is rebuilt only from an id already
        registered, one of tpo's own dependencies (MO-Gymnasium), or the package
        named by ``trust_env_module``."""
        meta, blob = read_model(path)
        config = TPOConfig.from_saved(meta["config"], meta["format"])
        env = from_spec(meta["env"], num_envs=config.num_envs, trust_module=trust_env_module)
        population = meta.get("population", 1)
        model = cls(env, meta["dag"], meta["slack"], config, meta["seed"],
                    population=population)
        model._fresh_env = model.host
        model.trainer = Trainer(model.env, model.graph, model.config, meta["total_timesteps"])
        blank = (np.zeros((config.num_envs, *model.env.obs_shape), np.float32) if model.host
                 else None)
        template = model.trainer.init(jax.random.key(0), obs=blank)
        if population > 1 and meta["updates_done"] < meta["num_updates"]:
            template = _stack([template] * population)  # the members, still training
        try:
            model.state = restore_state(template, blob)[0]
        except ValueError as err:
            raise DamagedModel(f"{path}/state.msgpack is damaged or does not match "
                           f"model.json: {err}") from None
        model.num_timesteps = meta["num_timesteps"]
        return model


@jax.jit
def _stack(states: list[TrainState]) -> TrainState:
    """The members' states stacked ``[M, ...]`` (one program, not one per leaf)."""
    return jax.tree.map(lambda *x: jnp.stack(x), *states)
