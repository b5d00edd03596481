"""Gymnasium envs that break TPO's contract, each in one way; importing this module
registers them as ``NAME-v0`` (so ``tpo train --env badenvs:NAME-v0``)."""

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class TwoRewards(gym.Env):
    """A well-formed env: 2-D Box observation, 2 actions, reward vector of width 2."""

    observation_space = spaces.Box(0.0, 10.0, (2,), np.float32)
    action_space = spaces.Discrete(2)
    reward_space = spaces.Box(-1.0, 1.0, (2,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self.observe(), {}

    def observe(self):
        return np.array([self.t, 0.0], np.float32)

    def reward(self):
        return np.array([1.0, -1.0], np.float32)

    def step(self, action):
        self.t += 1
        return self.observe(), self.reward(), self.t >= 5, False, {}


class NanReward(TwoRewards):
    """The second component turns NaN at the third step."""

    def reward(self):
        return np.array([1.0, np.nan if self.t == 3 else -1.0], np.float32)


class WideReward(TwoRewards):
    """Declares two reward components, returns three."""

    def reward(self):
        return np.zeros(3, np.float32)


class GrowingObservation(TwoRewards):
    """The observation gains a component at the second step."""

    def observe(self):
        return np.zeros(2 if self.t < 2 else 3, np.float32)


class SequenceObservation(TwoRewards):
    observation_space = spaces.Sequence(spaces.Discrete(3))


class MultiDiscreteAction(TwoRewards):
    action_space = spaces.MultiDiscrete([2, 2])


for _cls in (NanReward, WideReward, GrowingObservation, SequenceObservation, MultiDiscreteAction):
    if f"{_cls.__name__}-v0" not in gym.registry:
        gym.register(f"{_cls.__name__}-v0", entry_point=_cls,
                     disable_env_checker=True)
