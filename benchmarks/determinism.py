"""Determinism probes: digests of trained parameters under changed settings.

    python benchmarks/determinism.py            # prints one JSON object
    python benchmarks/determinism.py --compare other-machine.json

Trains ``TPO("small", "M>A>G")`` (seed 0, 8 envs x 64 steps, 60 updates) and
hashes every parameter's bytes: run twice, with another chunk size, with
single-threaded XLA and with ``--xla_cpu_max_isa=SSE4_2`` (each in a subprocess,
XLA flags are read at start-up), vmapped in batches of 1, 2 and 4 seeds (seed
0's digest), and a host-stepped MO-Gymnasium env run twice. Equal digests mean
bit-identical results. ``--compare`` lists the probes whose digests differ from
a JSON file saved on another machine. The findings: docs/determinism.md.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys

from tpo.experiments.engine import SINGLE_THREAD

UPDATES = 60


def digest(params) -> str:
    import jax
    import numpy as np

    leaves = jax.tree.leaves(params)
    return hashlib.sha256(b"".join(np.asarray(x).tobytes() for x in leaves)).hexdigest()[:12]


def config():
    from tpo.algo import TPOConfig

    return TPOConfig(num_envs=8, num_steps=64)


def single(chunk: int = 16) -> str:
    from tpo.algo import TPO

    model = TPO("small", "M>A>G", config=config(), seed=0)
    model.learn(config().batch_size * UPDATES, chunk_updates=chunk)
    return digest(model.state.params)


def vmapped(seeds: list[int]) -> str:
    import jax
    import jax.numpy as jnp

    from tpo.algo import Trainer
    from tpo.envs import load_map
    from tpo.envs.grid import GridNav
    from tpo.graph import ObjectiveGraph

    env = GridNav(load_map("small"), random_start=True)
    graph = ObjectiveGraph.parse("M>A>G", 0.0, objectives=env.objectives)
    trainer = Trainer(env, graph, config(), config().batch_size * UPDATES)
    slack = trainer.slack_array()
    states = jax.tree.map(lambda *x: jnp.stack(x),
                          *[trainer.init(jax.random.key(s)) for s in seeds])
    out = jax.jit(jax.vmap(lambda s: trainer.run(s, slack, trainer.num_updates)[0]))(states)
    return digest(jax.tree.map(lambda x: x[0], out.params))


def host() -> str:
    from tpo.algo import TPO

    model = TPO("mo-gymnasium:deep-sea-treasure-v0", "treasure>time",
                objectives=["treasure", "time"], config=config(), seed=0)
    model.learn(config().batch_size * 20)
    return digest(model.state.params)


def in_subprocess(xla_flags: str) -> str:
    env = {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} {xla_flags}"}
    out = subprocess.run([sys.executable, __file__, "--one"], env=env, check=True,
                         capture_output=True, text=True)
    return out.stdout.strip().splitlines()[-1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--compare", help="a JSON file of this script's output elsewhere")
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(single())
        return
    import jax

    result = {
        "jax": jax.__version__,
        "run": single(), "rerun": single(), "chunk 4": single(chunk=4),
        "xla one thread": in_subprocess(SINGLE_THREAD),
        "xla max isa SSE4_2": in_subprocess("--xla_cpu_max_isa=SSE4_2"),
        "vmap 1": vmapped([0]), "vmap 2": vmapped([0, 1]), "vmap 2 other": vmapped([0, 5]),
        "vmap 4": vmapped([0, 1, 2, 3]),
        "host": host(), "host rerun": host(),
    }
    print(json.dumps(result, indent=2))
    if args.compare:
        with open(args.compare) as f:
            other = json.load(f)
        differ = [k for k in result if k != "jax" and other.get(k) != result[k]]
        print("differ from", args.compare, ":", ", ".join(differ) or "none")


if __name__ == "__main__":
    main()
