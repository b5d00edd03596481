"""Gymnasium / MO-Gymnasium interoperability, run the way MO-Gymnasium's own suite runs."""

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence
from mo_gymnasium.wrappers import LinearReward, MORecordEpisodeStatistics

import tpo.envs  # noqa: F401  (registers the ids)
from tpo.envs import bundled_maps

IDS = [f"tpo/{kind}-{name}-v0" for name in bundled_maps()
       for kind in ("GridNav", "ContinuousNav", "ContinuousNavHeading")]


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        # check_env warns that an MO env's reward is a vector, as it does for MO-Gymnasium's.
        warnings.filterwarnings("ignore", message=".*reward returned by `step\\(\\)` must be")
        yield


@pytest.mark.parametrize("env_id", IDS)
def test_check_env_with_render(env_id):
    check_env(gym.make(env_id, render_mode="rgb_array").unwrapped)


@pytest.mark.parametrize("env_id", IDS)
def test_reward_space_and_bounds(env_id):
    env = LinearReward(gym.make(env_id), weight=np.array([1, 1, 1], np.float32))
    unwrapped = env.unwrapped
    assert unwrapped.reward_dim == 3 and unwrapped.reward_space.shape == (3,)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(300):
        _, scalar, terminated, truncated, info = env.step(env.action_space.sample())
        assert unwrapped.reward_space.contains(info["vector_reward"])
        assert scalar == pytest.approx(info["vector_reward"].sum())
        if terminated or truncated:
            env.reset()


@pytest.mark.parametrize("env_id", IDS)
def test_pickle_round_trip(env_id):
    env = LinearReward(gym.make(env_id))
    copy = pickle.loads(pickle.dumps(env))
    data_equivalence(env.reset(seed=1), copy.reset(seed=1))
    action = env.action_space.sample()
    data_equivalence(env.step(action), copy.step(action))


@pytest.mark.parametrize("env_id", IDS)
def test_same_seed_same_rollout(env_id):
    a, b = gym.make(env_id, **_noisy(env_id)), gym.make(env_id, **_noisy(env_id))
    a.action_space.seed(0)
    for x, y in zip(a.reset(seed=3), b.reset(seed=3), strict=True):
        data_equivalence(x, y)
    for _ in range(50):
        action = a.action_space.sample()
        data_equivalence(a.step(action), b.step(action))


def _noisy(env_id: str) -> dict:
    return {"slip": 0.3} if "GridNav" in env_id else {"noise": 0.1}


def test_episode_statistics_wrapper_reports_vector_returns():
    env = MORecordEpisodeStatistics(gym.make("tpo/GridNav-home-v0", max_steps=30), gamma=0.9)
    env.reset(seed=0)
    for _ in range(30):
        *_, terminated, truncated, info = env.step(0)  # up: bumps in the bedroom after 2 steps
    assert truncated and not terminated
    episode = info["episode"]
    assert episode["l"] == 30
    assert np.allclose(episode["r"], [-30, -28, -28])  # two free moves, then 28 bumps


def test_rgb_render_draws_the_map_and_the_robot():
    env = gym.make("tpo/GridNav-home-v0", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (11 * 12, 30 * 12, 3) and frame.dtype == np.uint8
    r, c = env.unwrapped.navmap.start
    assert (frame[r * 12 + 6, c * 12 + 6] == [20, 20, 20]).all()  # the robot at the start
    env.step(3)
    moved = env.render()
    assert (moved[r * 12 + 6, (c + 1) * 12 + 6] == [20, 20, 20]).all()


def test_gym_kwargs_reach_the_env():
    env = gym.make("tpo/GridNav-home-v0", observation="coords", slip=0.1)
    assert env.observation_space.shape == (8,)
    cont = gym.make("tpo/ContinuousNav-home-v0", n_beams=16)
    assert cont.observation_space.shape == (4 + 16 + 11 + 30,)  # + home's rows and columns
    cont = gym.make("tpo/ContinuousNav-home-v0", n_beams=16, observation="coords")
    assert cont.observation_space.shape == (20,)
    assert isinstance(gym.make("tpo/ContinuousNavHeading-home-v0").action_space,
                      gym.spaces.Discrete)


def test_step_before_reset_is_an_error():
    env = gym.make("tpo/GridNav-home-v0", disable_env_checker=True).unwrapped
    with pytest.raises(gym.error.ResetNeeded):
        env.step(0)
