"""Policy and critics: one actor, one critic per phase (Flax linen).

Orthogonal initialisation as in PPO implementations (hidden gain sqrt(2),
policy head 0.01, value heads 1): JAX's own matrices, made in two steps by
:func:`init_params`. The modules' kernels are Gaussian draws
(:func:`gaussian_draw`, in one compiled program); :func:`orthogonalize` turns them
into orthogonal matrices on the host, after the program. No QR and no Python
callback runs inside an XLA program: jaxlib's QR kernel deadlocked two at once on
a two-thread pool, and a host QR in a callback deadlocked on one CPU
(docs/design.md §5).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from functools import partial
from typing import ClassVar, NamedTuple

import flax.linen as nn
import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from tpo.algo.distributions import Categorical, DiagGaussian, Discretized, Distribution

ACTIVATIONS = {"tanh": nn.tanh, "relu": nn.relu}
#: a critic's advantage outputs are in this fraction of its value unit: advantages
#: are small beside values, and their loss would otherwise hardly move the network
ADVANTAGE_UNIT = 0.1


def _positive_q(a: np.ndarray) -> np.ndarray:
    """``Q`` of ``a = QR`` with ``R``'s diagonal made positive, for each matrix of a
    stack ``[..., m, n]`` (``m >= n``). SciPy's LAPACK is the one jaxlib's own QR
    calls, so the numbers are ``jnp.linalg.qr``'s, bit for bit."""
    a = np.asarray(a)
    out = np.empty_like(a)
    for i in np.ndindex(a.shape[:-2]):
        q, r = scipy.linalg.qr(a[i], mode="economic")
        out[i] = q * np.sign(np.diag(r))
    return out


HIDDEN_GAIN = float(np.sqrt(2))  # the orthogonal scale of every hidden layer's kernel


def gaussian_draw(key: jax.Array, shape: Sequence[int], dtype=jnp.float32) -> jax.Array:
    """The Gaussian matrix that ``jax.nn.initializers.orthogonal`` orthogonalises
    for a kernel ``shape`` ``[n_in, n_out]`` from ``key``, laid out as the kernel
    (transposed when it is wider than tall): :func:`orthogonal` of it is that
    initialiser's kernel (a Flax initialiser, traceable)."""
    n_cols = shape[-1]
    n_rows = math.prod(shape) // n_cols
    z = jax.random.normal(key, (max(n_rows, n_cols), min(n_rows, n_cols)), dtype)
    return (z.T if n_rows < n_cols else z).reshape(shape)


def orthogonal(draw: np.ndarray, scale: float) -> np.ndarray:
    """``jax.nn.initializers.orthogonal(scale)``'s kernels ``[..., n_in, n_out]`` (any
    leading axes: stacked kernels) from their :func:`gaussian_draw`, on the host, the
    same numbers bit for bit (:func:`_positive_q`)."""
    draw = np.asarray(draw)
    wide = draw.shape[-2] < draw.shape[-1]
    q = _positive_q(np.swapaxes(draw, -1, -2) if wide else draw)
    return np.asarray(scale, draw.dtype) * (np.swapaxes(q, -1, -2) if wide else q)


def orthogonalize(params: dict, out_gain: float) -> dict:
    """A network's parameters with every kernel's :func:`gaussian_draw` made
    :func:`orthogonal`: at ``out_gain`` in the output layer ``out``, at
    :data:`HIDDEN_GAIN` in the hidden ones."""

    def kernel(path: tuple, leaf: jax.Array) -> jax.Array:
        keys = [getattr(k, "key", None) for k in path]
        if keys[-1] != "kernel":
            return leaf
        return jnp.asarray(orthogonal(leaf, out_gain if "out" in keys else HIDDEN_GAIN))

    return jax.tree_util.tree_map_with_path(kernel, params)


#: blocks ``(start, stop)`` of an observation, each holding at most one non-zero number
OneHots = tuple[tuple[int, int], ...]


