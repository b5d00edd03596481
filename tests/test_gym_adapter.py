"""TPO on Gymnasium / MO-Gymnasium envs stepped on the host (issue 6)."""

import json
import os
import stat

import gymnasium as gym
import numpy as np
import pytest

from tpo.algo import TPO, TPOConfig
from tpo.algo.config import ConfigError
from tpo.atomic import UMASK
from tpo.envs.gym_adapter import EnvError, HostEnv
from tpo.errors import TPOError

SMALL = TPOConfig(num_envs=4, num_steps=16)
STEPS_SLIDER = 40_000  # 10 of 10 seeds learn the push (measured)


class Line(gym.Env):
    """Walk right along 5 cells; rewards [reach (-1 per step), left (+1 per left move)]."""

    def __init__(self, reward_fn=None, obs_space=None, action_space=None, grow=False):
        self.observation_space = obs_space or gym.spaces.Box(0, 4, (1,), np.float32)
        self.action_space = action_space or gym.spaces.Discrete(2)
        self.reward_space = gym.spaces.Box(np.array([-1, 0]), np.array([-1, 1]), (2,))
        self.reward_fn, self.grow, self.pos, self.t = reward_fn, grow, 0, 0

    def _obs(self):
        if isinstance(self.observation_space, gym.spaces.Discrete):
            return self.pos
        size = 1 + (self.t if self.grow else 0)
        return np.full(size, self.pos, np.float32)

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.pos, self.t = 0, 0
        return self._obs(), {}

    def step(self, action):
        self.t += 1
        self.pos = min(4, self.pos + 1) if action == 1 else max(0, self.pos - 1)
        reward = np.array([-1.0, float(action == 0)])
        if self.reward_fn is not None:
            reward = self.reward_fn(self.t, reward)
        return self._obs(), reward, self.pos == 4, self.t >= 20, {}


def make_line(**kwargs):
    return lambda: Line(**kwargs)


@pytest.mark.parametrize(("env", "objectives", "message"), [
    ("gym:CartPole-v1", ["a"], "has a scalar reward"),
    ("mo-gymnasium:deep-sea-treasure-v0", ["a", "b", "c"],
     "returns 2 reward components but 3 objectives are named"),
    (make_line(obs_space=gym.spaces.Sequence(gym.spaces.Discrete(2))), ["reach", "left"],
     "supports Box, Discrete and what gymnasium.spaces.flatten flattens"),
    (make_line(obs_space=gym.spaces.Dict({"x": gym.spaces.Sequence(gym.spaces.Discrete(2))})),
     ["reach", "left"], "cannot be flattened"),
    (make_line(action_space=gym.spaces.MultiDiscrete([2, 2])), ["reach", "left"],
     "supports Discrete and 1-D Box actions"),
    ("deep-sea-treasure-v0", ["a", "b"], "a Gymnasium env is named PACKAGE:ENV_ID"),
    ("mo-gymnasium:", ["a", "b"], "write PACKAGE:ENV_ID"),
    ("no-such-package:Foo-v0", ["a", "b"], "cannot import 'no-such-package'"),
    ("gym:NoSuchEnv-v0", ["a", "b"], "unknown env id 'NoSuchEnv-v0'"),
])
def test_unfit_envs_are_refused_before_training(env, objectives, message):
    with pytest.raises(TPOError, match=message):
        TPO(env, objectives[0], objectives=objectives, config=SMALL)


def test_objectives_must_be_named():
    with pytest.raises(TPOError, match="objectives="):
        TPO("mo-gymnasium:deep-sea-treasure-v0", "treasure")


def test_non_finite_reward_stops_training_naming_step_and_objective():
    nan_at_3 = make_line(reward_fn=lambda t, r: np.array([r[0], np.nan]) if t == 3 else r)
    model = TPO(nan_at_3, "left>reach", objectives=["reach", "left"], config=SMALL)
    with pytest.raises(EnvError, match=r"Line returned a non-finite reward nan for "
                                       r"objective 'left' at update 1, step 3 of its rollout"):
        model.learn(SMALL.batch_size * 2)


def test_changing_observation_shape_is_an_error():
    model = TPO(make_line(grow=True), "reach", objectives=["reach", "left"], config=SMALL)
    with pytest.raises(EnvError, match=r"observation shape changed from \(1,\) to \(2,\)"):
        model.learn(SMALL.batch_size)


