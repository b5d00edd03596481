"""The paper's experiments (§V) as data: Figure 2's four panels (a DAG whose
edges take the x-axis slack), the values its figure shows, Figure 3's two
slack settings, the forms of the learner every panel runs in, the
continuous robot's counterparts of the panels, and what ``tpo reproduce`` runs
(:class:`Settings`, its jobs and their names)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from tpo.graph import ObjectiveGraph


@dataclass(frozen=True)
class Panel:
    """One panel of Figure 2: a DAG whose edges ``swept`` take the x-axis slack
    (the others stay 0)."""

    name: str
    dag: str
    swept: tuple[int, ...]
    xlabel: str
    action: str = ""  # "" on the grid; else the continuous robot's action kind

    @property
    def key(self) -> str:
        """The panel's name among all panels: ``a`` on the grid, ``a-velocity`` for the
        continuous robot with velocity actions."""
        return f"{self.name}-{self.action}" if self.action else self.name

    def slack(self, x: float) -> list[float]:
        """Every edge's slack at ``x``."""
        edges = ObjectiveGraph.parse(self.dag, 0.0).edges
        return [float(x) if e in self.swept else 0.0 for e in range(len(edges))]


PANELS = (Panel("a", "M>A>G", (0, 1), r"$\eta_1 = \eta_2$"),
          Panel("b", "A>M>G", (1,), r"$\eta_2$"),
          Panel("c", "G>M>A", (0,), r"$\eta_1$"),
          Panel("d", "A>G, M>G", (0, 1), r"$\eta_1 = \eta_2$"))
# The paper's Figure 2 values at slack 0 and 100 (its figure source), by panel.
PAPER = {"a": {"avoid": (-133.65, -311.16), "monitor": (-114.47, -310.06),
               "goal": (-773.65, -596.74)},
         "b": {"avoid": (-72.94, -186.35), "monitor": (-65.27, -111.21),
               "goal": (-738.6, -600.74)},
         "c": {"avoid": (-364.38, -266.71), "monitor": (-288.76, -237.21),
               "goal": (-957.6, -957.46)},
         "d": {"avoid": (-251.67, -519.57), "monitor": (-185.26, -509.55),
               "goal": (-769.72, -670.23)}}
# The forms of the learner, each a profile of tpo.algo.config.PROFILES applied over the
# dynamics' own, the default learner's first: a reproduction runs it alone, or several
# side by side on the same seeds. penalty and restriction are TPOConfig.constraint's two
# forms; paper is the paper's TPO as printed (Algorithm 1 with Eq. 10).
FORMS = ("penalty", "restriction", "paper")
FIGURE3 = Panel("fig3", "M>A>G", (0,), r"$\eta_1$")  # slack (0, 0) and (100, 0)
FIGURE3_SLACKS = (0.0, 100.0)
# Each panel's share of the budget (Settings.steps, 1 M), measured by the reproduction
# (docs/notes/tpo-learning.md, session 26): panel (b) explores under a slack-0 root at
# every slack and takes the whole budget (40/40 LAR-correct; 40/40 on 1.5 M); (a) half
# (40/40, as on 0.75 M); (c) and Figure 3 three quarters (on half, (c) fell to 15/40 and
# Figure 3's (100, 0) to 3/5); the fan (d) half, for its four phases (the roots'
# completion among them): 30/30 same values, against 21/30 on a third (session 30).
SHARES = {"a": 1 / 2, "b": 1.0, "c": 3 / 4, "d": 1 / 2, "fig3": 3 / 4}
# The continuous robot's panels (tpo reproduce --continuous ACTION): each of Figure 2's
# DAGs, and Figure 3, at slack 0 and 100 only, in the penalty form (the paper's, the
# only one for a Gaussian policy); their budget is their share (CONTINUOUS_SHARES) of
# Settings.continuous_steps.
CONTINUOUS_PANELS = ("a", "b", "c", "d", "fig3")
# Each continuous panel's share of Settings.continuous_steps (2 M), measured with
# velocity actions (docs/notes/tpo-learning.md, sessions 32, 33 and 37): (b) takes the
# whole (8/10; on 7/8 it fell to 4/10), (c) five eighths (at (100, 0) 10/10 on seeds 0-9
# with GAE's lambda 0.98, 8/10 with 0.95; 6/10 on half), (a) and Figure 3 half (10/10
# and 5/5; on 7/16 18/20 and 5/10), the fan (d) three sixteenths (19/20 at value level;
# 6/10 on an eighth with lambda 0.95).
CONTINUOUS_SHARES = {"a": 1 / 2, "b": 1.0, "c": 5 / 8, "d": 3 / 16, "fig3": 1 / 2}
CONTINUOUS_FORM = "penalty"
CONTINUOUS_SLACKS = (0.0, 100.0)
CONTINUOUS_OBSERVATION = "factored"  # ContinuousNav's observation (a reproduction's setting)
GRID_OBSERVATION = "auto"  # GridNav's (tpo.envs.grid: factored+onehot on the paper's maps)
# A unit of work (one compiled program) holds at most this many of a panel's slack
# values x every seed: a panel of 8 is two units, so that two workers share the panels
# evenly (whole panels left one worker idle for the last 77 s; docs/scaling.md).
UNIT_SLACKS = 4


