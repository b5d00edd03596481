"""Hyperparameters of TPO (and of plain PPO, its one-objective case), in three
groups (:data:`GROUPS`), and the named profiles that set them (:data:`PROFILES`;
docs/config.md lists every field with its reason)."""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import tomli_w

from tpo.errors import TPOError

ADVANTAGE_FORMS = ("traced", "immediate", "penalized")
TELESCOPES = ("off", "roots", "all")
CONSTRAINTS = ("penalty", "restriction")
TIE_CRITICS = ("ancestors", "leaf")
#: the format of a config that tpo writes (``model.json``, a run's ``config.toml``):
#: 8 has the groups and profiles; a config of format 7 or before is read by
#: :func:`_from_format_7`
FORMAT = 8

#: the named learner profiles, each the fields it sets over :class:`TPOConfig`'s
#: defaults; a run names one or several (``tpo train --profile continuous,paper``),
#: applied in order
PROFILES: dict[str, dict[str, Any]] = {
    "grid": {},
    "continuous": {"telescope": "all", "advantage": "immediate", "tie_critic": "leaf",
                   "dead_zone": 0.4, "gae_lambda": 0.98},
    "penalty": {"constraint": "penalty"},
    "restriction": {"constraint": "restriction"},
    "paper": {"constraint": "penalty", "advantage": "penalized", "telescope": "off",
              "margin": 0.0, "tie_break": 0.0, "select": False},
}
#: what each profile is for, one line each (``tpo train --help``)
PROFILE_HELP = {
    "grid": "the defaults: tuned on the navigation grids, for any discrete env",
    "continuous": "a continuous state space (the navigation robot)",
    "penalty": "the constraints as the paper's Lagrangian penalty (the default form)",
    "restriction": "the constraints as LAR's admissible actions (discrete actions)",
    "paper": "the paper's TPO as printed: Algorithm 1 with Eq. 10, no added terms",
}
#: the defaults of a policy over each kind of action space, applied before a profile:
#: a Gaussian policy has no entropy bonus (its entropy grows without bound with its
#: standard deviation) and Adam's step 3e-4, CleanRL's and SB3's continuous default;
#: a discretized one 5 values per dimension (docs/config.md)
POLICY_DEFAULTS: dict[str, dict[str, Any]] = {
    "categorical": {},
    "gaussian": {"ent_coef": 0.0, "ent_coef_end": 0.0, "learning_rate": 3e-4},
    "discretized": {"action_bins": 5}}

MAX_WIDTH = 4096  # widest hidden layer: 4096 x 4096 weights are 64 MB per layer
MAX_BINS = 256  # values per dimension of a discretized continuous action
MAX_POPULATION = 64  # learners of one model (tpo.algo.TPO), each with a lone run's memory


class ConfigError(TPOError):
    """A bad hyperparameter."""


