"""``tpo sweep``: how the answer to one DAG changes with the slack, on any map —
LAR's exact curve first, then TPO's learned runs judged against it.

A sweep takes x-axis values; every edge of the DAG takes the value ``x`` or a
fixed slack (:attr:`SweepSpec.edge_slack`). Its learned runs are units of the
engine (:mod:`tpo.experiments.engine`): ``slacks_per_unit`` slack values × all
seeds as one compiled program, run by the local or the Ray backend. Output::

    OUT/settings.json   what the directory holds (a restart with other settings is refused)
    OUT/exact.csv       per slack and objective: V* (each objective's own constrained
                        optimum), LAR's leaf policy's value, the floor, feasibility
    OUT/exact.json, exact.png
    OUT/units/          each finished unit's record (a restart redoes none of them)
    OUT/results.csv     one row per run and objective: exact and Monte Carlo values of the
                        learned greedy policy, LAR's, and the verdicts (docs/design.md §6)
    OUT/results.json, sweep.png (learned solid with the seeds' range, LAR dashed), report.md
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tpo.algo.config import TPOConfig
from tpo.atomic import write_atomic
from tpo.envs import OBJECTIVES, grid_model, load_map
from tpo.errors import TPOError
from tpo.experiments.engine import Backend, Link, LocalBackend, Tracker, Unit, run_units
from tpo.experiments.report import CSV_FIELDS, merge_records, record_rows, slack_table
from tpo.experiments.runspec import ACTION_KINDS, DEFAULT_OBSERVATION, DEFAULT_STEPS, DYNAMICS
from tpo.graph import ObjectiveGraph
from tpo.locking import LOCK_FILE
from tpo.tabular import VERDICTS, Judge, solve_lar
from tpo.tabular.judge import ABS_TOL

if TYPE_CHECKING:
    from tpo.envs import ContinuousNav, GridNav

SWEPT = "x"  # an edge of SweepSpec.edge_slack that takes the x-axis value
MAX_SLACK = 1e30  # larger slacks overflow float32 (and constrain nothing)
EXACT_FIELDS = ("x", "slack", "objective", "v_star", "lar", "floor", "lar_feasible")


class SweepError(TPOError):
    """A sweep that cannot run, or a directory that holds something else."""


@dataclass(frozen=True)
class SweepSpec:
    """One slack sweep: the problem, its x-axis, and the learned runs' budget."""

    map: str = "home"
    dag: str = "M>A>G"
    dynamics: str = "grid"  # or "continuous" (tpo.experiments.runspec.DYNAMICS)
    action: str = "velocity"  # continuous: velocity or heading
    xs: tuple[float, ...] = (0.0, 1.0, 2.0, 5.0, 10.0, 100.0)
    edge_slack: tuple[str, ...] = ()  # per edge: SWEPT or a fixed slack; () = every edge swept
    seeds: int = 5
    steps: int = DEFAULT_STEPS["grid"]  # tpo sweep --dynamics continuous: DEFAULT_STEPS[...]
    slacks_per_unit: int = 1
    config: TPOConfig = field(default_factory=TPOConfig)

    def graph(self) -> ObjectiveGraph:
        return ObjectiveGraph.parse(self.dag, 0.0, objectives=OBJECTIVES)

    def slack(self, x: float) -> list[float]:
        """The slack of every edge at ``x``."""
        edges = self.edge_slack or (SWEPT,) * len(self.graph().edges)
        return [float(x) if e == SWEPT else float(e) for e in edges]

    def check(self, learned: bool = True) -> None:
        """Raise one line on anything the sweep would refuse (``learned``: its runs'
        too), before anything is made."""
        load_map(self.map)
        if self.dynamics not in DYNAMICS or self.action not in ACTION_KINDS:
            raise SweepError(f"dynamics must be one of {', '.join(DYNAMICS)} and action one "
                             f"of {', '.join(ACTION_KINDS)}")
        if self.dynamics == "grid" and self.action != SweepSpec.action:
            raise SweepError("--action is an option of continuous dynamics")
        if not self.xs or any(not math.isfinite(x) or x < 0 for x in self.xs) \
                or any(b <= a for a, b in pairwise(self.xs)):
            raise SweepError("--slack needs increasing finite values >= 0, e.g. 0,1,2,5,10,100")
        if self.xs[-1] > MAX_SLACK:
            raise SweepError(f"--slack values above {MAX_SLACK:g} are not supported (training "
                             "is in float32; a slack that large is no constraint)")
        graph = self.graph()
        if not graph.edges:
            raise SweepError(f"the DAG {self.dag!r} has no edges: no slack to sweep")
        if self.edge_slack:
            if len(self.edge_slack) != len(graph.edges):
                n = len(self.edge_slack)
                raise SweepError(f"--edge-slack has {n} entr{'y' if n == 1 else 'ies'}; the "
                                 f"DAG {self.dag!r} has {len(graph.edges)} edges ("
                                 + ", ".join(f"{e.parent}>{e.child}" for e in graph.edges)
                                 + ")")
            bad = [e for e in self.edge_slack if e != SWEPT and not _number(e)]
            if bad or SWEPT not in self.edge_slack:
                raise SweepError(f"--edge-slack: give per edge '{SWEPT}' (the swept value) or a "
                                 f"finite number, with at least one '{SWEPT}'; got "
                                 f"{','.join(self.edge_slack)!r}")
        for x in self.xs:
            graph.with_slack(self.slack(x))  # checks the fixed slacks' signs
        if not learned:
            return
        if not 1 <= self.seeds <= 1000:
            raise SweepError(f"--seeds must be from 1 to 1000, got {self.seeds}")
        if not 1 <= self.slacks_per_unit <= len(self.xs):
            raise SweepError(f"--slacks-per-unit must be from 1 to the number of slack values "
                             f"({len(self.xs)}), got {self.slacks_per_unit}")
        from tpo.algo import Trainer
        from tpo.algo.config import ConfigError

        try:
            Trainer(self.env(), graph, self.config, self.steps)
        except ConfigError as err:
            raise ConfigError(f"each run of the sweep: {err}") from None

    def units(self) -> list[tuple[str, list[float]]]:
        """Every unit's name and x values, in order."""
        k = self.slacks_per_unit
        return [(f"unit-{i // k:03d}", list(self.xs[i:i + k])) for i in range(0, len(self.xs), k)]

    def problem(self) -> dict[str, Any]:
        """What the exact curve depends on."""
        return {"map": self.map, "map_sha256": load_map(self.map).sha256(), "dag": self.dag,
                "dynamics": self.dynamics,
                "action": self.action if self.dynamics == "continuous" else None,
                "xs": list(self.xs),
                "edge_slack": list(self.edge_slack), "gamma": self.config.gamma}

    def learning(self) -> dict[str, Any]:
        """What the learned runs depend on beyond the problem."""
        return {"seeds": self.seeds, "steps": self.steps, "slacks_per_unit": self.slacks_per_unit,
                "config": self.config.to_dict(), "observation": DEFAULT_OBSERVATION}

    def env(self) -> GridNav | ContinuousNav:
        """The training env: episodes start anywhere (evaluation: at the map's start)."""
        from tpo.envs import ContinuousNav, GridNav

        if self.dynamics == "continuous":
            return ContinuousNav(load_map(self.map), action=self.action,
                                 observation=DEFAULT_OBSERVATION, random_start=True)
        return GridNav(load_map(self.map), observation=DEFAULT_OBSERVATION, random_start=True)

    def xlabel(self) -> str:
        edges = self.graph().edges
        swept = [f"{e.parent[0].upper()}>{e.child[0].upper()}" for e, s in
                 zip(edges, self.edge_slack or (SWEPT,) * len(edges), strict=True) if s == SWEPT]
        return f"slack on {', '.join(swept)}"


