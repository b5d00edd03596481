"""Hyperparameters of TPO (and of plain PPO, its one-objective case)."""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field, fields
from typing import Any

import tomli_w

from tpo.errors import TPOError

ADVANTAGE_FORMS = ("penalized", "literal", "immediate", "traced")
TELESCOPES = ("off", "roots", "all")
CONSTRAINTS = ("restriction", "penalty")
TIE_CRITICS = ("ancestors", "leaf")
REMOVED = frozenset({"critic_refit", "reset_actor", "clip_value"})  # options of tpo 0.1
#: fields added since tpo 0.2 (or whose default changed), and the value a config
#: written without them meant: a saved model (or a run's config.toml) without the key
#: was trained without the feature
ADDED = {"margin": 0.0, "tie_break": 0.0, "select": False, "action_bins": 0,
         "beta_warmup": 0.0, "telescope": "off", "advantage": "penalized",
         "mixed_population": False, "roots_completion": False, "dead_zone": 0.0}


#: the defaults of a Gaussian (continuous-action) policy that differ from a categorical
#: one's: no entropy bonus (a Gaussian's entropy grows without bound with its standard
#: deviation, so the bonus sized for a few categorical actions keeps the robot's moves
#: short and noisy; CleanRL's and SB3's continuous default) and Adam's step 3e-4;
#: measured in docs/notes/tpo-learning.md (sessions 9, 11 and 12)
GAUSSIAN_DEFAULTS = {"ent_coef": 0.0, "ent_coef_end": 0.0, "learning_rate": 3e-4}
#: the defaults of each kind of policy (:meth:`TPOConfig.defaults`): a discretized
#: continuous action has 5 values per dimension (the velocity robot's 16 full-speed
#: directions; 3 give 8, whose paths are up to 8 % longer) and a categorical's other
#: defaults (docs/notes/tpo-learning.md, sessions 13 and 16)
POLICY_DEFAULTS = {"categorical": {}, "gaussian": GAUSSIAN_DEFAULTS,
                   "discretized": {"action_bins": 5}}

#: what a learner in a continuous state space (the continuous navigation robot) sets
#: beside its policy's defaults: the telescoping penalty at zero slack, whose critic
#: errors cancel along a path, charged to the violating action alone, which keeps an
#: infeasible state's relaxation per state as LAR's, and the tie-break valued by the
#: leaf's own critic, which finds the leaf's way to an ancestor's reward that the
#: ancestor's own path reached through the leaf's forbidden region
#: (docs/notes/tpo-learning.md, sessions 19 to 21), and a dead zone of 0.4 of the
#: parent's reward range on the telescoping penalty, so that the dips a stochastic
#: root's critic has at doorways do not stop the phases under it (session 31), narrower
#: than one step onto the rug, which half the range let through free (session 33), and
#: GAE's lambda 0.98: the robot takes two steps a cell (speed 0.5), so 0.98 per step is
#: 0.96 per cell, near the grid's 0.95 per cell; the monitor phases of `G>M>A` at
#: (100, 0) and `A>M>G` at (0, 0) find the study and the hallway on more seeds (17 of 20
#: against 11 of 20, and 8 of 10 against 6 of 10, on part of their budget), Figure 3's
#: goal under a zero-slack avoid root ends short of its 5 % line on more (4 of 10
#: against 2 of 10: session 37)
CONTINUOUS_DEFAULTS = {"telescope": "all", "advantage": "immediate", "tie_critic": "leaf",
                       "dead_zone": 0.4, "gae_lambda": 0.98}

MAX_WIDTH = 4096  # widest hidden layer: 4096 x 4096 weights are 64 MB per layer
MAX_BINS = 256  # values per dimension of a discretized continuous action
MAX_POPULATION = 64  # learners of one model (tpo.algo.TPO), each with a lone run's memory


class ConfigError(TPOError):
    """A bad hyperparameter."""


