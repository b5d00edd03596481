"""The reproduction's outputs from its panel records: figures, ``results.csv``
(through :mod:`csv`), ``results.json`` and the markdown report, whose table of
each line's direction beside the paper's is also the command's summary."""

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

VERDICTS = ("lar_correct", "strict", "same_values")  # tpo.tabular.Judge's
CSV_FIELDS = ("panel", "dag", "x", "slack", "seed", "objective", "exact", "mc", "lar",
              "lar_feasible", *VERDICTS)


def write_outputs(out: Path, settings: Settings, records: dict[str, dict[str, Any]]) -> None:
    """Figures, CSV, JSON and the markdown report from the panel records."""
    from tpo.envs.render import plot_paths, save_figure
    from tpo.experiments.figures import figure2

    write_atomic(out / "results.csv", results_csv(records))
    summary = {"settings": asdict(settings), "panels": {
        n: {k: v for k, v in r.items() if k != "paths"} for n, r in records.items()}}
    write_atomic(out / "results.json", json.dumps(summary))
    save_figure(figure2([records[p.name] for p in PANELS], PANELS), out / "figure2.png")
    fig3 = records[FIGURE3.name]
    navmap = load_map(settings.map)
    paths = [np.array(fig3["paths"][i][0]) for i in range(2)]
    labels = [f"slack {'/'.join(f'{v:g}' for v in fig3['slacks'][i])}: "
              + (f"{len(p) - 1} steps to the goal" if tuple(p[-1]) == navmap.goal
                 else "never reaches the goal") for i, p in enumerate(paths)]
    save_figure(plot_paths(navmap, paths, labels, colors=("tab:blue", "tab:red"),
                           title=f"{navmap.name}: learned M>A>G paths (seed "
                                 f"{fig3['seeds'][0]})"), out / "figure3.png")
    write_atomic(out / "report.md", report(settings, records))


def results_csv(records: dict[str, dict[str, Any]]) -> str:
    """One row per panel, slack, seed and objective."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(CSV_FIELDS)
    for name, rec in records.items():
        for i, x in enumerate(rec["x"]):
            for j, seed in enumerate(rec["seeds"]):
                for k, obj in enumerate(rec["objectives"]):
                    writer.writerow((name, rec["panel"]["dag"], x,
                                     "/".join(f"{v:g}" for v in rec["slacks"][i]), seed, obj,
                                     f'{rec["exact"][i][j][k]:.6f}',
                                     f'{rec["mc"][i][j][k]:.6f}', f'{rec["lar"][i][k]:.6f}',
                                     rec["feasible"][i], *(rec[v][i][j] for v in VERDICTS)))
    return text.getvalue()


def _mean_std(values: np.ndarray) -> str:
    return f"{values.mean():.2f} ± {values.std():.2f}"


def report(settings: Settings, records: dict[str, dict[str, Any]]) -> str:
    """Markdown: a table per panel and the direction of every line beside the paper's."""
    lines = [f"# Reproduction of the paper's Figure 2 on `{settings.map}`", "",
             f"{len(settings.seeds)} seeds, {settings.steps:,} env steps per run; values are "
             "the exact discounted values at the start state of the learned greedy policy "
             "(mean ± std over seeds) and of LAR's policy for the same DAG and slack. "
             "The last three columns count the seeds whose policy is LAR-correct, strict "
             "and of the same values as LAR's (docs/design.md §6; judged against the "
             "relaxed solution where LAR is infeasible).", ""]
    for panel in PANELS:
        rec = records[panel.name]
        exact, lar = np.array(rec["exact"]), np.array(rec["lar"])
        objs = rec["objectives"]
        lines += [f"## ({panel.name}) `{panel.dag}`, slack on {panel.xlabel}", "",
                  "| slack | " + " | ".join(f"{o} | LAR {o}" for o in objs)
                  + " | LAR feasible | LAR-correct | strict | same values |",
                  "|---" * (2 * len(objs) + 5) + "|"]
        for i, x in enumerate(rec["x"]):
            cells = [f"{_mean_std(exact[i, :, k])} | {lar[i, k]:.2f}" for k in range(len(objs))]
            counts = " | ".join(f"{sum(rec[v][i])}/{len(rec['seeds'])}" for v in VERDICTS)
            lines.append(f"| {x:g} | " + " | ".join(cells) + f" | {rec['feasible'][i]} | "
                         f"{counts} |")
        lines.append("")
    lines += ["## Direction of each line", "", directions(records), ""]
    return "\n".join(lines)


def directions(records: dict[str, dict[str, Any]]) -> str:
    """The markdown table of each line's direction (learned, LAR, paper), with its
    note: the summary ``tpo reproduce`` prints."""
    rows = ["| panel | objective | learned (slack 0 → max) | LAR | paper | "
            "learned = paper | LAR = paper |", "|---|---|---|---|---|---|---|"]
    for panel in PANELS:
        rec = records[panel.name]
        exact, lar = np.array(rec["exact"]), np.array(rec["lar"])
        for k, obj in enumerate(rec["objectives"]):
            scale = float(np.abs(lar[:, k]).max())
            ours = direction(exact[0, :, k].mean(), exact[-1, :, k].mean(), scale)
            exact_dir = direction(lar[0, k], lar[-1, k], scale)
            paper = direction(*PAPER[panel.name][obj], 1.0)
            rows.append(f"| ({panel.name}) {panel.dag} | {obj} | {ours} | {exact_dir} | "
                        f"{paper} | {'yes' if ours == paper else 'no'} | "
                        f"{'yes' if exact_dir == paper else 'no'} |")
    return "\n".join([*rows, "", "The paper's directions are read off its figure source "
                      "(slack 0 and 100). 'flat' means a change under 1 % of the line's "
                      "scale (or 0.5)."])
