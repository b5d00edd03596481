"""The paper's experiments (§V): Figure 2 (four DAGs × a slack sweep) and Figure 3
(the robot's paths on the household map), by one call or ``tpo reproduce``.

Every panel runs in each form of the learner (``Settings.forms``, of
:data:`~tpo.experiments.paper.FORMS`, profiles of :data:`tpo.algo.config.PROFILES`:
the penalty, the restriction and the
paper's TPO as printed, on the same seeds). A panel of one form is one
:func:`~tpo.experiments.sweep.run_sweep`: every slack × seed of its DAG trains as
one compiled program: a unit of :mod:`tpo.experiments.engine`, run by its local
or Ray backend. Each finished panel is saved to ``OUT/panels/FORM-NAME.json`` at
once, so a killed run restarts where it was (a panel in progress resumes from its
checkpoint). The continuous robot's panels (``Settings.continuous``: the same DAGs
at slack 0 and 100, judged at value level against the env's finite reference) run
in the penalty form. Output (:mod:`tpo.experiments.report`)::

    OUT/figure2-FORM.png  four panels like the paper's: V_avoid red, V_monitor blue,
                          V_goal green against slack; seed spread shaded; LAR dashed
    OUT/figure3-FORM.png  the learned M>A>G paths at slack (0, 0) and (100, 0)
    OUT/figure2-continuous-ACTION.png, figure3-continuous-ACTION.png  the same of the
                          continuous robot (LAR: the reference's)
    OUT/results.csv       one row per form, panel, slack, seed and objective
    OUT/results.json      the same, nested, with the settings
    OUT/report.md         the verdicts of the forms side by side, a table per panel,
                          and each line's direction beside the paper's
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tpo.atomic import write_atomic
from tpo.envs import load_map
from tpo.errors import TPOError
from tpo.experiments.engine import Backend, Link, LocalBackend, Unit, read_record, run_units
from tpo.experiments.paper import (
    CONTINUOUS_FORM,
    CONTINUOUS_OBSERVATION,
    CONTINUOUS_PANELS,
    CONTINUOUS_SHARES,
    FORMS,
    GRID_OBSERVATION,
    Panel,
    Settings,
)
from tpo.experiments.report import (
    Records,
    directions,
    merge_records,
    pick_runs,
    verdict_table,
    write_outputs,
)

if TYPE_CHECKING:
    from tpo.algo import TPOConfig
    from tpo.envs import ContinuousNav, GridNav


@dataclass(frozen=True)
class Reproduction:
    """What :func:`reproduce` made: the grid panels' records of every form (forms and
    panels in order), the continuous panels' (by :attr:`Panel.key`), and where."""

    out: Path
    records: Records
    continuous: dict[str, dict[str, Any]]

    def summary(self) -> str:
        """The verdicts of the forms side by side, the direction of each line beside
        the paper's, the continuous panels' verdicts, and the time it took."""
        seconds = sum(r["seconds"] for form in self.records.values() for r in form.values())
        seconds += sum(r["seconds"] for r in self.continuous.values())
        cont = (f"\n\n{verdict_table({CONTINUOUS_FORM: self.continuous})}"
                if self.continuous else "")
        return (f"{verdict_table(self.records)}\n\n{directions(self.records)}{cont}\n\n"
                f"figures, tables and report in {self.out} ({seconds:.0f} s of panel time)")


def unit_problem(form: str, runs: list[tuple[Panel, float]], settings: Settings
                 ) -> tuple[GridNav | ContinuousNav, TPOConfig, list[list[float]]]:
    """The training env, the config and every run's slacks of ``runs`` ``(panel, x)``
    of one program (:meth:`Settings.program`) in ``form``."""
    from tpo.envs import ContinuousNav, GridNav

    navmap = load_map(settings.map)
    action = runs[0][0].action
    env = (ContinuousNav(navmap, action=action, observation=CONTINUOUS_OBSERVATION,
                         random_start=True) if action
           else GridNav(navmap, observation=GRID_OBSERVATION, random_start=True))
    return env, learner(form, settings, action), [p.slack(x) for p, x in runs]


def learner(form: str, settings: Settings, action: str = "") -> TPOConfig:
    """The config every run of ``form`` trains with (``action``: the continuous
    robot's action kind, whose policy's defaults it takes; "" on the grid)."""
    from tpo.experiments.runspec import learner_defaults

    dynamics = "continuous" if action else "grid"
    return learner_defaults(dynamics, action, f"{dynamics},{form}",
                            completion=settings.completion)


def check_settings(settings: Settings) -> None:
    """Raise on anything a panel's training would refuse (forms, map, budget,
    config), before anything is written."""
    from tpo.algo import Trainer
    from tpo.algo.config import ConfigError
    from tpo.envs.continuous import ACTION_KINDS
    from tpo.graph import ObjectiveGraph

    forms = settings.forms
    if not isinstance(forms, tuple) or not forms or len(set(forms)) != len(forms) \
            or not set(forms) <= set(FORMS):
        raise TPOError(f"forms must be distinct names from {', '.join(FORMS)}, "
                       f"got {forms!r}")
    if not isinstance(settings.continuous, tuple) \
            or not set(settings.continuous) <= set(CONTINUOUS_PANELS):
        raise TPOError(f"continuous must name panels from {', '.join(CONTINUOUS_PANELS)}, "
                       f"got {settings.continuous!r}")
    if settings.action not in ACTION_KINDS:
        raise TPOError(f"action must be one of {', '.join(ACTION_KINDS)}, "
                       f"got {settings.action!r}")
    for _, form, panel, xs in settings.jobs():
        env, config, slacks = unit_problem(form, [(panel, x) for x in xs], settings)
        graph = ObjectiveGraph.parse(panel.dag, slacks[0], objectives=env.objectives)
        steps = settings.steps_of(panel)
        try:
            Trainer(env, graph, config, steps)
        except ConfigError as err:
            budget = (f"its share of {settings.continuous_steps:,}, --continuous-steps"
                      if panel.action else f"its share of {settings.steps:,}")
            raise ConfigError(f"panel ({panel.key}) trains {steps:,} steps per run "
                              f"({budget}): {err}") from None


