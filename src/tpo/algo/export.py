"""Exporting a trained policy for a robot: a NumPy ``.npz`` (run by :mod:`tpo.deploy`
with NumPy alone) or an ONNX model (run by ONNX Runtime or any ONNX runtime).

Both hold the actor only, its greedy action and its distribution's parameters,
and the same metadata (:func:`policy_meta`). The ONNX graph is built with the
``onnx`` package's helper API: the actor is a few dense layers, so its graph is
a handful of ``MatMul``/``Add``/activation nodes that any runtime runs, with no
converter (such as jax2onnx) between the trained parameters and the file, and no
dependency of the export on a converter's support for each JAX primitive.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

import tpo
from tpo import deploy
from tpo.algo.tpo import TPO
from tpo.atomic import write_atomic
from tpo.envs.continuous import ContinuousNav, headings
from tpo.envs.grid import GridNav
from tpo.envs.grid_model import ACTIONS
from tpo.errors import TPOError

FORMATS = ("onnx", "npz")
ONNX_OPSET = 13


def actor_arrays(model: TPO) -> dict[str, np.ndarray]:
    """The actor's parameters as ``float32`` arrays named ``layer_<i>/kernel`` … ``out/bias``
    (and ``log_std``)."""
    state = model.member(0)  # a population still training: its first member
    trainer = model._need_trainer()
    if trainer.form.name == "restriction":
        raise TPOError("a restriction-form policy acts through its critics' admissible "
                       "actions; export supports the penalty form (the default)")
    actor = state.params["actor"]
    arrays = {f"{layer}/{name}": np.asarray(value, np.float32)
              for layer, params in actor.items() if isinstance(params, dict)
              for name, value in params.items()}
    if "log_std" in actor:
        arrays["log_std"] = np.asarray(actor["log_std"], np.float32)
    if trainer.actor.bins:  # a discretized action: value k of dimension i is low + k step
        low, high = (np.asarray(v, np.float32) for v in (trainer.actor.low, trainer.actor.high))
        arrays["action/low"] = low
        arrays["action/step"] = (high - low) / np.float32(trainer.actor.bins - 1)
    return arrays


def observer_arrays(model: TPO) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """How the policy's observation is made (metadata) and the arrays that
    :mod:`tpo.deploy` makes it from."""
    env = model.env
    if isinstance(env, GridNav):
        return ({"kind": env.observation,
                 "encoder": "observer/table[row, col]: the observation of the robot's cell"},
                {"observer/table": np.asarray(env.params.obs_table, np.float32)})
    if isinstance(env, ContinuousNav):
        p = env.params
        return ({"kind": "continuous",
                 "encoder": "position (row, col) / map shape, then range readings / "
                            "max_range along the beams (clockwise from up), then in-avoid "
                            "and in-monitor flags, then with observer/factored a tent "
                            "max(0, 1 - |pos - (i + 1/2)|) about every row's and column's "
                            "centre, then with observer/places the product of a cell's "
                            "row and column tents for every cell, row-major "
                            "(tpo.sensing.observation)",
                 "n_beams": int(p.beams.shape[0]), "max_range": float(p.ray_t[-1])},
                {"observer/walls": np.asarray(env.navmap.walls, bool),
                 "observer/factored": np.asarray(p.factored),
                 "observer/places": np.asarray(p.places),
                 **{f"observer/{n}": np.asarray(getattr(p, n)) for n in
                    ("avoid", "monitor", "beams", "ray_t")}})
    return ({"kind": "env", "encoder": "the observation of the env the policy was trained "
             "on, flattened", "size": int(model.env.obs_shape[0])}, {})


def action_meta(model: TPO) -> dict[str, Any]:
    """What the policy's actions mean."""
    env = model.env
    if isinstance(env, GridNav):
        return {"kind": "discrete", "meanings": list(ACTIONS)}
    if isinstance(env, ContinuousNav):
        speed = float(env.params.speed)
        if env.action == "heading":
            return {"kind": "discrete", "speed": speed,
                    "meanings": [f"move {speed} cells toward (d_row, d_col) = "
                                 f"({r + 0.0:.3f}, {c + 0.0:.3f})"
                                 for r, c in np.round(headings(8), 3)]}
        return {"kind": "continuous", "speed": speed, **_bins(model),
                "meanings": ["velocity (d_row, d_col), each clipped to [-1, 1], scaled down "
                             f"to unit length if longer, times {speed} cells per step"]}
    discrete = model._need_trainer().actor.discrete
    return {"kind": "discrete" if discrete else "continuous",
            **({} if discrete else _bins(model)), "meanings": [repr(env.action_space)]}


def _bins(model: TPO) -> dict[str, Any]:
    """A continuous action's ``bins``: its values per dimension (0: a Gaussian's mean)."""
    return {"bins": model._need_trainer().actor.bins}


def policy_meta(model: TPO, observation: dict[str, Any]) -> dict[str, Any]:
    """The exported file's metadata: what the policy expects and does."""
    navmap = getattr(model.env, "navmap", None)
    config = model.config
    return {"format": deploy.FORMAT, "tpo_version": tpo.__version__,
            "objectives": list(model.env.objectives), "dag": model.graph.spec,
            "slack": list(model.graph.slacks), "gamma": config.gamma,
            "hidden": list(config.hidden), "activation": config.activation,
            "observation": observation, "action": action_meta(model),
            "map": None if navmap is None else {
                "name": navmap.name,
                "sha256": navmap.sha256()},
            "trained_timesteps": model.num_timesteps}


