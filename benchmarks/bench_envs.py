"""Vectorised environment throughput: env-steps per second with random actions.

    python benchmarks/bench_envs.py --envs 256 1024 4096 --steps 1000 --repeats 5

Each measurement is one jitted ``lax.scan`` of ``--steps`` steps of ``vmap(step)``
(auto-reset included) over ``--envs`` environments. The observation and reward of
every step are summed into the carry so that XLA cannot drop their computation.
Prints the median over the repeats (compile time excluded, reported apart).
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp

from tpo.envs import load_map
from tpo.envs.continuous import ContinuousNav
from tpo.envs.grid import GridNav


def rollout_fn(env, n_envs: int, n_steps: int, continuous_actions: bool):
    def sample(key):
        if continuous_actions:
            return jax.random.uniform(key, (n_envs, 2), minval=-1, maxval=1)
        return jax.random.randint(key, (n_envs,), 0, env.action_space.n)

    def run(key):
        _, states = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, n_envs),
                                                            env.params)

        def body(carry, key):
            states, acc = carry
            k_act, k_step = jax.random.split(key)
            obs, states, reward, term, trunc, _ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(k_step, n_envs), states, sample(k_act), env.params)
            acc = acc + obs.sum() + reward.sum() + (term | trunc).sum()
            return (states, acc), None

        (_, acc), _ = jax.lax.scan(body, (states, jnp.float32(0)),
                                   jax.random.split(key, n_steps))
        return acc

    return jax.jit(run)


def measure(name, env, n_envs, n_steps, repeats, continuous_actions=False):
    fn = rollout_fn(env, n_envs, n_steps, continuous_actions)
    t0 = time.perf_counter()
    fn(jax.random.key(0)).block_until_ready()
    compile_s = time.perf_counter() - t0
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        fn(jax.random.key(r + 1)).block_until_ready()
        times.append(time.perf_counter() - t0)
    rate = n_envs * n_steps / statistics.median(times)
    print(f"{name:<28} {n_envs:>6} {rate / 1e6:10.2f} M/s   (compile {compile_s:.1f} s)",
          flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="home")
    parser.add_argument("--envs", type=int, nargs="+", default=[256, 1024, 4096])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    navmap = load_map(args.map)
    print(f"{'env':<28} {'envs':>6} {'steps/s':>12}   ({jax.devices()[0].platform})")
    for n in args.envs:
        for obs in ("factored", "factored+onehot", "coords"):
            measure(f"GridNav ({obs})", GridNav(navmap, observation=obs), n, args.steps,
                    args.repeats)
        measure("GridNav slip 0.1", GridNav(navmap, slip=0.1, observation="factored"), n,
                args.steps, args.repeats)
        measure("ContinuousNav velocity", ContinuousNav(navmap), n, args.steps, args.repeats,
                continuous_actions=True)
        measure("ContinuousNav heading", ContinuousNav(navmap, action="heading"), n,
                args.steps, args.repeats)


if __name__ == "__main__":
    main()