def _number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


# -------------------------------------------------------------------- exact
def exact_curve(spec: SweepSpec) -> dict[str, Any]:
    """LAR on the map's grid model (continuous: the env's finite reference) at every
    x: each objective's ``V*`` (its own constrained optimum; None off the DAG), the
    values of LAR's leaf policy, the floors of the LAR-correct criterion, and
    feasibility (relaxed where not)."""
    if spec.dynamics == "continuous":
        from tpo.envs import ContinuousNav
        from tpo.envs.continuous_model import continuous_model

        model = continuous_model(ContinuousNav(load_map(spec.map), action=spec.action),
                                 gamma=spec.config.gamma).model
    else:
        model = grid_model(load_map(spec.map), gamma=spec.config.gamma).model
    graph = spec.graph()
    objectives = list(model.objectives)
    curve: dict[str, Any] = {"x": list(spec.xs), "slacks": [], "objectives": objectives,
                             "v_star": [], "lar": [], "floors": [], "feasible": []}
    for x in spec.xs:
        sol = solve_lar(model, graph.with_slack(spec.slack(x)), relax=True)
        stars, values, floors = sol.start_values(), sol.start_policy_values(), \
            Judge(sol, ABS_TOL).floors
        curve["slacks"].append(spec.slack(x))
        curve["v_star"].append([stars.get(n) for n in objectives])
        curve["lar"].append([values[n] for n in objectives])
        curve["floors"].append([floors.get(n) for n in objectives])
        curve["feasible"].append(bool(sol.feasible))
    return curve