@dataclass(frozen=True)
class Settings:
    """What ``tpo reproduce`` runs: every panel of :meth:`panels` in every form, each
    run ``steps`` env steps times its panel's share (:meth:`steps_of`)."""

    map: str = "home"
    slacks: tuple[float, ...] = (0, 1, 2, 5, 10, 20, 50, 100)
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    steps: int = 1_000_000
    forms: tuple[str, ...] = FORMS[:1]  # every panel runs in each form
    completion: bool = False  # TPOConfig.completion
    shares: dict[str, float] = field(default_factory=lambda: dict(SHARES))
    action: str = "velocity"  # the continuous robot's action kind (velocity or heading)
    continuous: tuple[str, ...] = ()  # its panels, of CONTINUOUS_PANELS (() for none)
    continuous_steps: int = 2_000_000  # env steps of a continuous run of full share
    continuous_shares: dict[str, float] = field(
        default_factory=lambda: dict(CONTINUOUS_SHARES))

    @classmethod
    def quick(cls) -> Settings:
        """A small budget that runs end to end in CI (about two minutes a form, plus one
        continuous panel)."""
        return cls(map="small", slacks=(0, 100), seeds=(0, 1), steps=300_000,
                   continuous=("a",), continuous_steps=600_000)

    def panels(self) -> list[tuple[Panel, list[float]]]:
        """Every grid panel with its x-axis slack values, Figure 3 last."""
        return [*[(p, [float(x) for x in self.slacks]) for p in PANELS],
                (FIGURE3, list(FIGURE3_SLACKS))]

    def continuous_panels(self) -> list[tuple[Panel, list[float]]]:
        """The continuous robot's panels (:attr:`continuous`, in :meth:`panels`' order)
        with their slack values."""
        return [(replace(p, action=self.action), list(CONTINUOUS_SLACKS))
                for p, _ in self.panels() if p.name in self.continuous]

    def steps_of(self, panel: Panel) -> int:
        """The env steps of each run of ``panel``: its share of :attr:`steps`, or of
        :attr:`continuous_steps` for a continuous panel."""
        steps, shares = ((self.continuous_steps, self.continuous_shares) if panel.action
                         else (self.steps, self.shares))
        return max(1, round(steps * shares.get(panel.name, 1.0)))

    def jobs(self) -> list[tuple[str, str, Panel, list[float]]]:
        """Every form's grid panels (:meth:`panels`), the forms in order, then the
        continuous panels in their form, each with its name ``FORM-KEY``: its progress
        key and its file name in ``OUT/panels``."""
        return [*[(f"{form}-{p.key}", form, p, xs) for form in self.forms
                  for p, xs in self.panels()],
                *[(f"{CONTINUOUS_FORM}-{p.key}", CONTINUOUS_FORM, p, xs)
                  for p, xs in self.continuous_panels()]]

    def units(self) -> list[tuple[str, str, list[tuple[Panel, float]]]]:
        """The units of work ``(unit, form, runs)``, each run a ``(panel, x)``: every
        job's runs that no earlier job trains (:meth:`run`: Figure 3's slack (0, 0) is
        panel (a)'s first when their budgets agree), those of one :meth:`program`
        together (the continuous Figure 3's (100, 0) trains beside panel (a)'s runs),
        cut into units of at most :data:`UNIT_SLACKS` slack values, the costliest (runs
        x steps) first so that workers finish together. A program trained by one unit
        gives it the name of its first job, else ``JOB.1``, ``JOB.2``, ... in the order
        of their runs (kept: the sort is stable, and only a program's last unit is
        smaller)."""
        return [(unit, form, runs) for unit, _, form, runs in self._cut()]

    def _cut(self) -> list[tuple[str, str, str, list[tuple[Panel, float]]]]:
        """:meth:`units` with the job each unit belongs to (its first run's), second."""
        programs: dict[tuple, list[tuple[str, Panel, float]]] = {}
        seen = set()
        for job, form, panel, xs in self.jobs():
            for x in xs:
                run = self.run(form, panel, x)
                if run not in seen:
                    seen.add(run)
                    programs.setdefault(self.program(form, panel), []).append((job, panel, x))
        units = []
        for (form, *_), runs in programs.items():
            parts = [runs[i:i + UNIT_SLACKS] for i in range(0, len(runs), UNIT_SLACKS)]
            job = runs[0][0]
            units += [(job if len(parts) == 1 else f"{job}.{i + 1}", job, form,
                       [(panel, x) for _, panel, x in part]) for i, part in enumerate(parts)]
        return sorted(units, key=lambda u: -len(u[3]) * self.steps_of(u[3][0][0]))

    def sources(self) -> dict[str, list[tuple[str, list[int], bool]]]:
        """Where every job's runs are trained, in its slacks' order: ``(unit, indices
        of that unit's runs, whether the unit is the job's own)``."""
        trained = {self.run(form, panel, x): (unit, i, owner)
                   for unit, owner, form, runs in self._cut()
                   for i, (panel, x) in enumerate(runs)}
        out: dict[str, list[tuple[str, list[int], bool]]] = {}
        for job, form, panel, xs in self.jobs():
            parts = out.setdefault(job, [])
            for x in xs:
                unit, i, owner = trained[self.run(form, panel, x)]
                if parts and parts[-1][0] == unit:
                    parts[-1][1].append(i)
                else:
                    parts.append((unit, [i], owner == job))
        return out

    def program(self, form: str, panel: Panel) -> tuple:
        """What lets runs of ``panel`` train in one compiled program with another's:
        their form, DAG, action kind and budget."""
        return form, panel.dag, panel.action, self.steps_of(panel)

    def run(self, form: str, panel: Panel, x: float) -> tuple:
        """What makes a run of ``panel`` at ``x`` the same as another's: its
        :meth:`program` and every edge's slack."""
        return *self.program(form, panel), tuple(panel.slack(x))


def direction(start: float, end: float, scale: float) -> str:
    """``up``, ``down`` or ``flat`` (a change under 1 % of ``scale`` or 0.5)."""
    if abs(end - start) <= max(0.5, 0.01 * scale):
        return "flat"
    return "up" if end > start else "down"