class InputDense(nn.Module):
    """``nn.Dense`` (the same ``kernel`` and ``bias``, initialised alike) for inputs
    whose ``onehots`` blocks hold at most one non-zero number each: a block's product
    ``x[a:b] @ kernel[a:b]`` is its one non-zero ``x[a + i] * kernel[a + i]``, a row
    gathered instead of a matrix product (the grid's free-cell one-hot is 194 of
    ``home``'s 241 numbers: docs/notes/tpo-learning.md, session 29). The same
    outputs and parameter gradients as ``nn.Dense`` (to rounding), not the same
    gradient with respect to ``x``."""

    features: int
    onehots: OneHots
    kernel_init: Callable[..., jax.Array]

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = self.param("kernel", self.kernel_init, (x.shape[-1], self.features),
                            jnp.float32)
        y = self.param("bias", nn.initializers.zeros, (self.features,), jnp.float32)
        blocks, start = sorted(self.onehots), 0
        if any(not 0 <= a < b <= x.shape[-1] for a, b in blocks) or any(
                b > a for (_, b), (a, _) in itertools.pairwise(blocks)):
            raise ValueError(f"one-hot blocks {self.onehots} are not disjoint, non-empty "
                             f"ranges of an input of {x.shape[-1]} numbers")
        for a, b in [*blocks, (x.shape[-1], x.shape[-1])]:
            if a > start:  # the dense numbers before this block
                y = y + x[..., start:a] @ kernel[start:a]
            if b > a:
                block = x[..., a:b]
                i = jnp.argmax(block != 0, axis=-1)  # the non-zero number (0 if none)
                y = y + jnp.take_along_axis(block, i[..., None], -1) * kernel[a:b][i]
            start = b
        return y


def dense_stack(x: jax.Array, hidden: Sequence[int], out: int, activation: str,
                onehots: OneHots = ()) -> jax.Array:
    """Hidden layers ``layer_0, layer_1, ...`` and the output layer ``out``, created in
    the calling module (call it from a compact method): named, so code that reads a
    layer (:meth:`Critics.head`, the actor's softening, :func:`orthogonalize`) never
    depends on Flax's automatic names. Kernels start as :func:`gaussian_draw`s. The
    first layer reads the input's ``onehots`` blocks by :class:`InputDense`."""
    act = ACTIVATIONS[activation]
    names, widths = [f"layer_{i}" for i in range(len(hidden))] + ["out"], [*hidden, out]
    for i, (name, width) in enumerate(zip(names, widths, strict=True)):
        if i == 0 and onehots:
            x = InputDense(width, onehots, gaussian_draw, name=name)(x)
        else:
            x = nn.Dense(width, kernel_init=gaussian_draw, bias_init=nn.initializers.zeros,
                         name=name)(x)
        if name != "out":
            x = act(x)
    return x


class MLP(nn.Module):
    """:func:`dense_stack` as a module. The modules' ``init`` leaves every kernel a
    :func:`gaussian_draw`; :func:`init_params` (or :func:`orthogonalize`) makes them
    orthogonal."""

    hidden: Sequence[int]
    out: int
    activation: str = "tanh"
    onehots: OneHots = ()

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        return dense_stack(x, self.hidden, self.out, self.activation, self.onehots)


class Actor(nn.Module):
    """The policy ``pi(. | obs)``: a :class:`Categorical` over ``n_out`` actions; over
    ``n_out`` continuous dimensions a :class:`DiagGaussian` with a state-independent
    log-std, or with ``bins >= 2`` a :class:`Discretized` over ``bins`` values of each
    dimension from ``low`` to ``high`` (:meth:`for_space` picks from an action space).
    Its output layer is ``out``; its first layer reads the observation's ``onehots``
    blocks by :class:`InputDense`."""

    out_gain: ClassVar[float] = 0.01  # its output layer's orthogonal scale
    hidden: Sequence[int]
    n_out: int
    discrete: bool
    activation: str = "tanh"
    bins: int = 0
    low: tuple[float, ...] = ()
    high: tuple[float, ...] = ()
    onehots: OneHots = ()

    @classmethod
    def for_space(cls, space: gym.spaces.Space, hidden: Sequence[int],
                  activation: str, bins: int = 0, onehots: OneHots = ()) -> Actor:
        """The actor of a ``Discrete`` or a 1-D ``Box`` action space (with ``bins``, a
        ``Box`` of finite bounds takes the discretized policy)."""
        if isinstance(space, gym.spaces.Discrete):
            return cls(tuple(hidden), int(space.n), True, activation, onehots=onehots)
        if isinstance(space, gym.spaces.Box) and len(space.shape) == 1:
            if not bins:
                return cls(tuple(hidden), int(space.shape[0]), False, activation,
                           onehots=onehots)
            if not (np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))):
                raise ValueError(f"action_bins needs an action space of finite bounds, got "
                                 f"{space}")
            return cls(tuple(hidden), int(space.shape[0]), False, activation, bins,
                       tuple(map(float, space.low)), tuple(map(float, space.high)), onehots)
        raise ValueError(f"no policy for action space {space}")

    @nn.compact
    def __call__(self, obs: jax.Array) -> Distribution:
        width = self.n_out * self.bins if self.bins else self.n_out
        out = dense_stack(obs, self.hidden, width, self.activation, self.onehots)
        if self.discrete:
            return Categorical(out)
        if self.bins:
            return Discretized(out.reshape(*out.shape[:-1], self.n_out, self.bins),
                               jnp.asarray(self.low), jnp.asarray(self.high))
        return DiagGaussian(out, self.param("log_std", nn.initializers.zeros, (self.n_out,)))