def export_policy(model: TPO, out: str | Path, fmt: str) -> Path:
    """Write ``model``'s policy to ``out`` as ``fmt`` (``onnx`` or ``npz``); never
    replaces an existing file."""
    if fmt not in FORMATS:
        raise TPOError(f"unknown export format {fmt!r}; choose onnx or npz")
    out = Path(out)
    if out.suffix.lower() in (".onnx", ".npz") and out.suffix.lower() != f".{fmt}":
        raise TPOError(f"{out}: the file name ends in {out.suffix} but the format is {fmt}")
    if out.exists() or out.is_symlink():
        raise TPOError(f"{out} exists; choose another file name (tpo never replaces a file "
                       "on export)")
    arrays = actor_arrays(model)
    observation, observer = observer_arrays(model)
    meta = policy_meta(model, observation)
    if fmt == "npz":
        buffer = io.BytesIO()
        np.savez(buffer, meta=np.array(json.dumps(meta)), **arrays, **observer)
        blob = buffer.getvalue()
    else:
        blob = onnx_model(arrays, meta).SerializeToString()
    try:
        write_atomic(out, blob, replace=False)
    except FileExistsError:
        raise TPOError(f"{out} appeared during the export; it was left as it is") from None
    return out


def onnx_model(arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> Any:
    """The actor as an ONNX model: input ``obs [N, D]``; outputs ``action`` (the greedy
    action: an ``int64`` index, the Gaussian's mean, or a discretized action's most
    likely values ``low + argmax * step``), ``logits`` (``[N, d * K]`` for a
    discretized action) or ``mean``, and for a Gaussian ``log_std``; the metadata as
    the ``tpo`` metadata property."""
    try:
        import onnx
        from onnx import TensorProto, helper, numpy_helper
    except ImportError:
        raise TPOError("ONNX export needs the onnx package: pip install 'tpo[export]'") \
            from None
    activation = {"tanh": "Tanh", "relu": "Relu"}[meta["activation"]]
    names = [f"layer_{i}" for i in range(len(meta["hidden"]))] + ["out"]
    gaussian, binned = "log_std" in arrays, "action/low" in arrays
    discrete = not gaussian and not binned
    head = "mean" if gaussian else "logits"
    nodes, x = [], "obs"
    for i, name in enumerate(names):
        last = i == len(names) - 1
        nodes += [helper.make_node("MatMul", [x, f"{name}/kernel"], [f"{name}/matmul"]),
                  helper.make_node("Add", [f"{name}/matmul", f"{name}/bias"],
                                   [head if last else f"{name}/linear"])]
        if not last:
            nodes.append(helper.make_node(activation, [f"{name}/linear"], [f"{name}/act"]))
            x = f"{name}/act"
    n_out = arrays["out/bias"].shape[0]
    outputs = [helper.make_tensor_value_info(head, TensorProto.FLOAT, ["batch", n_out])]
    if discrete:
        nodes.append(helper.make_node("ArgMax", [head], ["action"], axis=-1, keepdims=0))
        outputs.insert(0, helper.make_tensor_value_info("action", TensorProto.INT64, ["batch"]))
    elif binned:
        dims = arrays["action/low"].shape[0]
        shape = numpy_helper.from_array(np.array([-1, dims, n_out // dims], np.int64),
                                        "action/shape")
        nodes += [helper.make_node("Reshape", [head, "action/shape"], ["action/logits"]),
                  helper.make_node("ArgMax", ["action/logits"], ["action/index"], axis=-1,
                                   keepdims=0),
                  helper.make_node("Cast", ["action/index"], ["action/k"],
                                   to=TensorProto.FLOAT),
                  helper.make_node("Mul", ["action/k", "action/step"], ["action/offset"]),
                  helper.make_node("Add", ["action/offset", "action/low"], ["action"])]
        outputs.insert(0, helper.make_tensor_value_info("action", TensorProto.FLOAT,
                                                        ["batch", dims]))
    else:
        nodes += [helper.make_node("Identity", [head], ["action"]),
                  helper.make_node("Identity", ["log_std_param"], ["log_std"])]
        outputs.insert(0, helper.make_tensor_value_info("action", TensorProto.FLOAT,
                                                        ["batch", n_out]))
        outputs.append(helper.make_tensor_value_info("log_std", TensorProto.FLOAT, [n_out]))
    weights = [numpy_helper.from_array(v, "log_std_param" if k == "log_std" else k)
               for k, v in arrays.items()] + ([shape] if binned else [])
    d = arrays["layer_0/kernel" if len(names) > 1 else "out/kernel"].shape[0]
    graph = helper.make_graph(
        nodes, "tpo_policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", d])], outputs,
        initializer=weights)
    model = helper.make_model(graph, producer_name="tpo", producer_version=tpo.__version__,
                              opset_imports=[helper.make_opsetid("", ONNX_OPSET)])
    model.ir_version = 8  # read by ONNX Runtime 1.14 and later
    helper.set_model_props(model, {"tpo": json.dumps(meta)})
    onnx.checker.check_model(model)
    return model