@dataclass(frozen=True)
class TPOConfig:
    """Hyperparameters of TPO (and of plain PPO, its one-objective case). Defaults
    are tuned for the navigation grids on 2 CPU cores (a Gaussian policy's differ:
    :meth:`defaults`); every field is a ``tpo train`` flag (``--num-envs 32``) and a
    ``config.toml`` key."""

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
    constraint: str = field(default="penalty", metadata={"choices": CONSTRAINTS})
    """how a phase keeps its ancestors' slacks: penalty (the paper's Algorithm 1, the
    Lagrangian penalty; always used for continuous actions) or restriction (it samples
    only the actions that the frozen ancestral critics admit; discrete actions); see
    docs/design.md §5"""
    completion: bool = False
    """after the leaf, one phase per ancestor (roots first) that keeps the leaf's value
    and the earlier completion phases' at zero slack: the tie rule, learned"""
    tolerance: float = 0.2
    """restriction: an action is admissible when its violation of an edge is at most
    the slack plus this share of the parent objective's one-step reward range; the
    penalty form allows the completion constraints (zero slack) the same tolerance"""
    margin: float = 0.15
    """penalty: a constraint is penalised from its slack less this share of the parent
    objective's one-step reward range (at most half the slack): the learned critics
    cannot tell an action that LAR barely admits from one it excludes, and the
    margin keeps the policy on the safe side (docs/notes/tpo-learning.md)"""
    tie_break: float = 0.1
    """the leaf's policy also weighs its ancestors' returns, roots first: the j-th
    ancestor in topological order by tie_break ** (j + 1) (in units of reward range;
    each step's share at most tie_break of the leaf's reward range), so where the
    leaf is indifferent its policy follows its ancestors, as the tie rule's
    completion does (docs/design.md §2); 0 turns it off"""
    tie_critic: str = field(default="ancestors", metadata={"choices": TIE_CRITICS})
    """which critic values the ancestors' returns in the tie-break: ancestors (each
    ancestor's one-step advantages against its frozen critic, which values the
    ancestor's own phase's policy; each step's share bounded) or leaf (the ancestors'
    rewards, with the same weights, join the leaf's reward, so that the leaf's critic
    values them under the leaf's policy, and a completion phase keeps that weighted
    return); docs/tpo-algorithm.md"""
    select: bool = True
    """end the run by choosing among the phases' final policies by their greedy Monte
    Carlo returns: the leaf's objective first, then its ancestors roots first, among
    the policies the leaf's constraint checks admit (the tie rule of docs/design.md
    §2 applied to the policies the run has); false keeps the leaf's own policy"""
    roots_completion: bool = True
    """with select and without completion, on a graph of several roots (a fan): after
    the leaf, a phase for every root after the first that learns it under the earlier
    roots at zero slack, from its root's own policy — one more candidate for the
    answer, the tie rule's where the leaf is indifferent, which no objective's own
    phase learns there (tpo.algo.phases.Problem; docs/design.md §5)"""
    explore: float = 0.1
    """restriction: share of rollout steps that take a uniform random action instead of
    the policy's; they teach the critics' advantages every action and are left out of
    the policy's loss and the value targets"""
    beta: float | str = field(default=10.0, metadata={"metavar": "NUMBER|auto"})
    """penalty: Lagrange multiplier of every phase, or "auto": Prop. 2's bound for a
    violation of one reward unit, max(|r_lo|, |r_hi|, r_hi - r_lo) / (1 - gamma)"""
    telescope: str = field(default="roots", metadata={"choices": TELESCOPES})
    """penalty: which constraints at zero slack charge the parent's one-step advantage
    itself, -A_w, not max(0, -A_w): the same with the parent's optimal critic (where
    A_w <= 0), but along a path the critic's errors then telescope (they sum to its
    errors at the path's ends) instead of each negative one being charged. off (the
    paper's penalty), all, or roots: those whose parent is a root objective, whose
    positive advantages can only be the critic's errors; a parent with constraints of
    its own gains where it breaks them, so its zero-slack constraints stay rectified,
    counted from the tolerance (docs/notes/tpo-learning.md, sessions 19 and 24)"""
    dead_zone: float = 0.0
    """penalty: a constraint that telescopes at zero slack, on a parent that is a cost
    (its best one-step reward is 0, as avoid's), charges the parent's one-step advantage
    only beyond this share of the parent's one-step reward range, either way
    (soft-thresholded): the dips a cost's critic learns where its own stochastic policy
    pays (a doorway, where it bumps), which its optimum (to pay nothing) has not, then
    charge nothing; a parent that rewards progress keeps every step's cost, standing
    still's included. The price: a violation no larger than the zone charges nothing
    either, so it must stay below a cost's one-step reward (on avoid, range 2, a share
    of 0.5 let a step onto the rug from its edge, where an accurate critic dips by 1,
    through free; docs/notes/tpo-learning.md, sessions 31 and 33)"""
    beta_warmup: float = 0.0
    """penalty: share of every phase over which the multiplier rises linearly from 0
    to beta: a phase then explores before its constraints bind, which helps a child
    whose reward lies where its zero-slack parent never goes and costs a child that
    must keep its parent's path (docs/tpo-algorithm.md, "The multiplier beta")"""
    advantage: str = field(default="traced", metadata={"choices": ADVANTAGE_FORMS})
    """traced (GAE on the reward, less the penalties' own GAE-weighted sum; the critics
    value the objectives' rewards), penalized (GAE on the Lagrangian reward, the
    critics value it), literal (Eq. 10 as printed) or immediate (GAE on the reward,
    each step's penalty on its own action only); see docs/tpo-algorithm.md"""
    phase_fractions: tuple[float, ...] | None = field(default=None)
    """share of the timesteps of each phase: the objectives in topological order, then
    the completion phases or the roots' completion (TPO.phases; default: equal)"""
    action_bins: int = 0
    """a continuous (Box) action's policy: 0 for a diagonal Gaussian, K >= 2 for a
    factorised categorical over K evenly spaced values of each dimension's bounds
    (Tang & Agrawal 2020; the velocity robot's default is 5: docs/notes/tpo-learning.md,
    sessions 13 and 16); no effect on discrete actions"""
    carry_temperature: float = 5.0
    """the policy carries over from phase to phase with its logits divided by this
    temperature (1 = unchanged; measured in docs/notes/tpo-learning.md)"""
    mixed_population: bool = True
    """a population's members differ, so they do not all fail alike: the odd ones learn
    a second design (penalty form: a zero-slack constraint that does not telescope is
    counted from 0.1 of its parent head's value spread, at least 0.02, instead of
    tolerance, and the penalty is traced by gamma alone), and each pair of members
    sees the next part of the observation that the env offers alone (the grid's
    free-cell one-hot, then its factored numbers); false: every member alike
    (docs/design.md §5, docs/notes/tpo-learning.md)"""

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
        _nonnegative("beta_warmup", self.beta_warmup)
        if self.beta_warmup > 1:
            raise ConfigError(f"beta_warmup must be in [0, 1], got {self.beta_warmup!r}")
        if isinstance(self.action_bins, bool) or not isinstance(self.action_bins, int) \
                or not (self.action_bins == 0 or 2 <= self.action_bins <= MAX_BINS):
            raise ConfigError(f"action_bins must be 0 (Gaussian) or an integer from 2 to "
                              f"{MAX_BINS}, got {self.action_bins!r}")
        _nonnegative("tolerance", self.tolerance)
        _nonnegative("margin", self.margin)
        _nonnegative("dead_zone", self.dead_zone)
        _nonnegative("explore", self.explore)
        _nonnegative("tie_break", self.tie_break)
        for name in ("explore", "tie_break"):
            if getattr(self, name) >= 1:
                raise ConfigError(f"{name} must be in [0, 1), got {getattr(self, name)!r}")
        if isinstance(self.telescope, bool):  # written when telescope was a flag
            object.__setattr__(self, "telescope", "all" if self.telescope else "off")
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
    def defaults(cls, policy: str = "categorical", continuous: bool = False,
                 **values: Any) -> TPOConfig:
        """The defaults for a ``policy`` of :data:`POLICY_DEFAULTS` (categorical,
        gaussian or discretized), in a ``continuous`` state space also
        :data:`CONTINUOUS_DEFAULTS`, with ``values`` on top."""
        extra = CONTINUOUS_DEFAULTS if continuous else {}
        return cls.from_dict({**POLICY_DEFAULTS[policy], **extra, **values})

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TPOConfig:
        if not isinstance(data, dict):
            raise ConfigError(f"a config is a table of settings, got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        removed = set(data) & REMOVED
        if removed:
            raise ConfigError(f"config key(s) {', '.join(sorted(removed))} were removed in tpo "
                              "0.2 (measured as no help: docs/notes/tpo-learning.md); delete "
                              "them from the config")
        unknown = set(data) - known
        if unknown:
            raise ConfigError(f"unknown config key(s): {', '.join(sorted(unknown))}")
        values = dict(data)
        for key in ("hidden", "phase_fractions"):
            if isinstance(values.get(key), list):
                values[key] = tuple(values[key])
        return cls(**values)

    @classmethod
    def from_saved(cls, data: dict[str, Any]) -> TPOConfig:
        """A config that tpo wrote (a saved model's, a resumed run's): a field added
        since it was written takes the value it meant then (:data:`ADDED`), not
        today's default."""
        return cls.from_dict({**ADDED, **data} if isinstance(data, dict) else data)

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
