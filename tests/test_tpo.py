"""The `TPO` model (tpo.algo.tpo), SB3-style: learn, predict, evaluate, save and load."""

import json

import jax
import numpy as np
import pytest

from tpo.algo import TPO, TPOConfig
from tpo.errors import TPOError

CONFIG = TPOConfig(num_envs=8, num_steps=32)
RESTRICTED = TPOConfig(num_envs=8, num_steps=32, constraint="restriction", completion=True)


@pytest.fixture(scope="module")
def model():
    return TPO("small", "M>A>G", slack=[100, 0], config=CONFIG, seed=3).learn(3 * 8 * 32 * 4)


def test_learn_reports_progress_per_chunk():
    seen = []
    TPO("small", "goal", config=CONFIG).learn(8 * 32 * 5, chunk_updates=2,
                                              callback=lambda m, n: seen.append(
                                                  (n, m["phase"].shape)))
    assert seen == [(2, (2,)), (4, (2,)), (5, (1,))]


def test_save_and_load_give_the_same_policy(model, tmp_path):
    path = model.save(tmp_path / "run")
    meta = json.loads((path / "model.json").read_text())
    assert meta["dag"] == "monitor>avoid>goal" and meta["slack"] == [100.0, 0.0]
    loaded = TPO.load(path)
    obs = model.eval_env.tabular_observations()
    assert np.array_equal(model.predict(obs), loaded.predict(obs))
    assert loaded.num_timesteps == model.num_timesteps == 3 * 8 * 32 * 4
    assert loaded.evaluate(episodes=4)["exact"] == model.evaluate(episodes=4)["exact"]


def test_a_model_saved_before_the_margin_existed_loads_without_it(model, tmp_path):
    """tpo 0.2 penalised from the slack itself and had no tie-break: its saved models
    keep doing so, and a new config without the keys gets today's defaults."""
    assert model.config.margin == 0.15
    path = model.save(tmp_path / "run")
    meta = json.loads((path / "model.json").read_text())
    del meta["config"]["margin"], meta["config"]["tie_break"]
    (path / "model.json").write_text(json.dumps({**meta, "format": 7}))  # as 0.2 wrote it
    loaded = TPO.load(path).config
    assert (loaded.margin, loaded.tie_break) == (0.0, 0.0)
    assert (TPOConfig.from_dict({}).margin, TPOConfig.from_dict({}).tie_break) == (0.15, 0.1)


def test_a_fan_saved_before_the_roots_completion_loads_with_its_three_phases(tmp_path):
    old = TPOConfig(num_envs=8, num_steps=32, roots_completion=False)
    model = TPO("small", "A>G, M>G", slack=5, config=old).learn(3 * 8 * 32)
    path = model.save(tmp_path / "run")
    meta = json.loads((path / "model.json").read_text())
    del meta["config"]["roots_completion"]  # as tpo wrote it before the field
    (path / "model.json").write_text(json.dumps({**meta, "format": 7}))
    loaded = TPO.load(path)
    assert loaded.phases == ("avoid", "monitor", "goal")
    obs = model.eval_env.tabular_observations()
    assert np.array_equal(model.predict(obs), loaded.predict(obs))
    assert TPO("small", "A>G, M>G", config=CONFIG).phases[3] == "monitor (under avoid)"


def test_a_restricted_model_acts_within_its_last_phase_and_round_trips(tmp_path):
    model = TPO("small", "A>G", slack=0, config=RESTRICTED, seed=2).learn(3 * 8 * 32 * 3)
    trainer = model.trainer
    assert trainer.problem.phase_names == ("avoid", "goal", "avoid (completion)")
    obs = model.eval_env.tabular_observations()
    acting = trainer.acting(model.state, trainer.slack_array())
    assert int(acting.phase) == 2
    allowed = np.asarray(trainer.form.allowed(trainer.critics, acting, obs))
    actions = model.predict(obs)
    assert allowed[np.arange(len(obs)), actions].all()
    loaded = TPO.load(model.save(tmp_path / "run"))
    assert np.array_equal(loaded.predict(obs), actions)
    assert loaded.evaluate(episodes=2)["exact"] == model.evaluate(episodes=2)["exact"]


