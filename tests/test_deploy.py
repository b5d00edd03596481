"""Exported policies (tpo.algo.export, tpo export) and their NumPy runner
(tpo.deploy): the same actions and distribution parameters as the JAX policy,
without JAX."""

import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import onnxruntime as ort
import pytest

from tpo.algo import TPO, TPOConfig
from tpo.algo.distributions import DiagGaussian
from tpo.algo.export import export_policy
from tpo.cli.main import main
from tpo.deploy import DeployError, load_policy
from tpo.envs import load_map
from tpo.envs.continuous import ContinuousNav
from tpo.envs.grid import GridNav
from tpo.errors import TPOError

CONFIG = TPOConfig(num_envs=4, num_steps=16)


def trained(env, **config):
    model = TPO(env, "M>A>G", [0, 0], TPOConfig(num_envs=4, num_steps=16, **config), seed=0)
    return model.learn(3 * 64 * 2)


@pytest.fixture(scope="module")
def grid_model():
    return trained(GridNav(load_map("small")))


@pytest.fixture(scope="module", params=["velocity", "velocity-binned", "heading"])
def continuous_model(request):
    action, _, binned = request.param.partition("-")
    return trained(ContinuousNav(load_map("small"), action=action),
                   action_bins=3 if binned else 0)


def exported(model, tmp_path):
    npz = export_policy(model, tmp_path / "policy.npz", "npz")
    onnx = export_policy(model, tmp_path / "policy.onnx", "onnx")
    return load_policy(npz), ort.InferenceSession(str(onnx))


def jax_outputs(model, obs):
    pi = model.trainer.policy(model.trainer.acting(model.state, model.trainer.slack_array()),
                              jnp.asarray(obs))
    head = pi.mean if isinstance(pi, DiagGaussian) else pi.logits
    return np.asarray(pi.mode()), np.asarray(head).reshape(len(obs), -1)


