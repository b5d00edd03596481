"""The paper's experiments (§V): Figure 2 (four DAGs × a slack sweep) and Figure 3
(the robot's paths on the household map), by one call or ``tpo reproduce``.

Each panel is one :func:`~tpo.experiments.sweep.run_sweep`: every slack × seed of
its DAG trains as one compiled program. Panels run in worker processes (one
XLA thread each, one per core: DESIGN.md §6) and each finished panel is saved
to ``OUT/panels/NAME.json`` at once, so a killed run restarts where it was (a
panel in progress resumes from its checkpoint). Output::

    OUT/figure2.png   four panels like the paper's: V_avoid red, V_monitor blue,
                      V_goal green against slack; seed spread shaded; LAR dashed
    OUT/figure3.png   the learned M>A>G paths at slack (0, 0) and (100, 0)
    OUT/results.csv   one row per panel, slack, seed and objective
    OUT/results.json  the same, nested, with the settings
    OUT/report.md     a table per panel and each line's direction beside the paper's
"""

from __future__ import annotations

import ctypes
import json
import os
import signal
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path
from queue import Empty
from typing import Any

import numpy as np

from tpo.atomic import write_atomic
from tpo.envs import OBJECTIVES, load_map
from tpo.errors import TPOError

SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
PR_SET_PDEATHSIG = 1  # prctl(2): the signal a process gets when its parent dies


@dataclass(frozen=True)
class Panel:
    """One panel of Figure 2: a DAG whose edges ``swept`` take the x-axis slack
    (the others stay 0)."""

    name: str
    dag: str
    swept: tuple[int, ...]
    xlabel: str

    def slack(self, x: float, n_edges: int) -> list[float]:
        return [float(x) if e in self.swept else 0.0 for e in range(n_edges)]


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
FIGURE3 = Panel("fig3", "M>A>G", (0,), r"$\eta_1$")  # slack (0, 0) and (100, 0)


@dataclass(frozen=True)
class Settings:
    """What ``tpo reproduce`` runs (``steps`` per configuration and seed)."""

    map: str = "home"
    slacks: tuple[float, ...] = (0, 1, 2, 5, 10, 20, 50, 100)
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    steps: int = 1_500_000
    workers: int = 2

    @classmethod
    def quick(cls) -> Settings:
        """A small budget that runs end to end in CI (about two minutes)."""
        return cls(map="small", slacks=(0, 100), seeds=(0, 1), steps=300_000)


def direction(start: float, end: float, scale: float) -> str:
    """``up``, ``down`` or ``flat`` (a change under 1 % of ``scale`` or 0.5)."""
    if abs(end - start) <= max(0.5, 0.01 * scale):
        return "flat"
    return "up" if end > start else "down"


# ------------------------------------------------------------------- running
def jobs(settings: Settings) -> list[tuple[Panel, list[float]]]:
    jobs = [(p, [float(x) for x in settings.slacks]) for p in PANELS]
    return [*jobs, (FIGURE3, [0.0, 100.0])]


def _run_panel(panel: Panel, xs: list[float], settings: Settings, out: Path
               ) -> dict[str, Any]:
    """Train and evaluate one panel (in a worker process); write its JSON."""
    from tpo.algo import TPOConfig
    from tpo.envs.grid import GridNav
    from tpo.experiments.sweep import run_sweep
    from tpo.graph import ObjectiveGraph

    env = GridNav(load_map(settings.map), random_start=True)
    n_edges = len(ObjectiveGraph.parse(panel.dag, 0.0, objectives=OBJECTIVES).edges)
    slacks = [panel.slack(x, n_edges) for x in xs]
    runs = len(slacks) * len(settings.seeds)

    def progress(done: int, total: int) -> None:
        if _progress_queue is not None:
            _progress_queue.put((panel.name, done / total))

    t0 = time.monotonic()
    result = run_sweep(env, panel.dag, slacks, settings.seeds, TPOConfig(), settings.steps,
                       progress=progress, checkpoint=out / "panels" / f"{panel.name}.ckpt")
    grid = env.tabular(TPOConfig().gamma)
    paths = [[grid.rollout(pi).tolist() for pi in row] for row in result.policies]
    record = {"panel": asdict(panel), "x": xs, "slacks": slacks, "seeds": list(settings.seeds),
              "objectives": list(result.objectives), "exact": result.exact.tolist(),
              "mc": result.mc.tolist(), "lar": result.lar.tolist(),
              "feasible": result.feasible.tolist(), "matches": result.matches().tolist(),
              "paths": paths, "seconds": time.monotonic() - t0, "runs": runs}
    _write_json(out / "panels" / f"{panel.name}.json", record)
    (out / "panels" / f"{panel.name}.ckpt").unlink(missing_ok=True)
    return record


