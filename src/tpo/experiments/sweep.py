"""Many slack values × seeds of one DAG as a single compiled run, judged against LAR.

The trainer's ``run`` is vmapped over seeds and then over slack vectors, so
``S`` slacks × ``N`` seeds train as one jitted program (chunked only to report
progress). Each learned greedy leaf policy is then evaluated beside LAR's
solution of the same DAG, slack and gamma: on a grid exactly on its tabular
model (and by Monte Carlo); in continuous space against the env's finite
reference (:mod:`tpo.envs.continuous_model`), at value level.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from tpo.algo import TPOConfig, Trainer, TrainState
from tpo.algo.evaluate import CONTINUOUS_TOL, episode_returns, greedy_path, noise_free
from tpo.algo.persist import restore_state, state_bytes
from tpo.algo.phases import Acting
from tpo.algo.selection import select
from tpo.envs.continuous import ContinuousNav
from tpo.envs.continuous_model import continuous_model, path_category
from tpo.envs.grid import GridNav
from tpo.envs.spec import from_spec
from tpo.errors import TPOError
from tpo.graph import ObjectiveGraph
from tpo.tabular import VERDICTS, Judge, solve_lar
from tpo.tabular.judge import ABS_TOL


@dataclass(frozen=True)
class SweepResult:
    """Values at the start state, by slack ``s``, seed ``n`` and objective ``k``.

    Attributes:
        graph: the DAG (with the first slack).
        objectives: reward columns (the last axis of every value array).
        slacks: ``[S, n_edges]`` local slack of every run.
        seeds: the ``N`` seeds.
        exact: ``[S, N, k]`` exact discounted values of the learned greedy policy
            (continuous: of its noise-free episode from the start).
        mc: ``[S, N, k]`` mean discounted Monte Carlo return of the greedy policy
            (continuous: with the env's noise).
        lar: ``[S, k]`` exact values of LAR's leaf policy (the completion).
        feasible: ``[S]`` whether LAR found the problem feasible (else relaxed).
        policies: ``[S, N, n_states]`` the learned greedy actions on the grid model
            (None in continuous space).
        paths: ``[S][N]`` each greedy policy's path from the start: the cells
            ``[T, 2]`` on a grid, the noise-free positions ``[T, 2]`` in continuous
            space (cell ``(r, c)`` covers ``[r, r + 1) x [c, c + 1)``).
        lar_correct, strict, same_values: ``[S, N]`` the verdicts of
            :class:`tpo.tabular.Judge` (docs/design.md §6); in continuous space at
            value level within 5 % (``CONTINUOUS_TOL``), strict meaning also the
            path's category (goal reached, avoid region entered, monitor region
            at the end) is the reference path's.
    """

    graph: ObjectiveGraph
    objectives: tuple[str, ...]
    slacks: np.ndarray
    seeds: tuple[int, ...]
    exact: np.ndarray
    mc: np.ndarray
    lar: np.ndarray
    feasible: np.ndarray
    policies: np.ndarray | None
    paths: list[list[np.ndarray]]
    lar_correct: np.ndarray
    strict: np.ndarray
    same_values: np.ndarray

    def record(self) -> dict[str, Any]:
        """The JSON-able values and verdicts, by slack, seed and objective."""
        return {"slacks": self.slacks.tolist(), "seeds": list(self.seeds),
                "objectives": list(self.objectives), "exact": self.exact.tolist(),
                "mc": self.mc.tolist(), "lar": self.lar.tolist(),
                "feasible": self.feasible.tolist(),
                **{k: getattr(self, k).tolist() for k in VERDICTS}}


Progress = Callable[[int, int], None]


def run_sweep(env: GridNav | ContinuousNav, dag: str | ObjectiveGraph,
              slacks: Sequence[Sequence[float]], seeds: Sequence[int], config: TPOConfig,
              total_timesteps: int, *,
              episodes: int = 8, chunk_updates: int = 32, progress: Progress | None = None,
              checkpoint: Checkpoint | None = None) -> SweepResult:
    """Train ``dag`` at every slack vector × seed in one compiled run and evaluate.

    ``env`` is the training env (e.g. with random starts); evaluation starts
    from the map's start. ``progress(updates_done, num_updates)`` is called as
    training starts (or resumes) and after every chunk. With ``checkpoint``, the
    stacked training state is saved there at most every ``checkpoint.every``
    seconds (at chunk boundaries) and a later call with the same arguments resumes
    from it, to the same result.
    """
    slack_arr = np.asarray(slacks, np.float32)
    first = slack_arr[0].tolist() if slack_arr.ndim == 2 and len(slack_arr) else []
    graph = (dag.with_slack(first) if isinstance(dag, ObjectiveGraph)
             else ObjectiveGraph.parse(dag, first, objectives=env.objectives))
    graphs = [graph.with_slack(s.tolist()) for s in slack_arr]  # checks every slack vector
    trainer = Trainer(env, graph, config, total_timesteps)
    per_seed = [trainer.init(jax.random.key(s)) for s in seeds]  # outside vmap: docs/design.md §5
    states = _stacked(per_seed, len(slack_arr))
    length = min(chunk_updates, trainer.num_updates)
    over_seeds = jax.vmap(lambda st, sl, n: trainer.run_chunk(st, sl, n, length)[0],
                          in_axes=(0, None, None))
    chunk = jax.jit(jax.vmap(over_seeds, in_axes=(0, 0, None)))  # one program, every chunk
    done = 0
    saved = None if checkpoint is None else checkpoint.load()
    if saved is not None:
        states, done = _load_states(checkpoint, saved, states)
    if progress is not None:
        progress(done, trainer.num_updates)
    saved_at = time.monotonic()
    while done < trainer.num_updates:
        n = min(chunk_updates, trainer.num_updates - done)
        states = jax.block_until_ready(chunk(states, jnp.asarray(slack_arr), jnp.int32(n)))
        done += n
        if checkpoint is not None and time.monotonic() - saved_at >= checkpoint.every:
            checkpoint.save(state_bytes(states, done=done))
            saved_at = time.monotonic()
        if progress is not None:
            progress(done, trainer.num_updates)
    slack_j = jnp.asarray(slack_arr)
    answer = partial(select, trainer, env=from_spec(env.to_spec(), evaluation=True))
    states = jax.jit(jax.vmap(jax.vmap(answer, in_axes=(0, None))))(states, slack_j)
    actings = jax.vmap(jax.vmap(trainer.acting, in_axes=(0, None)))(states, slack_j)
    evaluate = evaluate_sweep if hasattr(env, "tabular") else evaluate_reference_sweep
    return evaluate(trainer, actings, env, graphs, np.asarray(slacks, np.float64),
                    tuple(seeds), episodes)


@partial(jax.jit, static_argnums=1)
def _stacked(per_seed: list[TrainState], slacks: int) -> TrainState:
    """The seeds' states stacked ``[N, ...]``, then once for each slack value: ``[S, N,
    ...]`` (one program, not one eager operation per leaf)."""
    states = jax.tree.map(lambda *x: jnp.stack(x), *per_seed)
    return jax.tree.map(lambda x: jnp.broadcast_to(x, (slacks, *x.shape)), states)


class Checkpoint(Protocol):
    """Where a sweep keeps its training state (:class:`tpo.experiments.engine.Link`):
    saved at most every ``every`` seconds; ``where`` names it in messages."""

    every: float
    where: str

    def load(self) -> bytes | None: ...

    def save(self, data: bytes) -> None: ...


def _load_states(checkpoint: Checkpoint, data: bytes, template: TrainState
                 ) -> tuple[TrainState, int]:
    try:
        states, extra = restore_state(template, data)
        return states, int(extra["done"])
    except (ValueError, KeyError, TypeError) as err:
        raise TPOError(f"{checkpoint.where} is not a checkpoint of this sweep: {err}; "
                       "delete it to start the sweep again") from None


def evaluate_sweep(trainer: Trainer, actings: Acting, env: GridNav,
                   graphs: Sequence[ObjectiveGraph], slacks: np.ndarray,
                   seeds: tuple[int, ...], episodes: int) -> SweepResult:
    """Exact and Monte Carlo values of the policies ``actings`` (leading axes
    ``[S, N]``, of :meth:`Trainer.acting`)."""
    eval_env = from_spec(env.to_spec(), evaluation=True)
    gamma = trainer.config.gamma
    model = eval_env.tabular(gamma).model
    obs = jnp.asarray(eval_env.tabular_observations())
    policies = np.asarray(jax.vmap(jax.vmap(lambda p: trainer.policy(p, obs).mode()))(actings))
    solutions = [solve_lar(model, g, relax=True) for g in graphs]
    verdicts = [[judge(pi) for pi in row]
                for judge, row in zip(map(Judge, solutions), policies, strict=True)]
    exact = np.array([[[v.values[n] for n in model.objectives] for v in row]
                      for row in verdicts])
    keys = jax.random.split(jax.random.key(0), episodes)
    mc_run = jax.jit(jax.vmap(jax.vmap(
        lambda p: episode_returns(trainer.policy, p, eval_env, keys, True, gamma)[1].mean(0))))
    mc = np.asarray(mc_run(actings), np.float64)
    lar = np.array([[s.start_policy_values()[n] for n in env.objectives] for s in solutions])
    flags = {name: np.array([[getattr(v, name) for v in row] for row in verdicts])
             for name in VERDICTS}
    grid = eval_env.tabular(gamma)
    paths = [[grid.rollout(pi) for pi in row] for row in policies]
    return SweepResult(graphs[0], tuple(env.objectives), slacks, seeds, exact, mc, lar,
                       np.array([s.feasible for s in solutions]), policies, paths, **flags)


def evaluate_reference_sweep(trainer: Trainer, actings: Acting, env: ContinuousNav,
                             graphs: Sequence[ObjectiveGraph], slacks: np.ndarray,
                             seeds: tuple[int, ...], episodes: int) -> SweepResult:
    """The continuous counterpart of :func:`evaluate_sweep`: each greedy policy's
    noise-free episode and its Monte Carlo return with the env's noise, judged
    against the env's finite reference (solved once per slack)."""
    eval_env = from_spec(env.to_spec(), evaluation=True)
    gamma = trainer.config.gamma
    ref = continuous_model(eval_env, gamma)
    path = jax.jit(jax.vmap(jax.vmap(partial(greedy_path, trainer.policy,
                                             env=noise_free(eval_env, gamma), gamma=gamma))))
    positions, alive, returns = map(np.asarray, path(actings))
    keys = jax.random.split(jax.random.key(0), episodes)
    mc_run = jax.jit(jax.vmap(jax.vmap(
        lambda p: episode_returns(trainer.policy, p, eval_env, keys, True, gamma)[1].mean(0))))
    mc = np.asarray(mc_run(actings), np.float64)
    objectives = tuple(env.objectives)
    solutions = [solve_lar(ref.model, g, relax=True) for g in graphs]
    verdicts = np.zeros((len(graphs), len(seeds), len(VERDICTS)), bool)
    for s, sol in enumerate(solutions):
        judge, reference = Judge(sol, ABS_TOL), ref.category(sol.policy)
        for n in range(len(seeds)):
            values = dict(zip(objectives, map(float, returns[s, n]), strict=True))
            correct = judge.lar_correct(values, CONTINUOUS_TOL)
            matches = path_category(env.navmap, positions[s, n][alive[s, n]]) == reference
            verdicts[s, n] = (correct, correct and matches,
                              judge.same_values(values, CONTINUOUS_TOL))
    lar = np.array([[s.start_policy_values()[n] for n in objectives] for s in solutions])
    paths = [[positions[s, n][alive[s, n]] for n in range(len(seeds))]
             for s in range(len(graphs))]
    return SweepResult(graphs[0], objectives, slacks, seeds, returns.astype(np.float64), mc,
                       lar, np.array([s.feasible for s in solutions]), None, paths,
                       **{k: verdicts[..., i] for i, k in enumerate(VERDICTS)})
