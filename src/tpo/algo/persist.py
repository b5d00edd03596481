"""Saving and loading training states: of one model (:class:`tpo.algo.tpo.TPO`) and
of a stacked sweep (:mod:`tpo.experiments.sweep`).

A state is stored as Flax msgpack of its state dict, with the PRNG key as raw
key data (typed keys do not serialise). A saved model is a directory, written
atomically, holding ``model.json`` (format version, config, problem, env spec,
progress) and ``state.msgpack`` (the whole :class:`~tpo.algo.train.TrainState`:
parameters, optimiser states, value normalisation, env states, key), so it both
acts and resumes training exactly where it stopped.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from tpo.algo.train import TrainState
from tpo.atomic import write_dir_atomic
from tpo.errors import DamagedModel, TPOError
from tpo.schema import check_table

FORMAT = 8  # 5: model.json holds the SHA-256 of state.msgpack; 6: the phases' snapshots;
#: 7: each learner's design and observation view (a population's members); 8: the
#: config's fields in groups (tpo.algo.config.FORMAT; the state as in 7)
READS = (5, 6, 7, 8)  # a format-5 state's snapshots are its actor (nothing to choose among);
#: a state before 7 learned the first design


def state_bytes(state: TrainState, **extra: Any) -> bytes:
    """``state`` (and any ``extra`` plain values) as msgpack bytes, with the format."""
    data = serialization.to_state_dict(state.replace(key=jax.random.key_data(state.key)))
    return serialization.msgpack_serialize({"format": FORMAT, "state": data, **extra})


def restore_state(template: TrainState, blob: bytes) -> tuple[TrainState, dict[str, Any]]:
    """The state of :func:`state_bytes` shaped like ``template``, and the extra
    values; ``ValueError`` (saying why) if ``blob`` is not such a state."""
    try:
        saved = serialization.msgpack_restore(blob)
        found = saved.pop("format", None)
        if found not in READS:
            raise ValueError(f"written by another version of tpo (format {found!r}; this "
                             f"version reads {READS[0]} to {FORMAT})")
        like = template.replace(key=jax.random.key_data(template.key))
        data = saved.pop("state")
        if found == 5:
            axis = jnp.ndim(template.update)  # after a sweep's [slack, seed] axes
            n = jax.tree.leaves(template.snapshots)[0].shape[axis]
            data["snapshots"] = jax.tree.map(lambda x: np.stack([x] * n, axis),
                                             data["params"]["actor"])
        if found < 7:
            data["design"] = np.zeros_like(template.design)
            data["view"] = np.zeros_like(template.view)
        state = serialization.from_state_dict(like, data)
        for (path, want), got in zip(jax.tree_util.tree_leaves_with_path(like),
                                     jax.tree.leaves(state), strict=True):
            if jnp.shape(want) != jnp.shape(got):
                raise ValueError(f"{jax.tree_util.keystr(path)} has shape {jnp.shape(got)}, "
                                 f"not {jnp.shape(want)}")
    except (ValueError, KeyError, TypeError, AttributeError) as err:
        raise ValueError(str(err)) from None
    return state.replace(key=jax.random.wrap_key_data(state.key)), saved


def save_model(path: str | Path, meta: dict[str, Any], state: TrainState,
               overwrite: bool = False) -> Path:
    """Write the model directory ``path`` (atomically)."""
    blob = state_bytes(state)
    meta = {"format": FORMAT, **meta, "state_sha256": hashlib.sha256(blob).hexdigest()}
    try:
        return write_dir_atomic(path, {"model.json": json.dumps(meta, indent=2),
                                       "state.msgpack": blob}, overwrite)
    except FileExistsError:
        raise TPOError(f"{path} exists; pass overwrite=True to replace it") from None


def read_model(path: str | Path) -> tuple[dict[str, Any], bytes]:
    """``model.json``'s contents and the state's bytes of a saved model."""
    path = Path(path)
    try:
        meta = json.loads((path / "model.json").read_text(encoding="utf-8"))
        blob = (path / "state.msgpack").read_bytes()
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DamagedModel(f"{path} is not a saved tpo model: {err}") from None
    found = meta.get("format") if isinstance(meta, dict) else None
    if found not in READS:
        raise TPOError(f"{path}: unknown model format {found!r} "
                       f"(this version reads {READS[0]} to {FORMAT})")
    try:
        check_meta(meta)
    except TPOError as err:
        raise TPOError(f"{path}: {err}") from None
    if hashlib.sha256(blob).hexdigest() != meta["state_sha256"]:
        raise DamagedModel(f"{path}/state.msgpack is damaged (its SHA-256 is not the one "
                       "model.json records)")
    return meta, blob


#: ``model.json``'s keys and their types (the env spec is checked by tpo.envs).
META_KEYS: dict[str, type] = {
    "format": int, "config": dict, "dag": str, "slack": list, "env": dict, "seed": int,
    "num_timesteps": int, "total_timesteps": int, "updates_done": int, "num_updates": int,
    "state_sha256": str}


def check_meta(meta: dict[str, Any]) -> None:
    """Raise :class:`TPOError` naming the first missing or unknown key, or value of
    the wrong type, of a saved model's ``model.json``."""
    from tpo.envs.spec import check_spec

    check_table(meta, META_KEYS, "model.json", also=("population",))
    population = meta.get("population", 1)  # a model saved without it: one learner
    if isinstance(population, bool) or not isinstance(population, int) or population < 1:
        raise TPOError(f"model.json: population must be an integer >= 1, got "
                       f"{population!r:.60}")
    negative = [k for k, kind in META_KEYS.items() if kind is int and meta[k] < 0]
    if negative:
        raise TPOError(f"model.json: {negative[0]} must be >= 0, got {meta[negative[0]]}")
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in meta["slack"]):
        raise TPOError("model.json: slack must be a list of numbers")
    check_spec(meta["env"])