def exact_csv(curve: dict[str, Any]) -> str:
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(EXACT_FIELDS)
    for i, x in enumerate(curve["x"]):
        for k, name in enumerate(curve["objectives"]):
            writer.writerow((x, "/".join(f"{v:g}" for v in curve["slacks"][i]), name,
                             *("" if v is None else f"{v + 0.0:.6f}" for v in (
                                 curve["v_star"][i][k], curve["lar"][i][k],
                                 curve["floors"][i][k])), curve["feasible"][i]))
    return text.getvalue()


def exact_table(curve: dict[str, Any]) -> str:
    """The exact curve as a plain-text table (what ``tpo sweep`` prints first)."""
    names = curve["objectives"]
    lines = [f"{'slack':>8} " + " ".join(f"{'V*_' + n:>11}" for n in names) + "  "
             + " ".join(f"{'LAR ' + n:>12}" for n in names) + "  feasible"]
    for i, x in enumerate(curve["x"]):
        stars = [f"{'-' if v is None else f'{v:.3f}':>11}" for v in curve["v_star"][i]]
        lar = [f"{v:12.3f}" for v in curve["lar"][i]]
        lines.append(f"{x:8g} " + " ".join(stars) + "  " + " ".join(lar) + "  "
                     + ("yes" if curve["feasible"][i] else "no (relaxed)"))
    return "\n".join(lines)


# ------------------------------------------------------------------ learned
def run_unit(spec: SweepSpec, xs: list[float], link: Link) -> dict[str, Any]:
    """Train and judge every seed at the slacks of ``xs`` (a unit, in a worker)."""
    from tpo.experiments.sweep import run_sweep

    result = run_sweep(spec.env(), spec.dag, [spec.slack(x) for x in xs],
                       list(range(spec.seeds)), spec.config, spec.steps,
                       progress=lambda done, total: link.progress(done / total),
                       checkpoint=link)
    return {"x": xs, **result.record()}


def check_record(record: dict[str, Any], xs: list[float], seeds: int, path: Path) -> None:
    """Raise unless ``record`` is the unit of slacks ``xs`` × ``seeds`` seeds."""
    try:
        ok = record["x"] == xs and all(
            np.shape(record[k]) == (len(xs), seeds, len(record["objectives"]))
            for k in ("exact", "mc")) and np.shape(record["lar"])[0] == len(xs) and all(
            np.shape(record[k]) == (len(xs), seeds) for k in VERDICTS)
    except (KeyError, TypeError, ValueError):
        ok = False
    if not ok:
        raise SweepError(f"{path} is not this sweep's unit of slacks "
                         f"{', '.join(f'{x:g}' for x in xs)}; delete it to run the unit again")


def results_csv(spec: SweepSpec, record: dict[str, Any]) -> str:
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(("dag", *CSV_FIELDS[CSV_FIELDS.index("x"):]))
    for row in record_rows(record):
        writer.writerow((spec.dag, *row))
    return text.getvalue()


def counts(record: dict[str, Any]) -> tuple[list[int], int]:
    """Each verdict's count over the feasible runs, and their number."""
    feasible = np.asarray(record["feasible"], bool)
    runs = int(feasible.sum()) * len(record["seeds"])
    return [int(np.asarray(record[v])[feasible].sum()) for v in VERDICTS], runs


def report(spec: SweepSpec, record: dict[str, Any]) -> str:
    (correct, strict, same), runs = counts(record)
    return "\n".join([
        f"# Slack sweep of `{spec.dag}` on `{spec.map}`", "",
        f"{spec.seeds} seeds × {len(spec.xs)} slack values ({spec.xlabel()}), "
        f"{spec.steps:,} env steps per run, `constraint = \"{spec.config.constraint}\"`. "
        "Values are the exact discounted values at the start state of the learned greedy "
        "policy (mean ± std over seeds) and of LAR's policy; the verdicts count seeds "
        "(docs/design.md §6; judged against the relaxed solution where LAR is infeasible).",
        "", f"Over the {runs} runs at feasible slacks: LAR-correct {correct}/{runs}, "
        f"strict {strict}/{runs}, same values {same}/{runs}.", "",
        *slack_table(record), ""])


