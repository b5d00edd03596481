"""End-to-end training throughput: TPO (3 objectives) vs plain PPO in the same code vs
a CleanRL-style PyTorch PPO vs Stable-Baselines3 PPO, on the same grid map; TPO on the
continuous env of the same map (``tpo-velocity``, ``tpo-heading``: range sensors and
collision checks every step) against TPO on the grid, and with a tent about every
cell's centre in the observation (``tpo-velocity-places``: ``factored+onehot``)
against the velocity robot's default; and TPO's
host-stepped path (``tpo-host``: the same map as a NumPy Gymnasium env with vector
rewards; ``tpo-host-gym``: the registered ``tpo/GridNav-home-v0``) vs its JAX path.

    pip install -e ".[bench]"          # torch 2.13.0 (CPU) and stable-baselines3
    python benchmarks/bench_ppo.py --envs 16 256 --repeats 3

Every measurement runs in its own subprocess (so its peak RSS is its own) and
reports env-steps/s of training: rollout + PPO update, 128 steps per env per
update, 4 epochs of 4 minibatches, 64x64 tanh actor and critic(s), Adam. JAX runs
are timed after compilation (reported apart); PyTorch and SB3 after one warm-up
update. The PyTorch learner and ``sb3-vec`` step a NumPy vector version of the
same map in one call (the grid's exact model: one table lookup per step,
observations from the same table as GridNav's factored observation), so the env
is not what is compared; ``sb3`` is SB3 as its users run it, ``make_vec_env`` of
a plain one-copy Gymnasium env of the same tables (DummyVecEnv).
Prints medians over ``--repeats`` and the ratios the issue's targets name.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time

import gymnasium as gym
import numpy as np

MAP = "home"
NUM_STEPS = 128


# ------------------------------------------------------------------ NumPy env
class NumpyGrid:
    """``n`` copies of the grid map, stepped together in NumPy (goal reward only)."""

    def __init__(self, n: int, seed: int = 0) -> None:
        from tpo.envs import load_map
        from tpo.envs.grid import GridNav

        env = GridNav(load_map(MAP), random_start=True)
        model = env.tabular(0.99).model
        self.obs_table = env.tabular_observations().astype(np.float32)
        self.next = model.successors[:, :, 0]
        self.reward = model.rewards[:, :, list(model.objectives).index("goal")].astype(np.float32)
        self.terminal = model.terminal
        self.starts = np.flatnonzero(~model.terminal)
        self.max_steps = int(env.params.max_steps)
        self.n, self.num_actions = n, model.n_actions
        self.obs_dim = self.obs_table.shape[1]
        self.rng = np.random.default_rng(seed)
        self.state = self.rng.choice(self.starts, n)
        self.t = np.zeros(n, np.int64)

    def reset(self) -> np.ndarray:
        self.state = self.rng.choice(self.starts, self.n)
        self.t[:] = 0
        return self.obs_table[self.state]

    def step(self, action: np.ndarray):
        reward = self.reward[self.state, action]
        self.state = self.next[self.state, action]
        self.t += 1
        term = self.terminal[self.state]
        trunc = (self.t >= self.max_steps) & ~term
        done = term | trunc
        if done.any():
            self.state[done] = self.rng.choice(self.starts, int(done.sum()))
            self.t[done] = 0
        return self.obs_table[self.state], reward, term, trunc


class GridEnv(gym.Env):
    """One copy of the same grid as a plain Gymnasium env (what an SB3 user writes
    and hands to ``make_vec_env``)."""

    def __init__(self) -> None:
        self.grid = NumpyGrid(1)
        self.observation_space = gym.spaces.Box(0.0, 1.0, (self.grid.obs_dim,), np.float32)
        self.action_space = gym.spaces.Discrete(self.grid.num_actions)

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        return self.grid.reset()[0], {}

    def step(self, action):
        s, t = int(self.grid.state[0]), int(self.grid.t[0]) + 1
        reward = float(self.grid.reward[s, action])
        s = int(self.grid.next[s, action])
        self.grid.state[0], self.grid.t[0] = s, t
        term = bool(self.grid.terminal[s])
        trunc = t >= self.grid.max_steps and not term
        return self.grid.obs_table[s], reward, term, trunc, {}


class MOGridEnv(GridEnv):
    """:class:`GridEnv` with the reward vector ``[goal, avoid, monitor]`` and a
    ``reward_space`` (MO-Gymnasium's convention): what TPO's host path steps."""

    def __init__(self) -> None:
        from tpo.envs import load_map
        from tpo.envs.grid import GridNav

        super().__init__()
        env = GridNav(load_map(MAP), random_start=True)
        self.objectives = env.objectives
        self.rewards = env.tabular(0.99).model.rewards.astype(np.float32)
        self.reward_space = gym.spaces.Box(env.reward_low, env.reward_high, dtype=np.float32)

    def step(self, action):
        s = int(self.grid.state[0])
        obs, _, term, trunc, info = super().step(action)
        return obs, self.rewards[s, action], term, trunc, info


def run_host(n_envs: int, updates: int, gym_id: str | None = None) -> dict:
    """TPO's host-stepped path (``tpo.algo.runners.HostRunner``) on :class:`MOGridEnv`, or on the
    registered Gymnasium id ``gym_id`` (the JAX env stepped one transition per call)."""
    import jax

    from tpo.algo import TPOConfig, Trainer
    from tpo.algo.runners import HostRunner
    from tpo.envs.gym_adapter import HostEnv
    from tpo.graph import ObjectiveGraph

    make = MOGridEnv if gym_id is None else (lambda: gym.make(gym_id))
    objectives = ("goal", "avoid", "monitor")
    env = HostEnv(make, objectives, n_envs)
    config = TPOConfig(num_envs=n_envs, num_steps=NUM_STEPS)
    graph = ObjectiveGraph.parse("M>A>G", 0.0, objectives=objectives)
    trainer = Trainer(env, graph, config, config.batch_size * (2 * updates + 1) * 3)
    runner, slack = HostRunner(trainer, env), trainer.slack_array()
    state = trainer.init(jax.random.key(0), obs=env.reset(0))
    return timed(lambda s: runner(s, slack, 1, 1), lambda s: runner(s, slack, updates, updates),
                 state, updates * config.batch_size)


def timed(warm_up, run, state, steps: int) -> dict:
    """``run(warm_up(state))`` timed, the warm-up (compilation) apart."""
    import jax

    t0 = time.perf_counter()
    state, _ = warm_up(state)
    jax.block_until_ready(state)
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    state, _ = run(state)
    jax.block_until_ready(state)
    return {"seconds": time.perf_counter() - t0, "steps": steps, "compile_s": compile_s}


# ------------------------------------------------------------------------ JAX
def run_jax(dag: str, n_envs: int, updates: int, seeds: int = 1, action: str | None = None,
            observation: str = "factored") -> dict:
    """TPO's trainer on the grid, or with ``action`` on the continuous env of the same
    map (velocity or heading actions; its ``observation``); with ``seeds`` > 1, that
    many runs vmapped in one program (the steps of all of them counted)."""
    import jax
    import jax.numpy as jnp

    from tpo.algo import TPOConfig, Trainer
    from tpo.envs import ContinuousNav, GridNav, load_map
    from tpo.graph import ObjectiveGraph

    env = (GridNav(load_map(MAP), random_start=True) if action is None
           else ContinuousNav(load_map(MAP), action=action, random_start=True,
                              observation=observation))
    config = TPOConfig(num_envs=n_envs, num_steps=NUM_STEPS)
    graph = ObjectiveGraph.parse(dag, 0.0, objectives=env.objectives)
    n_phases = len(graph.order)
    trainer = Trainer(env, graph, config, config.batch_size * (2 * updates + 1) * n_phases)
    slack = trainer.slack_array()
    if seeds == 1:
        state = trainer.init(jax.random.key(0))
        run = jax.jit(lambda s: trainer.run(s, slack, updates))
    else:
        state = jax.tree.map(lambda *x: jnp.stack(x),
                             *[trainer.init(jax.random.key(i)) for i in range(seeds)])
        run = jax.jit(jax.vmap(lambda s: trainer.run(s, slack, updates)))
    return timed(run, run, state, seeds * updates * config.batch_size)


# -------------------------------------------------------------------- PyTorch
def run_torch(n_envs: int, updates: int) -> dict:
    """A CleanRL-style PPO (ppo.py's loop) written here, on :class:`NumpyGrid`."""
    import torch
    from torch import nn

    torch.set_num_threads(2)
    torch.manual_seed(0)
    env = NumpyGrid(n_envs)

    def layer(i: int, o: int, std: float = np.sqrt(2)) -> nn.Linear:
        lin = nn.Linear(i, o)
        nn.init.orthogonal_(lin.weight, std)
        nn.init.zeros_(lin.bias)
        return lin

    def mlp(out: int, std: float) -> nn.Sequential:
        return nn.Sequential(layer(env.obs_dim, 64), nn.Tanh(), layer(64, 64), nn.Tanh(),
                             layer(64, out, std))

    actor, critic = mlp(env.num_actions, 0.01), mlp(1, 1.0)
    params = [*actor.parameters(), *critic.parameters()]
    opt = torch.optim.Adam(params, lr=1e-3, eps=1e-5)
    gamma, lam, clip, batch = 0.99, 0.95, 0.2, n_envs * NUM_STEPS
    obs = torch.as_tensor(env.reset())

    def update() -> None:
        nonlocal obs
        b_obs = torch.zeros(NUM_STEPS, n_envs, env.obs_dim)
        b_act = torch.zeros(NUM_STEPS, n_envs, dtype=torch.long)
        b_logp, b_rew, b_val, b_next, b_term, b_done = (torch.zeros(NUM_STEPS, n_envs)
                                                        for _ in range(6))
        with torch.no_grad():
            for t in range(NUM_STEPS):
                dist = torch.distributions.Categorical(logits=actor(obs))
                action = dist.sample()
                b_obs[t], b_act[t], b_logp[t] = obs, action, dist.log_prob(action)
                b_val[t] = critic(obs).squeeze(-1)
                nxt, rew, term, trunc = env.step(action.numpy())
                obs = torch.as_tensor(nxt)
                b_rew[t] = torch.as_tensor(rew)
                b_next[t] = critic(obs).squeeze(-1)  # bootstraps truncation (approx.)
                b_term[t] = torch.as_tensor(term, dtype=torch.float32)
                b_done[t] = torch.as_tensor(term | trunc, dtype=torch.float32)
            adv = torch.zeros(NUM_STEPS, n_envs)
            last = torch.zeros(n_envs)
            for t in reversed(range(NUM_STEPS)):
                delta = b_rew[t] + gamma * b_next[t] * (1 - b_term[t]) - b_val[t]
                last = delta + gamma * lam * (1 - b_done[t]) * last
                adv[t] = last
            ret = adv + b_val
        f_obs, f_act, f_logp = b_obs.reshape(batch, -1), b_act.reshape(-1), b_logp.reshape(-1)
        f_adv, f_ret = adv.reshape(-1), ret.reshape(-1)
        for _ in range(4):
            for idx in torch.randperm(batch).reshape(4, -1):
                dist = torch.distributions.Categorical(logits=actor(f_obs[idx]))
                ratio = (dist.log_prob(f_act[idx]) - f_logp[idx]).exp()
                a = f_adv[idx]
                a = (a - a.mean()) / (a.std() + 1e-8)
                pg = torch.max(-a * ratio, -a * ratio.clamp(1 - clip, 1 + clip)).mean()
                vl = 0.5 * ((critic(f_obs[idx]).squeeze(-1) - f_ret[idx]) ** 2).mean()
                loss = pg - 0.01 * dist.entropy().mean() + 0.5 * vl
                opt.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(params, 0.5)
                opt.step()

    update()  # warm-up
    t0 = time.perf_counter()
    for _ in range(updates):
        update()
    return {"seconds": time.perf_counter() - t0, "steps": updates * batch}


# ------------------------------------------------------------------------ SB3
def run_sb3(n_envs: int, updates: int, batched: bool = False) -> dict:
    """SB3's PPO on ``make_vec_env`` of :class:`GridEnv` (its usual DummyVecEnv), or,
    ``batched``, on a custom VecEnv stepping :class:`NumpyGrid` in one call."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecEnv

    torch.set_num_threads(2)

    class SB3Grid(VecEnv):
        def __init__(self, n: int) -> None:
            self.grid = NumpyGrid(n)
            super().__init__(n, gym.spaces.Box(0.0, 1.0, (self.grid.obs_dim,), np.float32),
                             gym.spaces.Discrete(self.grid.num_actions))

        def reset(self):
            return self.grid.reset()

        def step_async(self, actions):
            self._actions = actions

        def step_wait(self):
            obs, rew, term, trunc = self.grid.step(self._actions)
            infos = [{"TimeLimit.truncated": bool(t), "terminal_observation": o}
                     for t, o in zip(trunc, obs, strict=True)]
            return obs, rew, term | trunc, infos

        def close(self):
            pass

        def get_attr(self, name, indices=None):
            return [None] * self.num_envs

        def set_attr(self, name, value, indices=None):
            pass

        def env_method(self, name, *args, indices=None, **kwargs):
            return [None] * self.num_envs

        def env_is_wrapped(self, wrapper_class, indices=None):
            return [False] * self.num_envs

    batch = n_envs * NUM_STEPS
    venv = SB3Grid(n_envs) if batched else make_vec_env(GridEnv, n_envs=n_envs, seed=0)
    model = PPO("MlpPolicy", venv, n_steps=NUM_STEPS, batch_size=batch // 4,
                n_epochs=4, learning_rate=1e-3, ent_coef=0.01, device="cpu", seed=0,
                policy_kwargs={"net_arch": [64, 64], "activation_fn": torch.nn.Tanh})
    model.learn(batch)  # warm-up
    t0 = time.perf_counter()
    model.learn(updates * batch, reset_num_timesteps=False)
    return {"seconds": time.perf_counter() - t0, "steps": updates * batch}


LEARNERS = {
    "tpo": lambda n, u: run_jax("M>A>G", n, u),
    "ppo": lambda n, u: run_jax("goal", n, u),
    "tpo-x8": lambda n, u: run_jax("M>A>G", n, u, seeds=8),
    "tpo-velocity": lambda n, u: run_jax("M>A>G", n, u, action="velocity"),
    "tpo-heading": lambda n, u: run_jax("M>A>G", n, u, action="heading"),
    "tpo-velocity-places": lambda n, u: run_jax("M>A>G", n, u, action="velocity",
                                                observation="factored+onehot"),
    "tpo-host": run_host,
    "tpo-host-gym": lambda n, u: run_host(n, u, "tpo/GridNav-home-v0"),
    "torch": run_torch,
    "sb3": run_sb3,
    "sb3-vec": lambda n, u: run_sb3(n, u, batched=True),
}


def measure(name: str, n_envs: int, updates: int) -> dict:
    out = subprocess.run([sys.executable, __file__, "--one", name, str(n_envs), str(updates)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, nargs="+", default=[16, 256])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=4.0,
                        help="rough length of one measurement")
    parser.add_argument("--learners", nargs="+", default=list(LEARNERS))
    parser.add_argument("--one", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        name, n_envs, updates = args.one[0], int(args.one[1]), int(args.one[2])
        result = LEARNERS[name](n_envs, updates)
        result["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(json.dumps(result))
        return
    # steps/s (per run), to size the measurements
    guess = {"tpo": 60e3, "ppo": 70e3, "torch": 15e3, "sb3": 4e3, "sb3-vec": 15e3,
             "tpo-x8": 15e3, "tpo-velocity": 40e3, "tpo-heading": 40e3,
             "tpo-velocity-places": 20e3, "tpo-host": 8e3,
             "tpo-host-gym": 2e3}
    rows = {}
    for n_envs in args.envs:
        for name in args.learners:
            batch = n_envs * NUM_STEPS
            updates = max(2, round(args.seconds * guess[name] * (1 + n_envs / 64) / 2 / batch))
            runs = [measure(name, n_envs, updates) for _ in range(args.repeats)]
            rate = statistics.median(r["steps"] / r["seconds"] for r in runs)
            rss = max(r["peak_rss_mb"] for r in runs)
            rows[name, n_envs] = rate
            extra = f", compile {statistics.median(r['compile_s'] for r in runs):.1f} s" \
                if "compile_s" in runs[0] else ""
            print(f"{name:6} {n_envs:4d} envs: {rate / 1e3:8.1f} k steps/s "
                  f"(median of {len(runs)}, {runs[0]['steps']} steps each{extra}), "
                  f"peak RSS {rss:.0f} MB", flush=True)
    for n_envs in args.envs:
        r = {k[0]: v for k, v in rows.items() if k[1] == n_envs}
        ratios = [f"{a}/{b} {r[a] / r[b]:.2f}x" for a, b in
                  (("tpo", "ppo"), ("tpo", "torch"), ("tpo", "sb3"), ("tpo", "sb3-vec"),
                   ("ppo", "torch"), ("tpo-x8", "sb3"), ("tpo-velocity", "tpo"),
                   ("tpo-heading", "tpo"), ("tpo-velocity-places", "tpo-velocity"),
                   ("tpo-host", "tpo"),
                   ("tpo-host-gym", "tpo"))
                  if a in r and b in r]
        print(f"{n_envs:4d} envs: " + ", ".join(ratios))


if __name__ == "__main__":
    main()
