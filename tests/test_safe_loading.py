"""Loading a saved model runs no code that its files name, and ``model.json`` is
checked against its schema (issue 15, item 3)."""

import json
import shutil
from pathlib import Path

import pytest

from tpo.algo import TPO, TPOConfig
from tpo.cli.main import main
from tpo.errors import TPOError

EVIL = '''from pathlib import Path
Path(__file__).with_name("IMPORTED").write_text("evil code ran")
'''


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> Path:
    """A tiny saved grid model, in a run directory's layout (``RUN/model``)."""
    run = tmp_path_factory.mktemp("saved") / "run"
    model = TPO("small", "A>G", config=TPOConfig(num_envs=4, num_steps=8))
    model.learn(4 * 8 * 2)
    model.save(run / "model")
    return run


def edited(saved: Path, tmp_path: Path, edit) -> Path:
    run = tmp_path / "run"
    shutil.copytree(saved, run)
    meta_file = run / "model" / "model.json"
    meta = json.loads(meta_file.read_text())
    edit(meta)
    meta_file.write_text(json.dumps(meta))
    return run


def gym_env(env_id: str):
    def edit(meta):
        meta["env"] = {"kind": "gym", "id": env_id, "objectives": ["goal", "avoid", "monitor"]}
    return edit


@pytest.mark.parametrize("env_id", ["evilmod:Evil-v0", "gym:evilmod:Evil-v0",
                                    "gymnasium:evilmod:Evil-v0"])
def test_a_module_named_in_model_json_is_never_imported(saved, tmp_path, monkeypatch,
                                                        capsys, env_id):
    run = edited(saved, tmp_path, gym_env(env_id))
    (tmp_path / "evilmod.py").write_text(EVIL)  # sent beside the model, in the cwd
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(TPOError):
        TPO.load(run / "model")
    assert main(["eval", str(run)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("tpo: error: ")
    assert not (tmp_path / "IMPORTED").exists()


def test_a_trusted_module_is_imported(saved, tmp_path, monkeypatch, capsys):
    run = edited(saved, tmp_path, gym_env("evilmod:Evil-v0"))
    (tmp_path / "evilmod.py").write_text(EVIL)
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["eval", str(run)]) == 2
    assert "--trust-module evilmod" in capsys.readouterr().err
    assert main(["eval", str(run), "--trust-module", "evilmod"]) == 2  # imported, then:
    assert "unknown env id 'Evil-v0'" in capsys.readouterr().err  # it registers nothing
    assert (tmp_path / "IMPORTED").read_text() == "evil code ran"


def _drop(key):
    return lambda meta: meta.pop(key)


def _set(key, value):
    return lambda meta: meta.__setitem__(key, value)


def _set_env(key, value):
    return lambda meta: meta["env"].__setitem__(key, value)


SCHEMA_CASES = [
    (_drop("config"), "model.json lacks 'config'"),
    (_drop("env"), "lacks 'env'"),
    (_set("extra", 1), "model.json has unknown key 'extra'"),
    (_set("seed", "zero"), "model.json: seed must be an integer, got 'zero'"),
    (_set("seed", True), "model.json: seed must be an integer, got True"),
    (_set("num_timesteps", -5), "model.json: num_timesteps must be >= 0, got -5"),
    (_set("slack", "0"), "model.json: slack must be a list"),
    (_set("slack", [0, "x"]), "slack must be a list of numbers"),
    (_set("dag", 7), "model.json: dag must be a string"),
    (_set("config", []), "model.json: config must be a table"),
    (_set("env", "grid"), "model.json: env must be a table"),
    (_set_env("kind", "maze"), "unknown env kind 'maze'"),
    (_set_env("slip", "high"), "grid env spec: slip must be a number"),
    (_set_env("random_start", 1), "random_start must be true or false"),
    (_set_env("max_steps", 2.5), "max_steps must be an integer"),
    (_set_env("module", "os"), "unknown key 'module'"),
    (lambda meta: meta["env"].pop("map"), "grid env spec lacks 'map'"),
    (lambda meta: meta.__setitem__("env", {"kind": "gym", "id": "x:Y-v0",
                                           "objectives": [1, 2]}),
     "objectives must be a list of names"),
    (_set("format", 3), "unknown model format 3"),
]


@pytest.mark.parametrize(("edit", "message"), SCHEMA_CASES,
                         ids=[m[:40] for _, m in SCHEMA_CASES])
def test_model_json_is_checked_against_its_schema(saved, tmp_path, capsys, edit, message):
    run = edited(saved, tmp_path, edit)
    assert main(["eval", str(run)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tpo: error: ") and err.count("\n") == 1, err
    assert message in err, err


def test_an_untouched_model_loads(saved):
    model = TPO.load(saved / "model")
    assert model.graph.spec == TPO("small", "A>G").graph.spec


def test_a_config_that_does_not_fit_the_state_is_one_line(saved, tmp_path, capsys):
    import hashlib

    def wider(meta):
        meta["config"]["hidden"] = [128, 128]

    run = edited(saved, tmp_path, wider)
    meta = json.loads((run / "model" / "model.json").read_text())
    meta["state_sha256"] = hashlib.sha256((run / "model" / "state.msgpack").read_bytes()
                                          ).hexdigest()
    (run / "model" / "model.json").write_text(json.dumps(meta))
    assert main(["eval", str(run)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not match model.json" in err and "128" in err, err
