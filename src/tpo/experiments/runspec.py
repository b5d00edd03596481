"""What one ``tpo train`` run trains, declared once: every field is a ``tpo train``
flag (:mod:`tpo.cli.options`) and a ``config.toml`` key. Importing this module
loads no JAX, so the command line starts fast."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import tomli_w

from tpo.algo.config import FORMAT, MAX_POPULATION, TPOConfig, profile_names
from tpo.errors import TPOError

if TYPE_CHECKING:
    from tpo.algo import TPO

DYNAMICS = ("grid", "continuous")
ACTION_KINDS = ("velocity", "heading")  # tpo.envs.continuous's (not imported: no JAX here)


#: a run's budget (``steps``) when none is given, by dynamics: the continuous robot
#: moves half a cell a step, and its zero-slack phases need four times the grid's steps
#: to trace the reference's path a step exactly (held-out maps: docs/notes/tpo-learning.md,
#: sessions 17 and 38)
DEFAULT_STEPS = {"grid": 1_000_000, "continuous": 8_000_000}
#: learners of a ``tpo train`` run: a Gymnasium env's one (stepped on the host); the
#: continuous robot's two, each on all the steps (a member that misses a zero-slack
#: path the other finds is outvoted: `hall` 2/3 against one learner's 1/3, session 38)
DEFAULT_POPULATION = {"grid": 4, "continuous": 2, "env": 1}
#: a run's observation when none is given: "auto", on a grid the factored numbers and
#: the free cell's one-hot up to tpo.envs.grid's ONEHOT_CELLS free cells, in continuous
#: space the row and column tents and a tent about every cell's centre up to
#: tpo.envs.continuous's PLACE_CELLS cells (without them the critics value a place by
#: its column: held-out maps, docs/notes/tpo-learning.md, sessions 39 and 40)
DEFAULT_OBSERVATION = "auto"
# tpo.envs.grid's and "auto" (not imported: no JAX here)
OBSERVATIONS = ("auto", "factored", "onehot", "coords", "factored+onehot")


def learner_defaults(dynamics: str, action: str, profile: str = "", **values: Any
                     ) -> TPOConfig:
    """The config the navigation robot's learner starts from, ``values`` on top
    (:meth:`TPOConfig.from_profile`): the discretized policy's for velocity actions
    in continuous space, else the categorical one's; ``profile``, by default the
    dynamics' own (``grid`` or ``continuous``)."""
    kind = "discretized" if dynamics == "continuous" and action == "velocity" else "categorical"
    return TPOConfig.from_profile(profile or dynamics, kind, **values)


class RunError(TPOError):
    """A run directory that cannot be created, read or resumed."""


