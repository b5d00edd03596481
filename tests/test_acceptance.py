"""Issue 4's acceptance: TPO's learned greedy leaf policy against the exact LAR
optimum on the `small` map, where the objectives conflict (the shortest way
crosses the avoid room; the study to monitor is off the way).

Judged exactly on the grid's tabular model by the TMDP's own criterion
(LAR-correct, docs/design.md §6), counted over seeds trained in one vmapped
program (tests/conftest.py). Margins measured per instruction set are in
docs/determinism.md.
"""

import numpy as np
import pytest

from tpo.algo import TPOConfig
from tpo.envs import load_map
from tpo.envs.grid import GridNav
from tpo.experiments.sweep import run_sweep

STEPS = 600_000
GOAL, AVOID, MONITOR = 0, 1, 2


@pytest.fixture(scope="module")
def env():
    return GridNav(load_map("small"), random_start=True)


@pytest.mark.slow
def test_chain_at_slack_0_is_lar_correct_and_slack_trades_monitor_for_goal(env, seeds,
                                                                         at_least):
    result = run_sweep(env, "M>A>G", [[0, 0], [100, 100]], seeds=seeds(5), config=TPOConfig(),
                       total_timesteps=STEPS)
    assert result.feasible.all()
    # LAR at slack 0: visit the study (monitor 88.6), avoid nothing more, goal pays.
    np.testing.assert_allclose(result.lar[0], [-100.0, -2.882, 88.638], atol=1e-3)
    correct = result.lar_correct  # [slack, seed]
    slack0, slack100 = result.exact[0], result.exact[1]  # [seed, objective]
    # Paper Fig. 2(a): more slack on both edges lowers monitor and raises goal.
    trades = (slack100[:, GOAL] > slack0[:, GOAL] + 50) & \
        (slack100[:, MONITOR] < slack0[:, MONITOR] - 50)
    # Monte Carlo agrees with the exact values where the greedy path ends within the
    # episode limit (at slack 100, once learned; at slack 0 it stays in the study).
    # Both are sums of at most 60 discounted rewards of size <= 2: float32 rounding
    # stays far below 1e-3.
    agrees = np.all(np.abs(result.mc[1] - result.exact[1]) <= 1e-3, axis=-1)
    at_least(0.6, correct.all(0) & trades & agrees,
             {"exact": result.exact.round(2).tolist(), "lar": result.lar.round(2).tolist()})


@pytest.mark.slow
def test_feasible_fan_is_lar_correct(env, seeds, at_least):
    # Avoid with slack 0 and monitor with slack 100 over goal: the detour around
    # the avoid room, no visit to the study.
    result = run_sweep(env, "A>G, M>G", [[0, 100]], seeds=seeds(5), config=TPOConfig(),
                       total_timesteps=STEPS)
    assert result.feasible.all()
    np.testing.assert_allclose(result.lar[0], [-13.125, 0.0, 0.0], atol=1e-3)
    at_least(0.6, result.lar_correct[0],
             {"exact": result.exact.round(2).tolist(), "lar": result.lar.round(2).tolist()})
