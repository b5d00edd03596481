"""Property-based fuzzing of everything tpo reads from a user or a file (issue 15,
item 7): whatever the input, reading it either succeeds or raises a
:class:`TPOError` with a one-line message, never another exception."""

import json
from dataclasses import fields

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tpo.algo import TPOConfig
from tpo.algo.persist import check_meta
from tpo.envs import OBJECTIVES, parse_map
from tpo.envs.spec import SPEC_KEYS, check_spec
from tpo.errors import TPOError
from tpo.experiments.runspec import RunSpec
from tpo.graph import ObjectiveGraph

# Values of every type TOML and JSON can hold, nested a little.
scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=8)
CONFIG_KEYS = [f.name for f in fields(TPOConfig)]
RUN_KEYS = [f.name for f in fields(RunSpec) if f.name != "config"]


def one_line_or_fine(read, *args) -> None:
    try:
        read(*args)
    except TPOError as err:
        assert "\n" not in str(err).strip(), str(err)


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.sampled_from(CONFIG_KEYS + RUN_KEYS + ["bogus"]), values,
                       max_size=5))
def test_config_toml_settings_of_any_type(settings_):
    one_line_or_fine(RunSpec.from_settings, settings_)


def _meta() -> dict:
    return {"format": 5, "config": TPOConfig().to_dict(), "dag": "A>G", "slack": [0.0],
            "env": {"kind": "grid", "map": "grid = 'x'", "slip": 0.0, "observation": "factored",
                    "max_steps": 10, "random_start": True},
            "seed": 0, "num_timesteps": 0, "total_timesteps": 6144, "updates_done": 0,
            "num_updates": 3, "state_sha256": "0" * 64}


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([*_meta(), "env.kind", "env.map", "env.slip",
                                           "env.id", "env.objectives", "other"]),
                          st.one_of(values, st.just("__drop__"))), min_size=1, max_size=4))
def test_model_json_with_any_key_changed(changes):
    meta = json.loads(json.dumps(_meta()))
    for key, value in changes:
        target, _, sub = key.partition(".")
        holder, name = (meta["env"], sub) if sub and isinstance(meta.get("env"), dict) \
            else (meta, target)
        if value == "__drop__":
            holder.pop(name, None)
        else:
            holder[name] = value
    one_line_or_fine(check_meta, meta)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(list(SPEC_KEYS)), st.dictionaries(st.text(max_size=10), values,
                                                         max_size=6))
def test_env_specs_of_any_shape(kind, spec):
    one_line_or_fine(check_spec, {"kind": kind, **spec})


MAP_ALPHABET = st.sampled_from(list("#.SGx \n"))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(MAP_ALPHABET, max_size=60),
       st.dictionaries(st.sampled_from(["avoid", "monitor", "max_steps", "name", "other"]),
                       values, max_size=3))
def test_maps_of_any_text(grid, extra):
    body = "\n".join(f"{k} = {json.dumps(v)}" for k, v in extra.items()
                     if v is not None and not isinstance(v, dict))
    one_line_or_fine(parse_map, f'grid = """\n{grid}\n"""\n{body}\n')


@settings(max_examples=300, deadline=None)
@given(st.text(st.sampled_from(list("MAGX>, ;-")), max_size=20) | st.text(max_size=8),
       st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4))
def test_dag_specs_of_any_text(spec, slack):
    one_line_or_fine(lambda: ObjectiveGraph.parse(spec, slack or 0.0, objectives=OBJECTIVES))


@pytest.mark.parametrize("text", ["grid = 3", "grid = '''\n\n'''", "[grid]\nx = 1",
                                  "grid = '''\n#S#\n#G#\n'''\navoid = [[0]]"])
def test_map_edge_cases(text):
    one_line_or_fine(parse_map, text)
