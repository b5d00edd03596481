"""The reproduction's outputs from the panel records of every form: figures,
``results.csv`` (through :mod:`csv`), ``results.json`` and the markdown report,
whose table of the forms' verdicts and table of each line's direction beside
the paper's are also the command's summary."""

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
from tpo.experiments.paper import FIGURE3, PANELS, PAPER, Settings, direction
from tpo.tabular import VERDICTS

CSV_FIELDS = ("form", "panel", "dag", "x", "slack", "seed", "objective", "exact", "mc", "lar",
              "lar_feasible", *VERDICTS)


Records = dict[str, dict[str, dict[str, Any]]]  # {form: {panel name: panel record}}


def write_outputs(out: Path, settings: Settings, records: Records) -> None:
    """Figures (two per form), CSV, JSON and the markdown report from the panel
    records of every form."""
    from tpo.envs.render import plot_paths, save_figure
    from tpo.experiments.figures import figure2

    write_atomic(out / "results.csv", results_csv(records))
    summary = {"settings": asdict(settings), "forms": {
        form: {n: {k: v for k, v in r.items() if k != "paths"} for n, r in panels.items()}
        for form, panels in records.items()}}
    write_atomic(out / "results.json", json.dumps(summary))
    navmap = load_map(settings.map)
    for form, panels in records.items():
        save_figure(figure2([panels[p.name] for p in PANELS], PANELS),
                    out / f"figure2-{form}.png")
        fig3 = panels[FIGURE3.name]
        paths = [np.array(fig3["paths"][i][0]) for i in range(2)]
        labels = [f"slack {'/'.join(f'{v:g}' for v in fig3['slacks'][i])}: "
                  + (f"{len(p) - 1} steps to the goal" if tuple(p[-1]) == navmap.goal
                     else "never reaches the goal") for i, p in enumerate(paths)]
        save_figure(plot_paths(navmap, paths, labels, colors=("tab:blue", "tab:red"),
                               title=f"{navmap.name}: learned M>A>G paths, {form} form "
                                     f"(seed {fig3['seeds'][0]})"),
                    out / f"figure3-{form}.png")
    write_atomic(out / "report.md", report(settings, records))


def results_csv(records: Records) -> str:
    """One row per form, panel, slack, seed and objective."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(CSV_FIELDS)
    for form, panels in records.items():
        for name, rec in panels.items():
            _panel_rows(writer, form, name, rec)
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


def budget_text(settings: Settings) -> str:
    """Each panel's steps per run, e.g. ``1,500,000 in (b), 1,000,000 in (a) (c)``."""
    by_steps: dict[int, list[str]] = {}
    for panel, _ in settings.panels():
        by_steps.setdefault(settings.steps_of(panel), []).append(f"({panel.name})")
    if len(by_steps) == 1:
        return f"{next(iter(by_steps)):,}"
    return ", ".join(f"{steps:,} in {' '.join(names)}"
                     for steps, names in sorted(by_steps.items(), reverse=True))


def report(settings: Settings, records: Records) -> str:
    """Markdown: the forms' verdicts side by side, a table per form and panel, and the
    direction of every line beside the paper's."""
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
