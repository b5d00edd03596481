"""Two sources of rollouts for one learner: a chunk of updates compiled whole on a
JAX env, and updates on a Gymnasium env stepped on the host. Both end in
:meth:`tpo.algo.train.Trainer.learn`: one implementation of the algorithm.

A runner is ``run(state, slack, n, length) -> (state, metrics)``: ``n`` updates,
metrics stacked over them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import jax
import jax.numpy as jnp
import numpy as np

from tpo.algo.evaluate import Episodes
from tpo.algo.phases import Acting
from tpo.algo.train import Rollout, Trainer, TrainState
from tpo.envs.gym_adapter import EnvError, HostEnv

Runner = Callable[[TrainState, jax.Array, int, int], tuple[TrainState, dict]]


def jax_runner(trainer: Trainer, population: bool = False) -> Runner:
    """``n`` updates by one jitted program per ``length`` (so a run's shorter last
    chunk compiles nothing new); metrics of the ``n`` updates. With ``population``,
    the state is a population's members stacked ``[M, ...]``, trained vmapped
    (metrics ``[M, n, ...]``)."""
    if population:
        def run_chunk(states: TrainState, slack: jax.Array, n: jax.Array, length: int):
            return jax.vmap(lambda s: trainer.run_chunk(s, slack, n, length))(states)

        chunk = jax.jit(run_chunk, static_argnums=3)
    else:
        chunk = jax.jit(trainer.run_chunk, static_argnums=3)

    def run(state: TrainState, slack: jax.Array, n: int, length: int):
        state, rows = chunk(state, slack, jnp.int32(n), length)
        return state, jax.tree.map(lambda x: x[:, :n] if population else x[:n], rows)

    return run


class HostRunner:
    """Runs :class:`Trainer` updates on rollouts of a :class:`HostEnv`, and plays its
    episodes for evaluation and the end-of-run selection.

    With ``members`` ``M``, the state is a population's members stacked ``[M, ...]``,
    each stepping its own ``N`` of the env's ``M * N`` copies; acting and learning
    are vmapped over the members (one JAX call per step for all of them)."""

    def __init__(self, trainer: Trainer, env: HostEnv, members: int = 0) -> None:
        self.trainer, self.env, self.members = trainer, env, members

        def act(acting: Acting, obs: jax.Array, key_data: jax.Array, greedy: jax.Array):
            pi = trainer.policy(acting, obs)
            return jnp.where(greedy, pi.mode(), pi.sample(jax.random.wrap_key_data(key_data)))

        def prepare(state: TrainState, slack: jax.Array):
            """The rollout's acting, the state's next key, one key per step."""
            acting = trainer.acting(state, slack, trainer.phase_of(state.update))
            key, k_roll = jax.random.split(state.key)
            return acting, key, jax.random.key_data(
                jax.random.split(k_roll, trainer.config.num_steps))

        def behave(acting: Acting, obs: jax.Array, key_data: jax.Array):
            return trainer.behave(acting, obs, jax.random.wrap_key_data(key_data))

        def each(f: Callable, *axes: int | None) -> Callable:  # over the members
            return jax.vmap(f, in_axes=axes or 0) if members else f

        # Keys travel as raw key data (NumPy): indexing typed keys on the host costs
        # an eager JAX dispatch per step; each step syncs with the device only for
        # the action.
        self._act = jax.jit(act)
        self._prepare = each(prepare, 0, None)
        self._behave = jax.jit(each(behave))
        self._begin = jax.jit(each(trainer.begin_phase))
        self._learn = jax.jit(each(trainer.learn, 0, None, 0, 0))

    def __call__(self, state: TrainState, slack: jax.Array, n: int, length: int
                 ) -> tuple[TrainState, dict]:
        del length  # nothing is compiled per chunk here
        history = []
        for _ in range(n):
            state, rollout, episodes = self.collect(state, slack)
            state, metrics = self._learn(self._begin(state), slack, rollout, episodes)
            history.append(metrics)
        return state, jax.tree.map(lambda *x: jnp.stack(x, int(bool(self.members))), *history)

    def collect(self, state: TrainState, slack: jax.Array
                ) -> tuple[TrainState, Rollout, dict]:
        """The host counterpart of :meth:`Trainer.collect` (each member's, stacked)."""
        cfg, env = self.trainer.config, self.env
        acting, key, keys = self._prepare(state, slack)
        keys = np.asarray(keys)
        members = (self.members, cfg.num_envs) if self.members else (env.num_envs,)
        obs = np.asarray(state.obs)
        stats = jax.tree.map(np.asarray, state.episodes.clear())
        steps: list[tuple] = []
        behaviour: list[tuple] = []
        for t in range(cfg.num_steps):
            action, log_prob, allowed, explore = self._behave(acting, obs, keys[..., t, :])
            action = np.asarray(action)
            stepped = env.step(action.reshape(env.num_envs, *action.shape[len(members):]))
            if not np.isfinite(stepped[1]).all():
                env_i, col = np.argwhere(~np.isfinite(stepped[1]))[0]
                raise EnvError(f"{env.name} returned a non-finite reward "
                               f"{stepped[1][env_i, col]} for objective "
                               f"'{env.objectives[col]}' at update "
                               f"{int(np.max(state.update)) + 1}, step {t + 1} of its "
                               f"rollout, in copy {env_i}")
            nxt, reward, term, trunc, final = (x.reshape(*members, *x.shape[1:])
                                               for x in stepped)
            done = (term | trunc).astype(np.float32)
            stats = stats.update(reward, done)
            steps.append((obs, action, reward, final, term.astype(np.float32), done))
            behaviour.append((log_prob, allowed, explore))
            obs = nxt
        time_axis = len(members) - 1  # a member's rollout is [T, N, ...]
        o, a, r, f, te, d = (jnp.asarray(np.stack(x, time_axis))
                             for x in zip(*steps, strict=True))
        log_prob, allowed, explore = jax.tree.map(lambda *x: jnp.stack(x, time_axis),
                                                  *behaviour)
        rollout = Rollout(o, a, log_prob, r, f, te, d, allowed, explore)
        state = state.replace(obs=jnp.asarray(obs), key=key,
                              episodes=jax.tree.map(jnp.asarray, stats))
        summary = jax.vmap(type(stats).summary) if self.members else type(stats).summary
        return state, rollout, summary(stats)

    def greedy_episodes(self, acting: Acting, episodes: int, seed: int) -> Episodes:
        """``episodes`` greedy episodes of the runner's env from ``env.reset(seed)``, as
        :class:`tpo.algo.evaluate.Episodes` padded to a power of two of steps (so
        few lengths compile)."""
        env = self.env
        quota = -(-episodes // env.num_envs)
        done: list[list[tuple]] = [[] for _ in range(env.num_envs)]
        current: list[list[tuple]] = [[] for _ in range(env.num_envs)]
        obs = env.reset(seed)
        keys = _key_stream(jax.random.key(seed))
        while min(len(d) for d in done) < quota:
            action = self._act(acting, obs, next(keys), jnp.bool_(True))
            nxt, reward, term, trunc, final = env.step(np.asarray(action))
            for i in range(env.num_envs):
                current[i].append((obs[i], final[i], reward[i], float(term[i])))
                if term[i] or trunc[i]:
                    if len(done[i]) < quota:
                        done[i].append(current[i])
                    current[i] = []
            obs = nxt
        runs = [run for d in done for run in d][:episodes]
        length = 1 << max(len(r) for r in runs).bit_length()
        zero = (np.zeros_like(obs[0]), np.zeros_like(obs[0]), np.zeros_like(reward[0]), 0.0)
        padded = [[*r, *[zero] * (length - len(r))] for r in runs]
        o, f, r, t = (np.asarray(x, np.float32) for x in zip(
            *[tuple(zip(*run, strict=True)) for run in padded], strict=True))
        alive = np.asarray([[1.0] * len(r) + [0.0] * (length - len(r)) for r in runs],
                           np.float32)
        return Episodes(jnp.asarray(o), jnp.asarray(f), jnp.asarray(r), jnp.asarray(t),
                        jnp.asarray(alive))

    def monte_carlo(self, acting: Acting, episodes: int, greedy: bool, gamma: float,
                    seed: int) -> dict[str, np.ndarray]:
        """Returns of ``episodes`` episodes on the runner's env (the layout of
        :func:`tpo.algo.evaluate.monte_carlo`); every copy runs the same number of
        whole episodes, so short episodes are not over-represented."""
        env = self.env
        k, n = len(env.objectives), env.num_envs
        quota = -(-episodes // n)
        found: list[list[tuple]] = [[] for _ in range(n)]
        obs = env.reset(seed)
        r_acc, d_acc = np.zeros((n, k)), np.zeros((n, k))
        g_acc, l_acc = np.ones(n), np.zeros(n)
        keys = _key_stream(jax.random.key(seed))
        while min(len(f) for f in found) < quota:
            action = self._act(acting, obs, next(keys), jnp.bool_(greedy))
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


def _key_stream(key: jax.Array, block: int = 256) -> Iterator[np.ndarray]:
    """Endless raw key data from ``key``, split ``block`` at a time (one JAX call
    per block, not per step)."""
    while True:
        key, sub = jax.random.split(key)
        yield from np.asarray(jax.random.key_data(jax.random.split(sub, block)))