def run_unit(form: str, runs: list[tuple[Panel, float]], settings: Settings, link: Link
             ) -> dict[str, Any]:
    """Train and evaluate ``runs`` ``(panel, x)`` of one program in ``form`` (a unit of
    work, in a worker; :meth:`Settings.units`): their record."""
    from tpo.experiments.sweep import run_sweep

    panel = runs[0][0]
    env, config, slacks = unit_problem(form, runs, settings)
    t0 = time.monotonic()
    result = run_sweep(env, panel.dag, slacks, settings.seeds, config, settings.steps_of(panel),
                       progress=lambda done, total: link.progress(done / total),
                       checkpoint=link)
    paths = [[path.tolist() for path in row] for row in result.paths]
    return {"x": [x for _, x in runs], **result.record(), "paths": paths,
            "seconds": time.monotonic() - t0, "runs": len(slacks) * len(settings.seeds)}


def check_record(path: Path, runs: list[tuple[Panel, float]]) -> None:
    """Refuse a finished unit's record at ``path`` that holds other runs than ``runs``
    (a version of tpo that cut the units otherwise wrote it), before anything trains."""
    if not path.exists():
        return
    record = read_record(path)
    mine = {"x": [x for _, x in runs], "slacks": np.float32([p.slack(x) for p, x in runs]).tolist()}
    if any(k in record and record[k] != v for k, v in mine.items()) or "x" not in record:
        raise TPOError(f"{path} holds other runs than this unit's (slacks "
                       f"{record.get('slacks', record.get('x'))}, not {mine['slacks']}): "
                       "another version of tpo cut the units otherwise; move it away to "
                       "train the unit again")


Progress = Callable[[dict[str, float]], None]


def saved_settings(path: Path) -> dict[str, Any]:
    """A reproduction's ``settings.json``; one without continuous panels means today's
    continuous shares (``continuous_shares``: another version's, or none, written
    before the field), which change nothing in it."""
    theirs = json.loads(path.read_text())
    if not theirs.get("continuous"):
        theirs["continuous_shares"] = dict(CONTINUOUS_SHARES)
    return theirs


def reproduce(out: str | Path, settings: Settings | None = None,
              progress: Progress | None = None, backend: Backend | None = None
              ) -> Reproduction:
    """Run (or finish) every panel into ``out`` and write figures, tables and report.

    A directory holding another reproduction (other settings, or runs of another
    learner config) is refused; units already in ``out/panels`` are skipped.
    ``progress({unit: fraction})`` is called at the start and as units advance
    (keys: the names of :meth:`Settings.units`). ``settings`` default to the
    paper's (:class:`Settings`); ``backend`` to two local workers.
    """
    settings = settings or Settings()
    check_settings(settings)
    out = Path(out)
    (out / "panels").mkdir(parents=True, exist_ok=True)
    settings_file = out / "settings.json"
    mine = asdict(settings)
    mine["learners"] = {form: {**learner(form, settings).to_dict(),
                               "observation": GRID_OBSERVATION} for form in settings.forms}
    if settings.continuous:
        mine["learners"][f"continuous-{settings.action}"] = {
            **learner(CONTINUOUS_FORM, settings, settings.action).to_dict(),
            "observation": CONTINUOUS_OBSERVATION}
    mine = json.loads(json.dumps(mine))
    if settings_file.exists():
        theirs = saved_settings(settings_file)
        if theirs != mine:
            changed = sorted(k for k in {*theirs, *mine} if theirs.get(k) != mine.get(k))
            raise TPOError(f"{out} holds a reproduction with other settings (in "
                           f"{', '.join(changed)}: see its settings.json); choose another --out")
    else:
        write_atomic(settings_file, json.dumps(mine))
    units = settings.units()
    for name, _, runs in units:
        check_record(out / "panels" / f"{name}.json", runs)
    found = run_units([Unit(name, run_unit, (form, runs, settings)) for name, form, runs in units],
                      backend or LocalBackend(), out / "panels",
                      None if progress is None else lambda t: progress(dict(t.fractions)))
    sources = settings.sources()
    panel = {job: {"form": form, "panel": asdict(p),
                   **merge_records([pick_runs(found[unit], indices, own)
                                    for unit, indices, own in sources[job]])}
             for job, form, p, _ in settings.jobs()}
    records = {form: {p.name: panel[job] for job, f, p, _ in settings.jobs()
                      if f == form and not p.action} for form in settings.forms}
    continuous = {p.key: panel[job] for job, _, p, _ in settings.jobs() if p.action}
    write_outputs(out, settings, records, continuous)
    return Reproduction(out, records, continuous)
