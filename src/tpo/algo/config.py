"""Hyperparameters of TPO (and of plain PPO, its one-objective case)."""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field, fields
from typing import Any

from tpo.algo.lagrangian import ADVANTAGE_FORMS
from tpo.errors import TPOError


class ConfigError(TPOError):
    """A bad hyperparameter."""


@dataclass(frozen=True)
class TPOConfig:
    """Hyperparameters. Defaults are tuned for the navigation grids on 2 CPU cores.

    Attributes:
        num_envs, num_steps: parallel envs and rollout length; one update sees
            ``num_envs * num_steps`` transitions.
        update_epochs, num_minibatches: PPO's passes over each rollout.
        learning_rate: Adam's step, annealed linearly to 0 within every phase
            when ``anneal_lr``.
        gamma, gae_lambda: discount and GAE's lambda.
        clip_eps, ent_coef, vf_coef, max_grad_norm: PPO's clip range, entropy bonus,
            value-loss weight and gradient-norm limit (actor and critics apart).
        hidden, activation: the MLPs of the actor and of each critic.
        beta: the Lagrange multiplier of every phase (a number), or ``"auto"``:
            Prop. 2's bound for a violation of one reward unit, the objective's
            largest value difference ``max(|r_lo|, |r_hi|, r_hi - r_lo) / (1 - gamma)``.
        advantage: ``"penalized"`` (default) or ``"literal"`` (Eq. 10 as printed);
            see :mod:`tpo.algo.lagrangian`.
        phase_fractions: share of the timesteps of each phase in topological
            order (default: equal).
        carry_temperature: the policy carries over from phase to phase (Algorithm 1)
            with its logits divided by this temperature at each phase start: the same
            greedy actions, but enough entropy to explore what the new objective
            wants (1 = carry unchanged; measured in docs/notes/tpo-learning.md).
        reset_actor: start every phase from the initial actor instead.
        clip_value: PPO's clipped value loss (off: it stalls critics of large values).
        critic_refit: share of each phase's updates, at its end, that roll out the
            greedy policy and train only the critic, so the frozen critic values the
            phase's final greedy policy.
    """

    num_envs: int = 16
    num_steps: int = 128
    update_epochs: int = 4
    num_minibatches: int = 4
    learning_rate: float = 1e-3
    anneal_lr: bool = True
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    hidden: tuple[int, ...] = (64, 64)
    activation: str = "tanh"
    beta: float | str = 10.0
    advantage: str = "penalized"
    phase_fractions: tuple[float, ...] | None = field(default=None)
    reset_actor: bool = False
    clip_value: bool = False
    critic_refit: float = 0.0
    carry_temperature: float = 5.0

    def __post_init__(self) -> None:
        for name in ("num_envs", "num_steps", "update_epochs", "num_minibatches"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"{name} must be a positive integer, got {value!r}")
        if (self.num_envs * self.num_steps) % self.num_minibatches:
            raise ConfigError(f"num_minibatches ({self.num_minibatches}) must divide "
                              f"num_envs * num_steps ({self.num_envs * self.num_steps})")
        for name in ("learning_rate", "clip_eps", "max_grad_norm"):
            _positive(name, getattr(self, name))
        for name in ("ent_coef", "vf_coef"):
            _nonnegative(name, getattr(self, name))
        for name in ("gamma", "gae_lambda"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) \
                    or not 0 <= value <= 1 or (name == "gamma" and value == 1):
                raise ConfigError(f"{name} must be in [0, 1{')' if name == 'gamma' else ']'}, "
                                  f"got {value!r}")
        hidden = tuple(self.hidden)
        if not hidden or not all(isinstance(h, int) and h > 0 for h in hidden):
            raise ConfigError(f"hidden must be positive layer widths, got {self.hidden!r}")
        object.__setattr__(self, "hidden", hidden)
        if self.activation not in ("tanh", "relu"):
            raise ConfigError(f"activation must be 'tanh' or 'relu', got {self.activation!r}")
        if self.beta != "auto":
            _nonnegative("beta", self.beta)
        _positive("carry_temperature", self.carry_temperature)
        if not isinstance(self.critic_refit, (int, float)) or not 0 <= self.critic_refit < 1:
            raise ConfigError(f"critic_refit must be in [0, 1), got {self.critic_refit!r}")
        if self.advantage not in ADVANTAGE_FORMS:
            raise ConfigError(f"advantage must be one of {', '.join(ADVANTAGE_FORMS)}, "
                              f"got {self.advantage!r}")
        if self.phase_fractions is not None:
            fr = tuple(self.phase_fractions)
            if not fr or any(not isinstance(f, (int, float)) or not f > 0 for f in fr):
                raise ConfigError(f"phase_fractions must be positive numbers, got {fr!r}")
            object.__setattr__(self, "phase_fractions", fr)

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.num_steps

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["hidden"] = list(self.hidden)
        if self.phase_fractions is None:
            del d["phase_fractions"]
        else:
            d["phase_fractions"] = list(self.phase_fractions)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TPOConfig:
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ConfigError(f"unknown config key(s): {', '.join(sorted(unknown))}")
        values = dict(data)
        for key in ("hidden", "phase_fractions"):
            if isinstance(values.get(key), list):
                values[key] = tuple(values[key])
        return cls(**values)

    @classmethod
    def from_toml(cls, text: str) -> TPOConfig:
        try:
            return cls.from_dict(tomllib.loads(text))
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"bad TOML: {err}") from None


def _positive(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{name} must be a finite number > 0, got {value!r}")


def _nonnegative(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or value < 0:
        raise ConfigError(f"{name} must be a finite number >= 0, got {value!r}")