@dataclass(frozen=True)
class RunSpec:
    """What one ``tpo train`` run trains: the problem and the budget (every field a
    ``tpo train`` flag and a ``config.toml`` key), and the hyperparameters (a velocity
    robot's Gaussian policy starts from its own defaults: :meth:`TPOConfig.defaults`)."""

    map: str = "home"
    """bundled map name or TOML file"""
    dag: str = "M>A>G"
    """objective DAG, e.g. "M>A>G" or "A>G, M>G" """
    slack: tuple[float, ...] = (0.0,)
    """local slack: one value for every edge, or one per edge (0,100)"""
    seed: int = 0
    """PRNG seed of the parameters, the run and a Gymnasium env's resets"""
    population: int = DEFAULT_POPULATION["grid"]
    """independent learners trained at once (vmapped), each on all the steps; the run
    answers with the one whose policy LAR's rule prefers on their greedy Monte Carlo
    returns (default 4 on a grid, 2 with continuous dynamics, 1 with a Gymnasium env)"""
    steps: int = DEFAULT_STEPS["grid"]
    """environment steps in all (default 1,000,000; with continuous dynamics 8,000,000)"""
    dynamics: str = field(default="grid", metadata={"choices": DYNAMICS})
    """grid (cell moves) or continuous (a point robot with range sensors) on the map"""
    slip: float = 0.0
    """grid: probability that a move goes in another direction"""
    observation: str = field(default=DEFAULT_OBSERVATION, metadata={"choices": OBSERVATIONS})
    """grid: auto (default), factored, onehot, coords or factored+onehot; continuous:
    auto (default), factored (row and column tents), coords or factored+onehot (a tent
    about every cell's centre too; what auto is on maps of up to 1024 cells)"""
    action: str = field(default="velocity", metadata={"choices": ACTION_KINDS})
    """continuous: velocity (a 2-vector) or heading (one of 8 compass headings)"""
    noise: float = 0.0
    """continuous: standard deviation of the Gaussian noise on every move, in cells"""
    env: str = field(default="", metadata={"metavar": "PACKAGE:ENV_ID"})
    """a Gymnasium env with vector rewards, PACKAGE:ENV_ID, instead of a map (e.g.
    mo-gymnasium:deep-sea-treasure-v0)"""
    objectives: tuple[str, ...] = field(default=(), metadata={"metavar": "NAME,..."})
    """the --env's reward components, in order"""
    profile: str = field(default="", metadata={"metavar": "NAME,..."})
    """the learner's named profile(s), applied in order under any hyperparameter given
    (listed below; default: grid, or continuous with continuous dynamics)"""
    config: TPOConfig = field(default_factory=TPOConfig)

    @classmethod
    def from_settings(cls, settings: dict[str, Any], saved: bool = False) -> RunSpec:
        """Run fields (defaults as declared) plus any TPOConfig field; ``saved``: the
        settings of a run that tpo wrote (:meth:`TPOConfig.from_saved`)."""
        settings = dict(settings)
        written = settings.pop("format", FORMAT if not saved else 7)
        defaults = {f.name: f.default for f in fields(cls) if f.name != "config"}
        continuous = settings.get("dynamics") == "continuous"
        if continuous:
            defaults["steps"] = DEFAULT_STEPS["continuous"]
            defaults["population"] = DEFAULT_POPULATION["continuous"]
        if settings.get("env"):
            defaults["population"] = DEFAULT_POPULATION["env"]
        if saved:  # what a run saved without the key meant when it was written
            defaults["observation"] = "coords" if continuous else "factored"
            defaults["population"] = 1
        run = {name: settings.pop(name, default) for name, default in defaults.items()}
        slack = run["slack"]
        slack = [slack] if isinstance(slack, int | float) else slack
        try:
            if isinstance(slack, str) or any(isinstance(v, bool) for v in slack):
                raise TypeError
            slack = tuple(float(v) for v in slack)
        except (TypeError, ValueError):
            raise RunError(f"slack must be a number or a list of numbers, got {slack!r}"
                           ) from None
        for name in ("seed", "steps", "population"):
            if isinstance(run[name], bool) or not isinstance(run[name], int):
                raise RunError(f"{name} must be an integer, got {run[name]!r:.60}")
        if not 1 <= run["population"] <= MAX_POPULATION:
            raise RunError(f"population must be from 1 to {MAX_POPULATION}, got "
                           f"{run['population']}")
        if not 0 <= run["seed"] < 2**32:
            raise RunError(f"seed must be an integer from 0 to 2**32 - 1, got {run['seed']}")
        for name in ("map", "dag", "observation", "env", "dynamics", "action", "profile"):
            if not isinstance(run[name], str):
                raise RunError(f"{name} must be a string, got {run[name]!r:.60}")
        for name in ("slip", "noise"):
            if isinstance(run[name], bool) or not isinstance(run[name], int | float):
                raise RunError(f"{name} must be a number, got {run[name]!r:.60}")
        if run["dynamics"] not in DYNAMICS:
            raise RunError(f"dynamics must be one of {', '.join(DYNAMICS)}, "
                           f"got {run['dynamics']!r:.60}")
        other = {"grid": ("action", "noise"), "continuous": ("slip",)}
        given = [n for n in other[run["dynamics"]] if run[n] != defaults[n]]
        if given:
            raise RunError(f"{given[0]} is not an option of {run['dynamics']} dynamics")
        objectives = run["objectives"]
        if isinstance(objectives, str):
            objectives = [o.strip() for o in objectives.split(",") if o.strip()]
        if not isinstance(objectives, list | tuple) or not all(isinstance(o, str)
                                                                for o in objectives):
            raise RunError(f"objectives must be names, got {objectives!r:.60}")
        if run["env"] and not objectives:
            raise RunError(f"name the reward components of env '{run['env']}' in order: "
                           "--objectives a,b,...")
        if isinstance(written, bool) or not isinstance(written, int) or written > FORMAT:
            raise RunError(f"format must be an integer of at most {FORMAT} (this version's), "
                           f"got {written!r:.60}")
        profile = ",".join(profile_names(run["profile"] or run["dynamics"]))
        return cls(map=str(run["map"]), dag=str(run["dag"]), slack=slack, seed=run["seed"],
                   population=run["population"], steps=run["steps"],
                   dynamics=run["dynamics"], slip=float(run["slip"]),
                   observation=str(run["observation"]), action=run["action"],
                   noise=float(run["noise"]), env=str(run["env"]),
                   objectives=tuple(objectives), profile=profile,
                   config=TPOConfig.from_saved(settings, written) if saved else learner_defaults(
                       run["dynamics"], run["action"], profile, **settings))

    @classmethod
    def from_toml(cls, path: str | Path, saved: bool = False) -> RunSpec:
        try:
            return cls.from_settings(tomllib.loads(Path(path).read_text(encoding="utf-8")),
                                     saved)
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
            raise RunError(f"cannot read {path}: {err}") from None

    def to_toml(self) -> str:
        if self.env:
            problem = {"env": self.env, "objectives": list(self.objectives)}
        elif self.dynamics == "continuous":
            problem = {"map": self.map, "dynamics": self.dynamics, "action": self.action,
                       "noise": self.noise, "observation": self.observation}
        else:
            problem = {"map": self.map, "slip": self.slip, "observation": self.observation}
        return tomli_w.dumps({"format": FORMAT, **problem, "dag": self.dag,
                              "slack": list(self.slack), "seed": self.seed,
                              "population": self.population, "steps": self.steps,
                              "profile": self.profile, **self.config.to_dict()})

    def check(self) -> None:
        """Raise on anything training would refuse (map, DAG, slack, env, budget),
        before a run directory is made."""
        from tpo.algo import Trainer

        model = self.model()
        Trainer(model.env, model.graph, self.config, self.steps)

    def model(self) -> TPO:
        """A fresh (untrained) model of this run; on a map, training episodes start
        anywhere (random starts), evaluation at the map's start."""
        from tpo.algo import TPO
        from tpo.envs import ContinuousNav, GridNav, load_map

        if self.env:
            return TPO(self.env, self.dag, slack=list(self.slack), config=self.config,
                       seed=self.seed, objectives=self.objectives, population=self.population)
        if self.dynamics == "continuous":
            env = ContinuousNav(load_map(self.map), action=self.action, noise=self.noise,
                                observation=self.observation, random_start=True)
        else:
            env = GridNav(load_map(self.map), slip=self.slip, observation=self.observation,
                          random_start=True)
        return TPO(env, self.dag, slack=list(self.slack), config=self.config, seed=self.seed,
                   population=self.population)