def _write_json(path: Path, data: Any) -> None:
    write_atomic(path, json.dumps(data))


_progress_queue: Any = None  # a worker's queue of (panel, fraction) for the parent


def _init_worker(queue: Any, parent: int) -> None:
    """A panel worker: one XLA thread; progress to ``queue``; on Linux, killed with
    its parent (a SIGKILLed ``tpo reproduce`` must not leave workers writing into
    the directory that its restart resumes)."""
    global _progress_queue
    _progress_queue = queue
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {SINGLE_THREAD}".strip()
    if sys.platform.startswith("linux"):
        # The signal follows the *thread* that started the worker: ProcessPoolExecutor
        # starts workers from submit(), in the caller's (main) thread.
        if ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL):
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
        if os.getppid() != parent:  # the parent died before prctl took effect
            os._exit(1)


Progress = Callable[[dict[str, float]], None]


def reproduce(out: str | Path, settings: Settings = Settings(),
              progress: Progress | None = None) -> dict[str, dict[str, Any]]:
    """Run (or finish) every panel into ``out`` and write figures, tables and report.

    A directory holding another reproduction's settings is refused; panels
    already in ``out/panels`` are skipped. ``progress({panel: fraction})`` is
    called as panels advance.
    """
    out = Path(out)
    (out / "panels").mkdir(parents=True, exist_ok=True)
    settings_file = out / "settings.json"
    mine = asdict(settings)
    mine.pop("workers")
    if settings_file.exists():
        theirs = json.loads(settings_file.read_text())
        if theirs != json.loads(json.dumps(mine)):
            raise TPOError(f"{out} holds a reproduction with other settings ({theirs}); "
                           "choose another --out")
    else:
        _write_json(settings_file, mine)
    records: dict[str, dict[str, Any]] = {}
    todo = []
    for panel, xs in jobs(settings):
        done = out / "panels" / f"{panel.name}.json"
        if done.exists():
            records[panel.name] = json.loads(done.read_text())
        else:
            todo.append((panel, xs))
    fractions = {p.name: 1.0 if p.name in records else 0.0 for p, _ in jobs(settings)}
    if todo:
        ctx = get_context("spawn")
        queue = ctx.Queue()
        with ProcessPoolExecutor(max_workers=min(settings.workers, len(todo)), mp_context=ctx,
                                 initializer=_init_worker, initargs=(queue, os.getpid())) as pool:
            futures = [pool.submit(_run_panel, p, xs, settings, out) for p, xs in todo]
            pending = set(futures)
            while pending:
                changed = False
                while True:
                    try:
                        name, fraction = queue.get_nowait()
                    except Empty:
                        break
                    fractions[name], changed = fraction, True
                if progress is not None and changed:
                    progress(dict(fractions))
                finished = [f for f in pending if f.done()]
                for f in finished:
                    record = f.result()
                    records[record["panel"]["name"]] = record
                    fractions[record["panel"]["name"]] = 1.0
                    pending.discard(f)
                if pending:
                    wait(pending, timeout=0.5)
        if progress is not None:
            progress(dict(fractions))
    records = {p.name: records[p.name] for p, _ in jobs(settings)}  # not finishing order
    write_outputs(out, settings, records)
    return records