@dataclass(frozen=True)
class TPOConfig:
    """Hyperparameters of TPO (and of plain PPO, its one-objective case): PPO's, the
    TMDP's, and the learner's mechanisms (:data:`GROUPS`). The defaults are the
    ``grid`` profile's; :meth:`from_profile` applies another. Every field is a
    ``tpo train`` flag (``--num-envs 32``) and a ``config.toml`` key."""

    # -- PPO
    num_envs: int = 16
    """parallel environments; an update sees num_envs * num_steps transitions"""
    num_steps: int = 128
    """rollout length of each environment per update"""
    update_epochs: int = 4
    """PPO's passes over each rollout"""
    num_minibatches: int = 4
    """minibatches per pass (must divide num_envs * num_steps)"""
    learning_rate: float = 1e-3
    """Adam's step size (actor and critics)"""
    anneal_lr: bool = True
    """anneal the learning rate linearly to 0 within every phase"""
    gamma: float = 0.99
    """discount factor"""
    gae_lambda: float = 0.95
    """GAE's lambda"""
    clip_eps: float = 0.2
    """PPO's clip range of the probability ratio"""
    ent_coef: float = 0.3
    """weight of the entropy bonus at the start of every phase"""
    ent_coef_end: float = 0.01
    """weight of the entropy bonus at the end of every phase (linear in between)"""
    vf_coef: float = 0.5
    """weight of the value loss"""
    max_grad_norm: float = 0.5
    """gradient-norm limit (actor and critics apart)"""
    hidden: tuple[int, ...] = (64, 64)
    """hidden layer widths of the actor and of each critic"""
    activation: str = field(default="tanh", metadata={"choices": ("tanh", "relu")})
    """activation of the hidden layers: tanh or relu"""
    action_bins: int = 0
    """a continuous (Box) action's policy: 0 for a diagonal Gaussian, K >= 2 for a
    factorised categorical over K evenly spaced values of each dimension"""
    # -- TMDP
    constraint: str = field(default="penalty", metadata={"choices": CONSTRAINTS})
    """how a phase keeps its ancestors' slacks: penalty (the paper's Lagrangian; any
    action space) or restriction (only LAR's admissible actions; discrete actions)"""
    beta: float | str = field(default=10.0, metadata={"metavar": "NUMBER|auto"})
    """the penalty's Lagrange multiplier, or "auto": Prop. 2's bound for a violation
    of one reward unit, max(|r_lo|, |r_hi|, r_hi - r_lo) / (1 - gamma)"""
    completion: bool = False
    """after the leaf, one phase per ancestor (roots first) that keeps the earlier
    values at zero slack: the tie rule, learned"""
    phase_fractions: tuple[float, ...] | None = field(default=None)
    """share of the timesteps of each phase (default: equal)"""
    # -- the learner's mechanisms
    select: bool = True
    """end the run by selecting among the phases' final policies by LAR's tie rule on
    their greedy returns; false keeps the leaf's own policy"""
    select_penalty: float = 5.0
    """a candidate's penalty may exceed the leaf policy's by this many one-step reward
    ranges of the constrained parents (the learned critics' noise)"""
    roots_completion: bool = True
    """with select, on a graph of several roots: a phase per later root that learns
    it under the earlier roots at zero slack, one more candidate"""
    tolerance: float = 0.2
    """a zero-slack constraint that is loose (restriction: every one) is kept within
    this share of the parent's one-step reward range"""
    margin: float = 0.15
    """penalty: a constraint charges from its slack less this share of the parent's
    one-step reward range (at most half the slack)"""
    telescope: str = field(default="roots", metadata={"choices": TELESCOPES})
    """penalty: which zero-slack constraints charge -A_w itself, not max(0, -A_w):
    off, roots (those on a root parent) or all"""
    dead_zone: float = 0.0
    """penalty: a telescoped cost's advantage charges only beyond this share of its
    one-step reward range"""
    advantage: str = field(default="traced", metadata={"choices": ADVANTAGE_FORMS})
    """the penalty in the advantage: traced (summed over GAE's horizon), immediate
    (on its own action) or penalized (GAE on the Lagrangian reward)"""
    tie_break: float = 0.1
    """the leaf also weighs its ancestors' returns, the j-th by tie_break ** (j + 1)
    in units of reward range; 0 turns it off"""
    tie_critic: str = field(default="ancestors", metadata={"choices": TIE_CRITICS})
    """who values the tie-break: the ancestors' frozen critics, or the leaf's own"""
    explore: float = 0.1
    """restriction: share of rollout steps that take a uniform random action"""
    carry_temperature: float = 5.0
    """the policy carries over from phase to phase with its logits divided by this"""
    mixed_population: bool = True
    """a population's members differ: the odd ones learn a second design, each pair
    sees another part of the observation"""
    second_tolerance: float = 0.1
    """a population's second design: a loose constraint's tolerance as a share of its
    parent head's value spread (at least 0.02)"""

    def __post_init__(self) -> None:
        for name, most in (("num_envs", 2**16), ("num_steps", 2**20), ("update_epochs", 1000),
                           ("num_minibatches", 2**20)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= most:
                raise ConfigError(f"{name} must be an integer from 1 to {most}, got {value!r}")
        if (self.num_envs * self.num_steps) % self.num_minibatches:
            raise ConfigError(f"num_minibatches ({self.num_minibatches}) must divide "
                              f"num_envs * num_steps ({self.num_envs * self.num_steps})")
        for name in ("learning_rate", "clip_eps", "max_grad_norm"):
            _positive(name, getattr(self, name))
        for name in ("ent_coef", "ent_coef_end", "vf_coef"):
            _nonnegative(name, getattr(self, name))
        for name in ("gamma", "gae_lambda"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) \
                    or not 0 <= value <= 1 or (name == "gamma" and value == 1):
                raise ConfigError(f"{name} must be in [0, 1{')' if name == 'gamma' else ']'}, "
                                  f"got {value!r}")
        hidden = tuple(self.hidden) if isinstance(self.hidden, tuple | list) else ()
        if not hidden or len(hidden) > 16 or not all(
                isinstance(h, int) and not isinstance(h, bool) and 1 <= h <= MAX_WIDTH
                for h in hidden):
            raise ConfigError(f"hidden must be 1 to 16 layer widths from 1 to {MAX_WIDTH}, "
                              f"got {self.hidden!r:.60}")
        object.__setattr__(self, "hidden", hidden)
        if not isinstance(self.activation, str) or self.activation not in ("tanh", "relu"):
            raise ConfigError(f"activation must be 'tanh' or 'relu', got {self.activation!r}")
        auto = isinstance(self.beta, str) and self.beta == "auto"
        if not auto and (isinstance(self.beta, bool) or not isinstance(self.beta, int | float)
                         or not math.isfinite(self.beta) or self.beta < 0):
            raise ConfigError(f'beta must be a finite number >= 0 or "auto", got '
                              f"{self.beta!r}")
        _positive("carry_temperature", self.carry_temperature)
        if isinstance(self.action_bins, bool) or not isinstance(self.action_bins, int) \
                or not (self.action_bins == 0 or 2 <= self.action_bins <= MAX_BINS):
            raise ConfigError(f"action_bins must be 0 (Gaussian) or an integer from 2 to "
                              f"{MAX_BINS}, got {self.action_bins!r}")
        _nonnegative("tolerance", self.tolerance)
        _nonnegative("margin", self.margin)
        _nonnegative("dead_zone", self.dead_zone)
        _nonnegative("explore", self.explore)
        _nonnegative("select_penalty", self.select_penalty)
        _nonnegative("second_tolerance", self.second_tolerance)
        _nonnegative("tie_break", self.tie_break)
        for name in ("explore", "tie_break"):
            if getattr(self, name) >= 1:
                raise ConfigError(f"{name} must be in [0, 1), got {getattr(self, name)!r}")
        for name, choices in (("constraint", CONSTRAINTS), ("tie_critic", TIE_CRITICS),
                              ("advantage", ADVANTAGE_FORMS), ("telescope", TELESCOPES)):
            value = getattr(self, name)
            if not isinstance(value, str) or value not in choices:
                raise ConfigError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
        for name in ("anneal_lr", "completion", "select", "roots_completion",
                     "mixed_population"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if self.phase_fractions is not None:
            fr = tuple(self.phase_fractions) if isinstance(self.phase_fractions,
                                                           tuple | list) else ()
            if not fr or any(isinstance(f, bool) or not isinstance(f, (int, float))
                             or not math.isfinite(f) or not f > 0 for f in fr):
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

    def to_toml(self) -> str:
        return tomli_w.dumps(self.to_dict())

    @classmethod
    def from_profile(cls, profile: str | Sequence[str] = "grid", policy: str = "categorical",
                     **values: Any) -> TPOConfig:
        """The config of ``profile`` (a name of :data:`PROFILES`, several names, or
        names joined by commas, applied in order) for a policy of ``policy``'s kind
        (:data:`POLICY_DEFAULTS`), with ``values`` on top."""
        settings = dict(POLICY_DEFAULTS[policy])
        for name in profile_names(profile):
            settings.update(PROFILES[name])
        return cls.from_dict({**settings, **values})

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TPOConfig:
        if not isinstance(data, dict):
            raise ConfigError(f"a config is a table of settings, got {type(data).__name__}")
        unknown = set(data) - {f.name for f in fields(cls)}
        if unknown:
            raise ConfigError(f"unknown config key(s): {', '.join(sorted(unknown))}")
        values = dict(data)
        for key in ("hidden", "phase_fractions"):
            if isinstance(values.get(key), list):
                values[key] = tuple(values[key])
        return cls(**values)

    @classmethod
    def from_saved(cls, data: dict[str, Any], format: int = FORMAT) -> TPOConfig:
        """A config that tpo wrote (a saved model's, a resumed run's) in ``format``."""
        if format < FORMAT and isinstance(data, dict):
            data = _from_format_7(data)
        return cls.from_dict(data)

    @classmethod
    def from_toml(cls, text: str) -> TPOConfig:
        try:
            return cls.from_dict(tomllib.loads(text))
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"bad TOML: {err}") from None


#: the fields of each group, in order
GROUPS: dict[str, tuple[str, ...]] = {
    "PPO": ("num_envs", "num_steps", "update_epochs", "num_minibatches", "learning_rate",
            "anneal_lr", "gamma", "gae_lambda", "clip_eps", "ent_coef", "ent_coef_end",
            "vf_coef", "max_grad_norm", "hidden", "activation", "action_bins"),
    "TMDP": ("constraint", "beta", "completion", "phase_fractions"),
    "mechanisms": ("select", "select_penalty", "roots_completion", "tolerance", "margin",
                   "telescope", "dead_zone", "advantage", "tie_break", "tie_critic",
                   "explore", "carry_temperature", "mixed_population", "second_tolerance"),
}


def profile_names(profile: str | Sequence[str]) -> tuple[str, ...]:
    """The names of ``profile`` (one name, several, or names joined by commas),
    each checked against :data:`PROFILES`."""
    names = profile.split(",") if isinstance(profile, str) else list(profile)
    names = [n.strip() if isinstance(n, str) else n for n in names]
    bad = [n for n in names if n not in PROFILES]
    if not names or bad:
        raise ConfigError(f"unknown profile {bad[0] if bad else profile!r:.60}: choose from "
                          f"{', '.join(PROFILES)}")
    return tuple(names)


#: what a config of format 7 or before meant by a key it did not have
_FORMAT_7_ABSENT = {"margin": 0.0, "tie_break": 0.0, "select": False, "action_bins": 0,
                    "telescope": "off", "advantage": "penalized", "mixed_population": False,
                    "roots_completion": False, "dead_zone": 0.0}
#: switches of format 7 that format 8 dropped, and the value under which they did nothing
_FORMAT_7_DROPPED = {"beta_warmup": 0.0}


def _from_format_7(data: dict[str, Any]) -> dict[str, Any]:
    """A format-7 config as format 8: absent keys take the value they meant then, a
    dropped switch must be off, and an old flag of ``telescope`` is read."""
    data = {**_FORMAT_7_ABSENT, **data}
    for key, off in _FORMAT_7_DROPPED.items():
        if data.pop(key, off) != off:
            raise ConfigError(f"this config sets {key}, which tpo no longer has; train "
                              "again without it")
    if data.get("advantage") == "literal":
        raise ConfigError('this config sets advantage = "literal", which tpo no longer has; '
                          "train again with another")
    for key in ("critic_refit", "reset_actor", "clip_value"):  # switches of tpo 0.1
        if key in data:
            raise ConfigError(f"config key {key} was removed in tpo 0.2; delete it")
    if isinstance(data.get("telescope"), bool):  # written when telescope was a flag
        data["telescope"] = "all" if data["telescope"] else "off"
    return data


def _positive(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{name} must be a finite number > 0, got {value!r}")


def _nonnegative(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or value < 0:
        raise ConfigError(f"{name} must be a finite number >= 0, got {value!r}")
