"""The reproduction's outputs from the panel records of every form and of the
continuous robot: figures, ``results.csv`` (through :mod:`csv`), ``results.json``
and the markdown report, whose tables of the verdicts and of each line's
direction beside the paper's are also the command's summary."""

from __future__ import annotations

import csv
import io
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from tpo.atomic import write_atomic
from tpo.envs import load_map
from tpo.experiments.paper import (
    CONTINUOUS_FORM,
    CONTINUOUS_SLACKS,
    FIGURE3,
    PANELS,
    PAPER,
    Settings,
    direction,
)
from tpo.tabular import VERDICTS

#: the keys of a unit's record (``x``, ``SweepResult.record()``, ``paths``, ``seconds``,
#: ``runs``) that run along the slack axis, and those that add up
ALONG_SLACKS = ("x", "slacks", "exact", "mc", "lar", "feasible", *VERDICTS, "paths")
SUMMED = ("seconds", "runs")


def pick_runs(record: dict[str, Any], indices: list[int], own: bool) -> dict[str, Any]:
    """The runs at ``indices`` of a unit's slack axis; from another job's unit
    (``own`` false) they cost this job nothing (its summed keys 0)."""
    return {k: [v[i] for i in indices] if k in ALONG_SLACKS else v if own or k not in SUMMED
            else 0 for k, v in record.items()}