# ------------------------------------------------------------------- outputs
def write_outputs(out: Path, settings: Settings, records: dict[str, dict[str, Any]]) -> None:
    """Figures, CSV, JSON and the markdown report from the panel records."""
    from tpo.envs.render import plot_paths, save_figure
    from tpo.experiments.figures import figure2

    rows = ["panel,dag,x,slack,seed,objective,exact,mc,lar,lar_feasible,matches_lar"]
    for name, rec in records.items():
        for i, x in enumerate(rec["x"]):
            for j, seed in enumerate(rec["seeds"]):
                for k, obj in enumerate(rec["objectives"]):
                    rows.append(",".join(str(v) for v in (
                        name, f'"{rec["panel"]["dag"]}"', x,
                        "/".join(f"{v:g}" for v in rec["slacks"][i]), seed, obj,
                        f'{rec["exact"][i][j][k]:.6f}', f'{rec["mc"][i][j][k]:.6f}',
                        f'{rec["lar"][i][k]:.6f}', rec["feasible"][i], rec["matches"][i][j])))
    write_atomic(out / "results.csv", "\n".join(rows) + "\n")
    summary = {"settings": asdict(settings), "panels": {
        n: {k: v for k, v in r.items() if k != "paths"} for n, r in records.items()}}
    _write_json(out / "results.json", summary)
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


def _mean_std(values: np.ndarray) -> str:
    return f"{values.mean():.2f} ± {values.std():.2f}"


def report(settings: Settings, records: dict[str, dict[str, Any]]) -> str:
    """Markdown: a table per panel and the direction of every line beside the paper's."""
    lines = [f"# Reproduction of the paper's Figure 2 on `{settings.map}`", "",
             f"{len(settings.seeds)} seeds, {settings.steps:,} env steps per run; values are "
             "the exact discounted values at the start state of the learned greedy policy "
             "(mean ± std over seeds) and of LAR's policy for the same DAG and slack. "
             "'match' counts seeds within 5 % or 0.5 of LAR on every objective.", ""]
    directions = ["| panel | objective | learned (slack 0 → max) | LAR | paper | "
                  "learned = paper | LAR = paper |", "|---|---|---|---|---|---|---|"]
    for panel in PANELS:
        rec = records[panel.name]
        exact, lar = np.array(rec["exact"]), np.array(rec["lar"])
        objs = rec["objectives"]
        lines += [f"## ({panel.name}) `{panel.dag}`, slack on {panel.xlabel}", "",
                  "| slack | " + " | ".join(f"{o} | LAR {o}" for o in objs)
                  + " | LAR feasible | match |",
                  "|---" * (2 * len(objs) + 3) + "|"]
        for i, x in enumerate(rec["x"]):
            cells = [f"{_mean_std(exact[i, :, k])} | {lar[i, k]:.2f}" for k in range(len(objs))]
            lines.append(f"| {x:g} | " + " | ".join(cells) + f" | {rec['feasible'][i]} | "
                         f"{sum(rec['matches'][i])}/{len(rec['seeds'])} |")
        lines.append("")
        for k, obj in enumerate(objs):
            scale = float(np.abs(lar[:, k]).max())
            ours = direction(exact[0, :, k].mean(), exact[-1, :, k].mean(), scale)
            exact_dir = direction(lar[0, k], lar[-1, k], scale)
            paper = direction(*PAPER[panel.name][obj], 1.0)
            directions.append(f"| ({panel.name}) {panel.dag} | {obj} | {ours} | {exact_dir} | "
                              f"{paper} | {'yes' if ours == paper else 'no'} | "
                              f"{'yes' if exact_dir == paper else 'no'} |")
    lines += ["## Direction of each line", "", *directions, "",
              "The paper's directions are read off its figure source (slack 0 and 100). "
              "'flat' means a change under 1 % of the line's scale (or 0.5).", ""]
    return "\n".join(lines)