def test_save_refuses_to_overwrite(model, tmp_path):
    path = model.save(tmp_path / "run")
    before = (path / "state.msgpack").read_bytes()
    with pytest.raises(TPOError, match="exists; pass overwrite=True"):
        model.save(path)
    model.save(path, overwrite=True)
    assert (path / "state.msgpack").read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["run"]  # no temporary left behind


@pytest.mark.parametrize("config", [CONFIG, RESTRICTED], ids=["penalty", "restriction"])
def test_a_model_saved_mid_training_resumes_to_the_same_state(tmp_path, config):
    total = 8 * 32 * 15  # 15 updates: whole phases of 3 (penalty) and 5 (completion)
    whole = TPO("small", "M>A>G", slack=[100, 0], config=config, seed=1).learn(
        total, chunk_updates=2)
    part = TPO("small", "M>A>G", slack=[100, 0], config=config, seed=1)
    part.learn(total, chunk_updates=2, callback=lambda m, n: n < 3)  # stops after 4
    assert int(part.state.update) == 4 and not part.finished
    resumed = TPO.load(part.save(tmp_path / "ckpt")).resume(chunk_updates=2)
    assert resumed.finished and resumed.num_timesteps == whole.num_timesteps == total
    same = jax.tree.map(lambda a, b: bool(np.array_equal(a, b)),
                        jax.tree.leaves(whole.state.params), jax.tree.leaves(resumed.state.params))
    assert all(same)


def test_evaluate_reports_mc_exact_and_lar(model):
    result = model.evaluate(episodes=8)
    assert set(result) == {"mc", "exact", "lar", "lar_correct", "strict", "same_values", "outside"}
    assert set(result["lar"]["floors"]) == {"monitor", "avoid"}
    for kind in ("greedy", "stochastic"):
        assert set(result["mc"][kind]["undiscounted"]) == {"goal", "avoid", "monitor"}
        assert set(result["exact"][kind]) == {"goal", "avoid", "monitor"}
    assert result["lar"]["policy_values"]["goal"] == pytest.approx(-(1 - 0.99**14) / 0.01)
    greedy = result["mc"]["greedy"]
    length = greedy["length"]  # the same every episode: greedy policy, deterministic env
    assert greedy["discounted"]["goal"]["std"] == pytest.approx(0.0, abs=1e-5)
    assert greedy["undiscounted"]["goal"]["mean"] == -length  # goal pays -1 per step
    assert greedy["discounted"]["goal"]["mean"] == pytest.approx(-(1 - 0.99**length) / 0.01,
                                                                 rel=1e-5)


def test_predict_checks_shapes_and_needs_parameters(model):
    # small's observation: 8 rows + 13 columns + 4 walls + 2 flags + 44 free cells
    with pytest.raises(TPOError, match=r"expected \[\.\.\., 71\]"):
        model.predict(np.zeros(3))
    with pytest.raises(TPOError, match=r"call learn\(\) or TPO\.load\(\)"):
        TPO("small", "goal").predict(np.zeros(71))
    assert model.predict(np.zeros(71)).shape == ()


def test_load_rejects_a_folder_that_is_not_a_model(tmp_path):
    with pytest.raises(TPOError, match="is not a saved tpo model"):
        TPO.load(tmp_path)