def test_grid_policy_acts_alike_on_every_tabular_state(grid_model, tmp_path):
    policy, session = exported(grid_model, tmp_path)
    obs = np.asarray(grid_model.eval_env.tabular_observations())
    action, logits = jax_outputs(grid_model, obs)
    np.testing.assert_array_equal(policy.act(obs), grid_model.predict(obs))
    np.testing.assert_array_equal(policy.act(obs), action)
    np.testing.assert_allclose(policy.forward(obs), logits, atol=1e-5)
    onnx_action, onnx_logits = session.run(["action", "logits"], {"obs": obs})
    np.testing.assert_array_equal(onnx_action, action)
    np.testing.assert_allclose(onnx_logits, logits, atol=1e-5)
    # The observer: a cell's observation is the env's own.
    grid = grid_model.eval_env.tabular(0.99)
    for state in (0, len(grid.cells) // 2, len(grid.cells) - 1):
        np.testing.assert_array_equal(policy.observer.observe(cell=grid.cells[state]),
                                      obs[state])


def test_continuous_policy_acts_alike_on_10000_observations(continuous_model, tmp_path):
    model = continuous_model
    policy, session = exported(model, tmp_path)
    env = model.eval_env
    free = np.argwhere(~env.navmap.walls)
    rng = np.random.default_rng(0)
    positions = (free[rng.integers(len(free), size=10_000)]
                 + rng.uniform(0.01, 0.99, (10_000, 2))).astype(np.float32)
    state = jax.vmap(lambda p: env.reset(jax.random.key(0), env.params)[1].replace(pos=p))(
        jnp.asarray(positions))
    obs = np.asarray(jax.vmap(env.observe, in_axes=(0, None))(state, env.params))
    for i in range(0, 10_000, 997):  # the NumPy observer computes the env's observation
        # (to an ulp: XLA may divide by multiplying with the reciprocal)
        np.testing.assert_allclose(policy.observer.observe(position=positions[i]), obs[i],
                                   rtol=0, atol=1e-6)
    action, head = jax_outputs(model, obs)
    np.testing.assert_allclose(policy.forward(obs), head, atol=1e-5)
    gaussian = policy.log_std is not None
    onnx_action, onnx_head = session.run(["action", "mean" if gaussian else "logits"],
                                         {"obs": obs})
    np.testing.assert_allclose(onnx_head, head, atol=1e-5)
    if not gaussian:  # a most likely action: an index, or each dimension's value
        np.testing.assert_array_equal(policy.act(obs), action)
        np.testing.assert_array_equal(onnx_action, action)
        np.testing.assert_array_equal(policy.act(obs), model.predict(obs))
    else:
        np.testing.assert_allclose(policy.act(obs), action, atol=1e-5)
        np.testing.assert_allclose(onnx_action, action, atol=1e-5)
        log_std = session.run(["log_std"], {"obs": obs[:1]})[0]
        np.testing.assert_array_equal(log_std, policy.log_std)


def test_the_npz_runs_where_jax_cannot_be_imported(grid_model, tmp_path):
    path = export_policy(grid_model, tmp_path / "policy.npz", "npz")
    code = ("import sys\n"
            "for name in ('jax', 'jaxlib', 'flax', 'optax', 'gymnasium', 'scipy', "
            "'matplotlib', 'tomli_w'):\n"
            "    sys.modules[name] = None  # importing them now fails\n"
            "from tpo.deploy import load_policy\n"
            f"policy = load_policy({str(path)!r})\n"
            "print(int(policy.act(policy.observer.observe(cell=(1, 1)))))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    obs = grid_model.eval_env.tabular_observations()
    cell = grid_model.eval_env.tabular(0.99).index[1, 1]
    assert int(done.stdout) == int(grid_model.predict(obs[cell]))


def test_metadata_says_what_the_policy_expects(grid_model, tmp_path):
    policy, session = exported(grid_model, tmp_path)
    meta = policy.meta
    assert meta["dag"] == grid_model.graph.spec and meta["slack"] == [0.0, 0.0]
    assert meta["objectives"] == ["goal", "avoid", "monitor"] and meta["gamma"] == 0.99
    assert meta["observation"]["kind"] == "factored+onehot"
    assert meta["action"]["meanings"] == ["up", "down", "left", "right"]
    assert meta["map"]["name"] == "small" and len(meta["map"]["sha256"]) == 64
    assert json.loads(session.get_modelmeta().custom_metadata_map["tpo"]) == meta


def test_export_replaces_nothing_and_refuses_what_it_cannot_export(grid_model, tmp_path):
    path = tmp_path / "mine.npz"
    path.write_text("a user's file")
    with pytest.raises(TPOError, match="exists"):
        export_policy(grid_model, path, "npz")
    assert path.read_text() == "a user's file"
    with pytest.raises(TPOError, match="unknown export format"):
        export_policy(grid_model, tmp_path / "p.x", "tflite")
    restricted = trained(GridNav(load_map("small")), constraint="restriction")
    with pytest.raises(TPOError, match="restriction-form"):
        export_policy(restricted, tmp_path / "r.npz", "npz")


def test_bad_files_and_observations_get_one_clear_error(grid_model, tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(DeployError, match="is not an exported tpo policy"):
        load_policy(bad)
    path = export_policy(grid_model, tmp_path / "p.npz", "npz")
    blob = path.read_bytes()
    for name, damaged in (("empty", b""), ("half", blob[:len(blob) // 2]),
                          ("short", blob[:-10])):
        (tmp_path / name).write_bytes(damaged)
        with pytest.raises(DeployError, match="is not an exported tpo policy"):
            load_policy(tmp_path / name)
    with np.load(path) as data:  # meta that disagrees with the arrays
        arrays = dict(data)
    meta = json.loads(str(arrays["meta"]))
    for change in ({"hidden": [64]}, {"hidden": 3}, {"activation": ["tanh"]},
                   {"observation": None}, {"action": {"kind": "continuous"}}):
        np.savez(tmp_path / "edited.npz", **{**arrays,
                                             "meta": np.array(json.dumps({**meta, **change}))})
        with pytest.raises(DeployError, match="damaged or not tpo's"):
            load_policy(tmp_path / "edited.npz")
    policy = load_policy(path)
    with pytest.raises(DeployError, match="off the"):
        policy.observer.observe(cell=(99, 0))
    for cell in ((-0.5, 2), (np.nan, 1), 5, (1, 2, 3)):
        with pytest.raises(DeployError, match="cell must be two integers"):
            policy.observer.observe(cell=cell)
    obs = policy.observer.observe(cell=(1, 1))
    obs[0] = 99.0  # a copy: the observer's table is untouched
    assert policy.observer.observe(cell=(1, 1))[0] != 99.0
    with pytest.raises(DeployError, match="an observation has"):
        policy.act(np.zeros(3))
    for bad in (np.full(policy.obs_size, np.nan), np.full(policy.obs_size, np.inf)):
        with pytest.raises(DeployError, match="finite"):
            policy.act(bad)


def test_continuous_readings_are_checked(continuous_model, tmp_path):
    policy = load_policy(export_policy(continuous_model, tmp_path / "p.npz", "npz"))
    observer = policy.observer
    with pytest.raises(DeployError, match="finite"):
        observer.observe(position=(2.5, 2.5), ranges=[np.nan] * 8)
    with pytest.raises(DeployError, match=">= 0"):
        observer.observe(position=(2.5, 2.5), ranges=[-1.0] * 8)
    with pytest.raises(DeployError, match="position must be"):
        observer.observe(position=(np.inf, 1.0))
    h = observer.walls.shape[0]
    edge = observer.observe(position=(h - 1e-7, 1.5))  # rounds onto the edge in float32
    assert np.isfinite(edge).all() and edge[0] < 1.0


def test_export_and_render_from_the_command_line(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["train", "--map", "small", "--dag", "A>G", "--steps", "4096", "--num-envs",
                 "4", "--num-steps", "16", "--episodes", "2", "--quiet", "--out",
                 str(run)]) == 0
    assert main(["export", str(run), "--format", "npz", "--out", str(tmp_path / "p.npz")]) == 0
    assert load_policy(tmp_path / "p.npz").meta["dag"] == "avoid>goal"
    assert main(["export", str(run), "--format", "onnx", "--out", str(tmp_path / "p.npz")]) == 2
    assert "exists" in capsys.readouterr().err
    example = Path(__file__).parents[1] / "examples" / "deploy_robot.py"
    drive = subprocess.run([sys.executable, str(example), str(tmp_path / "p.npz")],
                           capture_output=True, text=True, check=True)
    assert drive.stdout.splitlines()[1].startswith("step   1: ")
    assert main(["render", str(run)]) == 0
    assert (run / "policy.png").stat().st_size > 0 and (run / "policy.pdf").stat().st_size > 0
    mine = tmp_path / "mine.png"
    mine.write_text("a user's file")
    assert main(["render", str(run), "--out", str(mine)]) == 2
    assert mine.read_text() == "a user's file"