def merge_records(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The records of units that cut one sweep's slack axis, in order, as one."""
    merged = dict(records[0])
    for key in merged:
        if key in ALONG_SLACKS:
            merged[key] = [v for r in records for v in r[key]]
        elif key in SUMMED:
            merged[key] = sum(r[key] for r in records)
    return merged


CSV_FIELDS = ("form", "panel", "dag", "x", "slack", "seed", "objective", "exact", "mc", "lar",
              "lar_feasible", *VERDICTS)


Records = dict[str, dict[str, dict[str, Any]]]  # {form: {panel name: panel record}}


def write_outputs(out: Path, settings: Settings, records: Records,
                  continuous: dict[str, dict[str, Any]]) -> None:
    """Figures (two per form, two of the continuous robot), CSV, JSON and the markdown
    report from the grid panels' records of every form and the continuous panels'
    (by :attr:`Panel.key`)."""
    from tpo.envs.render import save_figure
    from tpo.experiments.figures import figure2

    write_atomic(out / "results.csv", results_csv(records, continuous))
    summary = {"settings": asdict(settings), "forms": {
        form: {n: _without_paths(r) for n, r in panels.items()}
        for form, panels in records.items()},
        "continuous": {k: _without_paths(r) for k, r in continuous.items()}}
    write_atomic(out / "results.json", json.dumps(summary))
    navmap = load_map(settings.map)
    for form, panels in records.items():
        save_figure(figure2([panels[p.name] for p in PANELS], PANELS),
                    out / f"figure2-{form}.png")
        save_figure(figure3(navmap, panels[FIGURE3.name], f"{form} form"),
                    out / f"figure3-{form}.png")
    by_name = {r["panel"]["name"]: r for r in continuous.values()}
    name = f"continuous-{settings.action}"
    shown = [p for p in PANELS if p.name in by_name]
    if shown:
        save_figure(figure2([by_name[p.name] for p in shown], shown), out / f"figure2-{name}.png")
    if FIGURE3.name in by_name:
        save_figure(figure3(navmap, by_name[FIGURE3.name],
                            f"continuous robot, {settings.action} actions"),
                    out / f"figure3-{name}.png")
    write_atomic(out / "report.md", report(settings, records, continuous))


def _without_paths(record: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in record.items() if k != "paths"}


def figure3(navmap: Any, record: dict[str, Any], what: str) -> Any:
    """The learned paths of Figure 3's record (its first seed) at its two slacks: cells
    on the grid, noise-free positions of the continuous robot (drawn on the cells'
    centres, as cells are)."""
    from tpo.envs.render import plot_paths

    continuous = bool(record["panel"].get("action"))
    paths = [np.array(record["paths"][i][0], float) - (0.5 if continuous else 0.0)
             for i in range(len(record["x"]))]
    labels = []
    for i, path in enumerate(paths):
        reached = tuple(np.floor(path[-1] + 0.5).astype(int)) == navmap.goal
        labels.append(f"slack {'/'.join(f'{v:g}' for v in record['slacks'][i])}: "
                      + (f"{len(path) - 1} steps to the goal" if reached
                         else "never reaches the goal"))
    return plot_paths(navmap, paths, labels, colors=("tab:blue", "tab:red"),
                      title=f"{navmap.name}: learned M>A>G paths, {what} "
                            f"(seed {record['seeds'][0]})")


def results_csv(records: Records, continuous: dict[str, dict[str, Any]]) -> str:
    """One row per form, panel, slack, seed and objective (the continuous panels in
    their form, named by :attr:`Panel.key`)."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(CSV_FIELDS)
    for form, panels in records.items():
        for name, rec in panels.items():
            _panel_rows(writer, form, name, rec)
    for key, rec in continuous.items():
        _panel_rows(writer, CONTINUOUS_FORM, key, rec)
    return text.getvalue()


def _panel_rows(writer: Any, form: str, name: str, rec: dict[str, Any]) -> None:
    for row in record_rows(rec):
        writer.writerow((form, name, rec["panel"]["dag"], *row))


def record_rows(rec: dict[str, Any]) -> list[tuple]:
    """One row per slack, seed and objective of a sweep record (the columns of
    ``CSV_FIELDS`` from ``x``)."""
    return [(x, "/".join(f"{v:g}" for v in rec["slacks"][i]), seed, obj,
             f'{rec["exact"][i][j][k]:.6f}', f'{rec["mc"][i][j][k]:.6f}',
             f'{rec["lar"][i][k]:.6f}', rec["feasible"][i], *(rec[v][i][j] for v in VERDICTS))
            for i, x in enumerate(rec["x"]) for j, seed in enumerate(rec["seeds"])
            for k, obj in enumerate(rec["objectives"])]


def _mean_std(values: np.ndarray) -> str:
    return f"{values.mean():.2f} ± {values.std():.2f}"


def _counts(recs: list[dict[str, Any]]) -> tuple[list[int], int]:
    """The verdict counts over the feasible runs of ``recs``, and their number."""
    counts, runs = [0] * len(VERDICTS), 0
    for rec in recs:
        for i, feasible in enumerate(rec["feasible"]):
            if feasible:
                runs += len(rec["seeds"])
                for n, v in enumerate(VERDICTS):
                    counts[n] += sum(rec[v][i])
    return counts, runs


def slack_table(rec: dict[str, Any]) -> list[str]:
    """Markdown rows of a sweep record: per slack, each objective's learned value
    (mean ± std over seeds) beside LAR's, and the verdicts' counts over seeds."""
    exact, lar, objs = np.array(rec["exact"]), np.array(rec["lar"]), rec["objectives"]
    rows = ["| slack | " + " | ".join(f"{o} | LAR {o}" for o in objs)
            + " | LAR feasible | LAR-correct | strict | same values |",
            "|---" * (2 * len(objs) + 5) + "|"]
    for i, x in enumerate(rec["x"]):
        cells = [f"{_mean_std(exact[i, :, k])} | {lar[i, k]:.2f}" for k in range(len(objs))]
        counts = " | ".join(f"{sum(rec[v][i])}/{len(rec['seeds'])}" for v in VERDICTS)
        rows.append(f"| {x:g} | " + " | ".join(cells) + f" | {rec['feasible'][i]} | {counts} |")
    return rows


def verdict_table(records: Records) -> str:
    """Markdown: per panel, the forms side by side, the counts of LAR-correct, strict
    and same-values runs among the feasible ones (docs/design.md §6)."""
    forms = list(records)
    names = list(next(iter(records.values())))
    rows = ["| panel | " + " | ".join(f"{f}: LAR-correct / strict / same values"
                                       for f in forms) + " |", "|---" * (1 + len(forms)) + "|"]
    for name in [*names, None]:
        cells = []
        for form in forms:
            recs = list(records[form].values()) if name is None else [records[form][name]]
            counts, runs = _counts(recs)
            cells.append(" / ".join(f"{c}/{runs}" for c in counts) if runs else "no feasible run")
        label = "**all feasible runs**" if name is None else \
            f"({name}) {records[forms[0]][name]['panel']['dag']}"
        rows.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def budget_text(settings: Settings, continuous: bool = False) -> str:
    """Each grid (or continuous) panel's steps per run, e.g. ``1,500,000 in (b),
    1,000,000 in (a) (c)``."""
    by_steps: dict[int, list[str]] = {}
    for panel, _ in settings.continuous_panels() if continuous else settings.panels():
        by_steps.setdefault(settings.steps_of(panel), []).append(f"({panel.name})")
    if len(by_steps) == 1:
        return f"{next(iter(by_steps)):,}"
    return ", ".join(f"{steps:,} in {' '.join(names)}"
                     for steps, names in sorted(by_steps.items(), reverse=True))


def report(settings: Settings, records: Records, continuous: dict[str, dict[str, Any]]
           ) -> str:
    """Markdown: the forms' verdicts side by side, a table per form and panel, the
    direction of every line beside the paper's, and the continuous panels'."""
    lines = [f"# Reproduction of the paper's Figure 2 on `{settings.map}`", "",
             f"{len(settings.seeds)} seeds; env steps per run: {budget_text(settings)}; "
             + (f"in the {', '.join(records)} forms of the constraint on the same seeds. "
                if len(records) > 1 else f"in the {next(iter(records))} form. ")
             + "Values are the "
             "exact discounted values at the start state of the learned greedy policy "
             "(mean ± std over seeds) and of LAR's policy for the same DAG and slack. "
             "The verdict columns count the seeds whose policy is LAR-correct, strict "
             "and of the same values as LAR's (docs/design.md §6; judged against the "
             "relaxed solution where LAR is infeasible; the first table leaves those "
             "runs out).", "", verdict_table(records), ""]
    for form, panels in records.items():
        for panel in PANELS:
            lines += [f"## ({panel.name}) `{panel.dag}`, slack on {panel.xlabel}: {form} form",
                      "", *slack_table(panels[panel.name]), ""]
    lines += ["## Direction of each line", "", directions(records), ""]
    if continuous:
        lines += [f"## The continuous robot, {settings.action} actions", "",
                  f"The same DAGs at slack {' and '.join(f'{x:g}' for x in CONTINUOUS_SLACKS)} "
                  f"on the continuous env (`ContinuousNav`); env steps per run: "
                  f"{budget_text(settings, True)}; in the {CONTINUOUS_FORM} form. Values are "
                  "each learned greedy policy's noise-free discounted return from the start "
                  "(mean ± std over seeds) beside the values of LAR's policy on the env's finite "
                  "reference (`tpo solve --dynamics continuous`); LAR-correct and same "
                  "values within 5 %, strict: also the path's category (goal reached, "
                  "avoid region entered, monitor region at the end) is the reference "
                  "path's.", "", verdict_table({CONTINUOUS_FORM: continuous}), ""]
        for key, rec in continuous.items():
            lines += [f"### ({key}) `{rec['panel']['dag']}`", "", *slack_table(rec), ""]
    return "\n".join(lines)


def directions(records: Records) -> str:
    """The markdown table of each line's direction (learned in every form, LAR, paper),
    with its note: part of the summary ``tpo reproduce`` prints."""
    forms = list(records)
    rows = ["| panel | objective | " + " | ".join(f"{f} (slack 0 → max)" for f in forms)
            + " | LAR | paper | " + " | ".join(f"{f} = paper" for f in forms)
            + " | LAR = paper |", "|---" * (5 + 2 * len(forms)) + "|"]
    for panel in PANELS:
        lar = np.array(records[forms[0]][panel.name]["lar"])
        for k, obj in enumerate(records[forms[0]][panel.name]["objectives"]):
            scale = float(np.abs(lar[:, k]).max())
            ours = []
            for form in forms:
                exact = np.array(records[form][panel.name]["exact"])
                ours.append(direction(exact[0, :, k].mean(), exact[-1, :, k].mean(), scale))
            exact_dir = direction(lar[0, k], lar[-1, k], scale)
            paper = direction(*PAPER[panel.name][obj], 1.0)
            rows.append(f"| ({panel.name}) {panel.dag} | {obj} | " + " | ".join(ours)
                        + f" | {exact_dir} | {paper} | "
                        + " | ".join("yes" if o == paper else "no" for o in ours)
                        + f" | {'yes' if exact_dir == paper else 'no'} |")
    return "\n".join([*rows, "", "The paper's directions are read off its figure source "
                      "(slack 0 and 100). 'flat' means a change under 1 % of the line's "
                      "scale (or 0.5)."])