def test_non_finite_training_stops_naming_phase_and_update_and_keeps_the_good_state():
    from tpo.algo import NonFiniteError

    model = TPO("small", "M>A>G", slack=[100, 0], config=CONFIG)
    model.learn(8 * 32 * 6, chunk_updates=2, callback=lambda m, n: n < 2)  # 2 per phase
    poisoned = jax.tree.map(lambda x: x * np.nan, model.state.params["critics"])
    model.state = model.state.replace(params={**model.state.params, "critics": poisoned})
    with pytest.raises(NonFiniteError, match=r"non-finite policy_loss in phase 'avoid' at "
                                             r"update 3; the last good state \(update 2\)"):
        model.resume(chunk_updates=2)
    assert int(model.state.update) == 2


def test_a_population_trains_its_members_at_once_and_answers_with_one(tmp_path):
    total = 8 * 32 * 12  # 4 updates per phase
    seen = []

    def callback(metrics, done):
        seen.append((done, model.stacked, metrics["phase"].shape))
        if done == 4:
            model.save(tmp_path / "mid")

    model = TPO("small", "M>A>G", slack=[100, 0], config=CONFIG, seed=5, population=3)
    model.learn(total, callback, chunk_updates=4)
    # While training the state holds 3 members (metrics: their mean per update); the
    # chunk that ends the run answers with one of them.
    assert seen == [(4, True, (4,)), (8, True, (4,)), (12, False, (4,))]
    assert np.ndim(model.state.update) == 0 and model.finished
    assert model.num_timesteps == total  # steps of each member
    mid = TPO.load(tmp_path / "mid")
    assert mid.population == 3 and mid.stacked and mid.updates_done == 4
    # odd members learn the second design; the third sees the cell's one-hot alone
    assert mid.state.design.tolist() == [0, 1, 0] and mid.state.view.tolist() == [0, 0, 1]
    assert mid.predict(np.zeros(mid.env.obs_shape)).shape == ()  # its first member acts
    resumed = mid.resume(chunk_updates=4)
    same = jax.tree.map(lambda a, b: bool(np.array_equal(a, b)),
                        jax.tree.leaves(model.state.params),
                        jax.tree.leaves(resumed.state.params))
    assert all(same)
    saved = TPO.load(model.save(tmp_path / "done"))
    assert saved.population == 3 and not saved.stacked
    assert json.loads((tmp_path / "done" / "model.json").read_text())["population"] == 3


def test_an_unmixed_population_learns_one_design():
    config = TPOConfig(num_envs=8, num_steps=32, mixed_population=False)
    model = TPO("small", "M>A>G", slack=[100, 0], config=config, population=2)
    model.learn(8 * 32 * 12, lambda m, n: False, chunk_updates=4)
    assert model.state.design.tolist() == [0, 0] and model.state.view.tolist() == [0, 0]


@pytest.mark.parametrize("bad", [0, 65, True, 2.0])
def test_a_bad_population_is_one_line(bad):
    with pytest.raises(TPOError, match="population must be an integer from 1 to 64"):
        TPO("small", "goal", config=CONFIG, population=bad)


def test_model_json_s_population_is_checked_and_a_model_without_it_is_one_learner(
        model, tmp_path):
    path = model.save(tmp_path / "run")
    meta = json.loads((path / "model.json").read_text())
    assert meta["population"] == 1
    del meta["population"]  # saved before populations
    (path / "model.json").write_text(json.dumps(meta))
    assert TPO.load(path).population == 1
    for bad in (0, True, "4"):
        (path / "model.json").write_text(json.dumps({**meta, "population": bad}))
        with pytest.raises(TPOError, match=r"model\.json: population must be an integer >= 1"):
            TPO.load(path)


def test_a_continuous_robot_s_population_answers_with_one_member():
    from tpo.envs import ContinuousNav, load_map

    env = ContinuousNav(load_map("small"), random_start=True)
    config = TPOConfig.from_profile("continuous", "discretized", num_envs=8, num_steps=32)
    model = TPO(env, "M>A>G", slack=[100, 0], config=config, population=2).learn(8 * 32 * 6)
    assert model.finished and not model.stacked
    assert model.predict(np.zeros(env.obs_shape)).shape == (2,)  # a velocity