def scale_output(actor_params: dict, factor: jax.Array) -> dict:
    """The actor with its output layer scaled by ``factor``: a categorical (or
    discretized) policy's logits divided by a temperature (a Gaussian's mean scaled
    likewise)."""
    return {**actor_params, "out": jax.tree.map(lambda x: x * factor, actor_params["out"])}


class Critics(nn.Module):
    """One independent critic network per phase (stacked parameters ``[P, ...]``
    under ``heads``), each with ``n_out`` outputs: ``[..., P, n_out]``.

    Output 0 of a head is the state value ``V(s)``; with ``n_out = 1 + A`` (the
    restriction form, discrete actions) outputs ``1 + a`` are the advantages
    ``Q(s, a) - V(s)`` (a dueling head: the small differences between actions are
    learned directly, not as differences of two large values). Each head predicts
    *normalised* values; :class:`ValueNorm` turns them into values.
    """

    out_gain: ClassVar[float] = 1.0  # every head's output layer's orthogonal scale
    hidden: Sequence[int]
    k: int
    n_out: int = 1
    activation: str = "tanh"
    onehots: OneHots = ()

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        heads = nn.vmap(MLP, variable_axes={"params": 0}, split_rngs={"params": True},
                        in_axes=None, out_axes=-2, axis_size=self.k)
        return heads(self.hidden, self.n_out, self.activation, self.onehots,
                     name="heads")(obs)

    def head(self, params: dict, index: jax.Array, obs: jax.Array) -> jax.Array:
        """Head ``index``'s outputs ``[..., n_out]`` alone (one MLP instead of ``k``;
        the gradient reaches only that head's slice of ``params``)."""
        one = jax.tree.map(lambda x: x[index], params["heads"])
        mlp = MLP(self.hidden, self.n_out, self.activation, self.onehots, parent=None)
        return mlp.apply({"params": one}, obs)


class ValueNorm(NamedTuple):
    """Running statistics of each critic head's value targets, ``[k]`` each.

    A critic head learns ``(V - mean) / std`` (and ``(Q - V) / std``); the
    statistics of head ``i`` move only during its own phase, so they freeze with
    its critic.
    """

    mean: jax.Array
    mean_sq: jax.Array
    weight: jax.Array  # debiasing weight of the exponential averages

    @classmethod
    def init(cls, k: int) -> ValueNorm:
        return cls(jnp.zeros(k), jnp.zeros(k), jnp.zeros(k))

    def stats(self) -> tuple[jax.Array, jax.Array]:
        w = jnp.maximum(self.weight, 1e-6)
        mean = jnp.where(self.weight > 0, self.mean / w, 0.0)
        var = jnp.where(self.weight > 0, self.mean_sq / w - mean**2, 1.0)
        return mean, jnp.sqrt(jnp.maximum(var, 1e-4))

    def denormalize(self, out: jax.Array) -> jax.Array:
        """Values (and advantages) from the critics' outputs ``[..., k, n_out]``."""
        mean, std = self.stats()
        first = jnp.arange(out.shape[-1]) == 0
        return out * std[:, None] * jnp.where(first, 1.0, ADVANTAGE_UNIT) + jnp.where(
            first, mean[:, None], 0.0)

    def update(self, targets: jax.Array, pick: jax.Array, decay: float = 0.9) -> ValueNorm:
        """Fold the batch ``targets`` (of the objective ``pick`` one-hots) into the stats."""
        d = 1.0 - (1.0 - decay) * pick
        return ValueNorm(self.mean * d + (1 - d) * targets.mean(),
                         self.mean_sq * d + (1 - d) * jnp.mean(targets**2),
                         self.weight * d + (1 - d))


def init_params(key: jax.Array, actor: Actor, critics: Critics,
                obs_shape: tuple[int, ...]) -> dict:
    """``{"actor": ..., "critics": ...}`` for one seed (call outside any jit or vmap):
    :func:`draw_params` in one compiled program, then :func:`orthogonalize`d on the
    host (module docstring)."""
    draws = draw_params(key, actor, critics, tuple(obs_shape))
    return {"actor": orthogonalize(draws["actor"], actor.out_gain),
            "critics": orthogonalize(draws["critics"], critics.out_gain)}


@partial(jax.jit, static_argnums=(1, 2, 3))
def draw_params(key: jax.Array, actor: Actor, critics: Critics,
                obs_shape: tuple[int, ...]) -> dict:
    """The modules' parameters with every kernel a :func:`gaussian_draw`."""
    k_actor, k_critic = jax.random.split(key)
    dummy = jnp.zeros(obs_shape, jnp.float32)
    return {"actor": actor.init(k_actor, dummy)["params"],
            "critics": critics.init(k_critic, dummy)["params"]}