def test_discrete_observations_are_one_hot_and_episodes_auto_reset():
    line = HostEnv(make_line(obs_space=gym.spaces.Discrete(5)), ["reach", "left"], 2)
    assert line.observation_onehots == ((0, 5),)  # the network reads it as one row
    assert HostEnv(make_line(), ["reach", "left"], 1).observation_onehots == ()
    obs = line.reset(seed=0)
    assert obs.shape == (2, 5) and (obs[:, 0] == 1).all()
    for _ in range(3):
        line.step(np.array([1, 0]))
    obs, reward, term, trunc, final = line.step(np.array([1, 0]))
    assert term.tolist() == [True, False] and not trunc.any()  # env 0 reached cell 4
    assert final[0].argmax() == 4 and obs[0].argmax() == 0  # true final obs; then reset
    np.testing.assert_array_equal(reward, [[-1, 0], [-1, 1]])


def test_plain_ppo_and_tpo_learn_a_host_env_and_save_and_load(tmp_path):
    model = TPO("mo-gymnasium:deep-sea-treasure-v0", "treasure>time", slack=0.0,
                objectives=["treasure", "time"], config=SMALL, seed=0)
    model.learn(SMALL.batch_size * 4)
    result = model.evaluate(episodes=4)
    assert set(result["mc"]["greedy"]["undiscounted"]) == {"treasure", "time"}
    # judged exactly on the env's stepped model: LAR's treasure 23.7 in 19 steps
    assert result["lar"]["values"] == pytest.approx(
        {"treasure": 23.7 * 0.99**18, "time": -(1 - 0.99**19) / 0.01}, rel=1e-7)
    assert {"lar_correct", "strict", "same_values"} <= set(result)
    loaded = TPO.load(model.save(tmp_path / "dst"))
    obs = np.array([0, 0], np.int32)
    assert loaded.predict(obs) == model.predict(obs)
    assert loaded.resume().finished


def test_a_host_population_steps_its_own_copies_answers_with_one_and_resumes(tmp_path):
    """Members are stacked, each stepping 4 of the env's 2 x 4 copies; the run's end
    answers with one member; a model saved mid-run resumes to its end."""
    seen = []

    def callback(metrics, done):
        seen.append((done, model.stacked, metrics["phase"].shape))
        if done == 2:
            model.save(tmp_path / "mid")

    model = TPO("mo-gymnasium:deep-sea-treasure-v0", "treasure>time", slack=0.0,
                objectives=["treasure", "time"], config=SMALL, seed=3, population=2)
    assert model.env.num_envs == 2 * SMALL.num_envs
    model.learn(SMALL.batch_size * 4, callback, chunk_updates=2)
    assert seen == [(2, True, (2,)), (4, False, (2,))]
    assert model.finished and np.ndim(model.state.update) == 0
    assert model.state.obs.shape == (SMALL.num_envs, 2)  # the answering member's copies
    mid = TPO.load(tmp_path / "mid")
    assert mid.population == 2 and mid.stacked and mid.updates_done == 2
    assert mid.state.obs.shape == (2, SMALL.num_envs, 2)
    resumed = mid.resume(chunk_updates=2)
    assert resumed.finished and not resumed.stacked and resumed.num_timesteps == \
        model.num_timesteps
    assert resumed.predict(np.array([[0, 0], [1, 0], [2, 1]], np.int32)).shape == (3,)


def test_cli_trains_a_gymnasium_env_into_a_run_directory(tmp_path, capsys):
    from tpo.cli.main import main

    out = tmp_path / "dst"
    assert main(["train", "--env", "mo-gymnasium:deep-sea-treasure-v0", "--objectives",
                 "treasure,time", "--dag", "treasure>time", "--slack", "0", "--steps", "4096",
                 "--out", str(out), "--quiet", "--episodes", "2"]) == 0
    result = json.loads((out / "eval.json").read_text())  # judged on the stepped model
    assert set(result) == {"mc", "exact", "lar", "lar_correct", "strict", "same_values",
                           "outside"}
    assert set(result["mc"]["greedy"]["discounted"]) == {"treasure", "time"}
    assert (out / "model" / "model.json").exists() and (out / "metrics.csv").exists()
    capsys.readouterr()
    assert main(["train", "--env", "mo-gymnasium:deep-sea-treasure-v0", "--dag", "treasure",
                 "--out", str(tmp_path / "x")]) == 2
    assert "name the reward components of env" in capsys.readouterr().err