# -------------------------------------------------------------------- sweep
@dataclass(frozen=True)
class Sweep:
    """What :func:`sweep` made: the exact curve, the learned record (None for an
    exact-only sweep) and where."""

    out: Path
    curve: dict[str, Any]
    record: dict[str, Any] | None

    def summary(self) -> str:
        if self.record is None:
            return f"exact curve in {self.out}"
        (correct, strict, same), runs = counts(self.record)
        return (f"{runs} runs at feasible slacks: LAR-correct {correct}/{runs}, strict "
                f"{strict}/{runs}, same values {same}/{runs}; results, figure and report "
                f"in {self.out}")


def claim(out: Path, spec: SweepSpec, learned: bool) -> None:
    """Make ``out`` this sweep's directory, or find it so: new, empty, or holding this
    sweep (a learned sweep may follow an exact-only one of the same problem)."""
    settings = out / "settings.json"
    mine = json.loads(json.dumps({"kind": "tpo sweep", "problem": spec.problem(),
                                  "learning": spec.learning() if learned else None}))
    if settings.exists():
        try:
            theirs = json.loads(settings.read_text())
        except (OSError, ValueError) as err:
            raise SweepError(f"cannot read {settings}: {err}") from None
        if not isinstance(theirs, dict) or theirs.get("kind") != "tpo sweep":
            raise SweepError(f"{out} is not a tpo sweep directory; choose another --out")
        if not isinstance(theirs.get("problem"), dict) or not isinstance(
                theirs.get("learning"), dict | None):
            raise SweepError(f"{settings} is damaged; choose another --out")
        for part in ("problem", "learning"):
            if mine[part] is not None and theirs.get(part) is not None \
                    and theirs[part] != mine[part]:
                changed = sorted(k for k in {*theirs[part], *mine[part]}
                                 if theirs[part].get(k) != mine[part].get(k))
                raise SweepError(f"{out} holds a sweep with other settings (in "
                                 f"{', '.join(changed)}: see its settings.json); choose "
                                 "another --out")
        if theirs.get("learning") is not None:
            return
    elif out.exists() and any(p.name != LOCK_FILE for p in out.iterdir()):
        raise SweepError(f"{out} is not empty and holds no tpo sweep; choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(settings, json.dumps(mine))


def sweep(out: str | Path, spec: SweepSpec, backend: Backend | None = None,
          exact_only: bool = False, on_exact: Callable[[dict[str, Any]], None] | None = None,
          progress: Callable[[Tracker], None] | None = None) -> Sweep:
    """Write the exact curve into ``out`` (``on_exact(curve)`` then), then unless
    ``exact_only`` train and judge every run (``backend``: default two local
    workers) and write results, figure and report. A restart on the directory
    redoes no finished unit."""
    spec.check(learned=not exact_only)
    out = Path(out)
    claim(out, spec, learned=not exact_only)
    curve = exact_curve(spec)
    write_atomic(out / "exact.csv", exact_csv(curve))
    write_atomic(out / "exact.json", json.dumps(curve))
    _figure(out / "exact.png", spec, {**curve, "seeds": []})
    if on_exact is not None:
        on_exact(curve)
    if exact_only:
        return Sweep(out, curve, None)
    units = [Unit(name, run_unit, (spec, xs)) for name, xs in spec.units()]
    found = run_units(units, backend or LocalBackend(), out / "units", progress)
    for name, xs in spec.units():
        check_record(found[name], xs, spec.seeds, out / "units" / f"{name}.json")
    record = merge_records([found[u.name] for u in units])
    write_atomic(out / "results.csv", results_csv(spec, record))
    write_atomic(out / "results.json", json.dumps({"settings": json.loads(
        (out / "settings.json").read_text()), "exact": curve, "learned": record}))
    _figure(out / "sweep.png", spec, record)
    write_atomic(out / "report.md", report(spec, record))
    return Sweep(out, curve, record)


def _figure(path: Path, spec: SweepSpec, record: dict[str, Any]) -> None:
    from tpo.envs.render import save_figure
    from tpo.experiments.figures import sweep_figure

    save_figure(sweep_figure(record, spec.dag, spec.xlabel(),
                             f"{spec.map}: {spec.dag}, {len(record['seeds'])} seeds"
                             if record["seeds"] else f"{spec.map}: {spec.dag}, LAR"), path)