def test_a_sync_vector_env_is_stepped_copy_by_copy_and_sets_num_envs():
    from mo_gymnasium.wrappers.vector import MOSyncVectorEnv

    envs = MOSyncVectorEnv([make_line() for _ in range(2)])
    model = TPO(envs, "left>reach", objectives=["reach", "left"], config=SMALL)
    assert model.config.num_envs == 2 and model.env.envs == list(envs.envs)
    model.learn(model.config.batch_size * 2)
    assert model.finished and model.num_timesteps == 2 * 2 * SMALL.num_steps


def test_a_vector_env_whose_copies_are_out_of_reach_is_refused():
    envs = gym.vector.AsyncVectorEnv([make_line() for _ in range(2)])
    try:
        with pytest.raises(TPOError, match="takes a SyncVectorEnv"):
            TPO(envs, "left>reach", objectives=["reach", "left"], config=SMALL)
    finally:
        envs.close()


def test_models_of_a_made_env_or_a_vector_env_save_and_load_by_registered_name(tmp_path):
    from mo_gymnasium.wrappers.vector import MOSyncVectorEnv

    made = gym.make("deep-sea-treasure-v0")
    vector = MOSyncVectorEnv([lambda: gym.make("deep-sea-treasure-v0") for _ in range(2)])
    for i, env in enumerate((made, vector)):
        model = TPO(env, "treasure>time", objectives=["treasure", "time"], config=SMALL)
        model.learn(SMALL.batch_size * 2)
        path = model.save(tmp_path / f"m{i}")
        assert json.loads((path / "model.json").read_text())["env"]["id"] == \
            "mo_gymnasium:deep-sea-treasure-v0"
        loaded = TPO.load(path)
        assert loaded.config.num_envs == model.config.num_envs
        assert loaded.predict(np.array([0, 0])) == model.predict(np.array([0, 0]))
        assert stat.S_IMODE(os.stat(path).st_mode) == 0o777 & ~UMASK


class Slider(gym.Env):
    """A point on [0, 1] pushed by a continuous action in [-1, 1] (x += 0.1 a) until it
    reaches 1; rewards [distance (-(1 - x) after the move), effort (-a^2)]."""

    observation_space = gym.spaces.Box(0.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    reward_space = gym.spaces.Box(np.array([-1.0, -1.0]), np.array([0.0, 0.0]))

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.t = 0.0, 0
        return np.array([self.x], np.float32), {}

    def step(self, action):
        a = float(np.clip(action[0], -1.0, 1.0))
        self.x, self.t = min(1.0, max(0.0, self.x + 0.1 * a)), self.t + 1
        reward = np.array([self.x - 1.0, -a * a])
        return np.array([self.x], np.float32), reward, self.x >= 1.0, self.t >= 50, {}


class Unbounded(Slider):
    action_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)


def test_a_box_without_bounds_takes_a_gaussian_and_cannot_be_discretized():
    assert TPO(Slider, "distance", objectives=["distance", "effort"]).config.action_bins == 5
    model = TPO(Unbounded, "distance", objectives=["distance", "effort"])
    assert model.config == TPOConfig.from_profile("grid", "gaussian")
    with pytest.raises(ConfigError, match="action_bins needs an action space of finite bounds"):
        TPO(Unbounded, "distance", objectives=["distance", "effort"],
            config=TPOConfig(action_bins=3)).learn(10**4)


@pytest.mark.slow
def test_plain_ppo_learns_a_continuous_action_host_env(seeds, at_least):
    config = TPOConfig(num_envs=8, num_steps=32, num_minibatches=2)
    outcomes, learned = [], []
    for seed in seeds(5):
        model = TPO(Slider, "distance", objectives=["distance", "effort"], config=config,
                    seed=seed)
        model.learn(STEPS_SLIDER)
        length = model.evaluate(episodes=8)["mc"]["greedy"]["length"]
        push = model.predict(np.array([0.5], np.float32)).item()
        learned.append((length, round(push, 3)))
        # a full push takes 10 steps; doing nothing, 50
        outcomes.append(length <= 12 and push > 0.8)
    at_least(0.8, outcomes, {"(length, push at 0.5)": learned})
