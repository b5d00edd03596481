"""The ``tpo`` command line: ``tpo maps``, ``solve``, ``train``, ``eval``, ``export``,
``render``, ``sweep``, ``reproduce``.

Every user mistake ends in one line ``tpo: error: ...`` on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time
from collections.abc import Sequence
from itertools import pairwise
from pathlib import Path
from typing import NoReturn

from tpo.algo.config import GROUPS, PROFILE_HELP, TPOConfig
from tpo.cli.options import UsageError, add_fields, read_fields
from tpo.envs import OBJECTIVES, bundled_maps, grid_model, load_map
from tpo.errors import TPOError
from tpo.experiments.paper import FORMS
from tpo.experiments.runspec import ACTION_KINDS, DEFAULT_STEPS, RunSpec, learner_defaults
from tpo.graph import ObjectiveGraph
from tpo.locking import exclusive
from tpo.tabular import LARSolution, solve_lar

EXIT_USAGE = 2


#: the profiles, listed under ``tpo train --help`` and ``tpo sweep --help``
PROFILES_EPILOG = "profiles (--profile): " + "; ".join(
    f"{name}: {text}" for name, text in PROFILE_HELP.items())

def parse_slack(text: str, option: str = "--slack") -> list[float]:
    """``"0"`` or ``"0,100"`` -> floats (the graph checks sign and count)."""
    try:
        values = [float(v) for v in text.split(",")]
        if not all(math.isfinite(v) for v in values):
            raise ValueError
        return values
    except ValueError:
        raise UsageError(f"bad {option} {text!r}: give a finite number or comma-separated "
                         "finite numbers"
                         ) from None


def episodes(text: str) -> int:
    """An argparse type: a number of episodes, 1 to 1,000,000."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    if not 1 <= value <= 10**6:
        raise argparse.ArgumentTypeError(f"must be from 1 to 1000000, got {value}")
    return value


def check_plot_file(path: str, force: bool, option: str = "--plot") -> Path:
    """A figure file to write: a format matplotlib writes, and not a user's file
    unless ``--force``."""
    from matplotlib.backend_bases import FigureCanvasBase

    p = Path(path)
    formats = set(FigureCanvasBase.get_supported_filetypes()) - {"pgf"}  # pgf needs LaTeX
    if p.suffix[1:].lower() not in formats:
        raise UsageError(f"{option} {p}: give a file ending in one of "
                         f"{', '.join('.' + f for f in sorted(formats))}")
    if (p.exists() or p.is_symlink()) and not force:
        raise UsageError(f"{p} exists; pass --force to overwrite it")
    if p.is_dir():
        raise UsageError(f"{option} {p} is a directory")
    if any(parent.exists() and not parent.is_dir() for parent in p.parents):
        raise UsageError(f"{option} {p}: a folder on its path is a file")
    return p


# --------------------------------------------------------------------- maps
def cmd_maps(args: argparse.Namespace) -> int:
    print(f"{'map':<12} {'size':>7} {'free':>6} {'max_steps':>9}  description")
    for name in bundled_maps():
        m = load_map(name)
        first = m.description.split(".")[0].replace("\n", " ")
        print(f"{name:<12} {m.shape[0]:>3}x{m.shape[1]:<3} {m.n_free:>6} {m.max_steps:>9}  "
              f"{first}")
    return 0


# -------------------------------------------------------------------- solve
def cmd_solve(args: argparse.Namespace) -> int:
    plot = check_plot_file(args.plot, args.force) if args.plot else None
    if args.dynamics == "continuous":
        if plot or args.slip:
            raise UsageError("--plot and --slip are options of grid dynamics")
        return solve_continuous(args)
    if args.action or args.resolution:
        raise UsageError("--action and --resolution are options of continuous dynamics")
    navmap = load_map(args.map)
    grid = grid_model(navmap, gamma=args.gamma, slip=args.slip)
    graph = ObjectiveGraph.parse(args.dag, parse_slack(args.slack), objectives=OBJECTIVES,
                                 slack_kind=args.slack_kind, gamma=args.gamma)
    sol = solve_lar(grid.model, graph, relax=args.relax)
    path = grid.rollout(sol.policy)
    reached = bool(grid.model.terminal[grid.index[tuple(path[-1])]])
    summary = {"map": navmap.name, **sol.summary(), "slip": args.slip,
               "path_length": len(path) - 1, "reached_goal": reached}
    if args.json:
        print(json.dumps(summary))
    else:
        print_solution(navmap.name, sol, summary)
    if plot:
        from tpo.envs.render import plot_paths, save_figure

        title = f"{navmap.name}: {graph}, gamma {args.gamma}"
        save_figure(plot_paths(navmap, [path], [f"greedy LAR path ({len(path) - 1} steps)"],
                               title=title), plot)
        if not args.json:
            print(f"path drawn to {plot}")
    return 0


def solve_continuous(args: argparse.Namespace) -> int:
    """The continuous env's finite reference (:mod:`tpo.envs.continuous_model`) solved
    at ``--resolution`` and at twice it, the difference being its discretisation
    error."""
    from tpo.algo.evaluate import CONTINUOUS_TOL
    from tpo.envs import ContinuousNav
    from tpo.envs.continuous_model import RESOLUTION, continuous_model
    from tpo.tabular.judge import tolerance

    resolution = args.resolution or RESOLUTION
    if resolution < 2 or resolution % 2:
        raise UsageError(f"--resolution must be an even number >= 2, got {resolution}")
    navmap = load_map(args.map)
    env = ContinuousNav(navmap, action=args.action or "velocity")
    graph = ObjectiveGraph.parse(args.dag, parse_slack(args.slack), objectives=OBJECTIVES,
                                 slack_kind=args.slack_kind, gamma=args.gamma)
    solved = []
    for n in (resolution, 2 * resolution):
        ref = continuous_model(env, gamma=args.gamma, resolution=n)
        sol = solve_lar(ref.model, graph, relax=args.relax)
        solved.append((ref, sol))
    (ref, sol), (_, fine) = solved
    finer = fine.start_policy_values()
    error = {n: abs(v - finer[n]) for n, v in sol.start_policy_values().items()}
    # Objectives the lattice does not resolve within a continuous verdict's tolerance.
    unresolved = [n for n, e in error.items() if e > tolerance(finer[n], CONTINUOUS_TOL)]
    summary = {"map": navmap.name, "dynamics": "continuous", "action": env.action,
               "resolution": resolution, **sol.summary(), "path": ref.category(sol.policy),
               "discretisation_error": error, "policy_values_at_double_resolution": finer,
               "unresolved": unresolved}
    if args.json:
        print(json.dumps(summary))
        return 0
    print_solution(navmap.name, sol, summary)
    print(f"continuous {env.action} dynamics on a lattice of {resolution}x{resolution} points "
          f"per cell; at {2 * resolution}x{2 * resolution}: "
          + ", ".join(f"{n} {v:.3f} (differs by {error[n]:.3f})"
                      for n, v in finer.items()))
    print("path (more likely than not): " + "; ".join(
        f"{k.replace('_', ' ')}: {'yes' if v else 'no'}" for k, v in summary["path"].items()))
    if unresolved:
        print(f"not resolved: {', '.join(unresolved)} differs by more than a continuous "
              f"verdict's tolerance ({CONTINUOUS_TOL:.0%} or 0.5); solve at --resolution "
              f"{2 * resolution}")
    return 0


def print_solution(name: str, sol: LARSolution, summary: dict) -> None:
    model = sol.model
    print(f"map {name}: {model.n_states} states, gamma {model.gamma:g}, DAG {sol.graph}")
    print(f"{'objective':<10} {'V*(s0)':>10} {'V^pi(s0)':>10}")
    values, policy_values = sol.start_values(), sol.start_policy_values()
    for n in model.objectives:
        own = f"{values[n]:10.3f}" if n in values else f"{'-':>10}"
        print(f"{n:<10} {own} {policy_values[n]:10.3f}")
    print("V*: each objective's own constrained optimum; V^pi: the leaf's greedy policy.")
    feasible = "yes" if sol.feasible else f"no, relaxed at {summary['relaxed_states']}"
    if "path_length" not in summary:
        print(f"feasible: {feasible}")
        return
    end = "reaches the goal" if summary["reached_goal"] else "does not reach the goal"
    print(f"feasible: {feasible}; greedy path: {summary['path_length']} steps, {end}")


# -------------------------------------------------------------------- train
def cmd_train(args: argparse.Namespace) -> int:
    import tomllib

    from tpo.experiments.runs import create_run

    given = {**read_fields(args, RunSpec, skip={"config"}), **read_fields(args, TPOConfig)}
    if args.resume:
        if given or args.config or args.out:
            raise UsageError("--resume continues a run with its own config.toml; "
                             "drop --out, --config and the run options")
        run_dir = Path(args.resume)
        if not (run_dir / "config.toml").exists():
            raise UsageError(f"{run_dir} is not a run directory (no config.toml)")
        with exclusive(run_dir):
            return _train(args, run_dir, RunSpec.from_toml(run_dir / "config.toml", saved=True),
                          None)
    if not args.out:
        raise UsageError("give --out RUN_DIR (or --resume RUN_DIR)")
    settings: dict = {}
    if args.config:
        if not Path(args.config).is_file():
            raise UsageError(f"cannot read --config {args.config}: not a regular file")
        try:
            settings = tomllib.loads(Path(args.config).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
            raise UsageError(f"cannot read --config {args.config}: {err}") from None
    spec = RunSpec.from_settings({**settings, **given})
    spec.check()  # map, DAG, slack, env and budget, before creating anything
    with exclusive(args.out, create=True) as out:
        run_dir, replaced = create_run(out, spec, force=args.force)
        return _train(args, run_dir, spec, replaced)


def _train(args: argparse.Namespace, run_dir: Path, spec: RunSpec, replaced) -> int:
    """Train ``run_dir`` to its end with a progress bar, then print the verdict."""
    from tqdm import tqdm

    from tpo.experiments.runs import train_run

    bars = []  # the bar appears with the first trained chunk: an error before is one line

    def progress(model, metrics: dict, updates: int) -> None:
        if not bars:
            bars.append(tqdm(total=spec.steps, unit="step", unit_scale=True,
                             disable=args.quiet))
        bars[0].update(updates * spec.config.batch_size - bars[0].n)
        bars[0].set_postfix(phase=model.phases[int(metrics["phase"][-1])],
                            ret="/".join(f"{r:.1f}" for r in metrics["episode_return"][-1]))

    try:
        result = train_run(run_dir, episodes=args.episodes, progress=progress,
                           replaced=replaced, trust_module=args.trust_module)
    finally:
        for bar in bars:
            bar.close()
    print_result(result)
    print(f"run written to {run_dir}")
    return 0


def print_result(result: dict) -> None:
    """The learned greedy policy's values beside LAR's, and the three verdicts (exact,
    on a map); the greedy Monte Carlo returns elsewhere."""
    if "reference" in result:
        print_reference_result(result)
        return
    if "exact" not in result:
        greedy = result["mc"]["greedy"]["discounted"]
        print(f"{'objective':<10} {'greedy return (discounted, Monte Carlo)':>40}")
        for name, stats in greedy.items():
            print(f"{name:<10} {stats['mean']:>31.3f} ± {stats['std']:.3f}")
        return
    learned, lar = result["exact"]["greedy"], result["lar"]
    print(f"{'objective':<10} {'learned':>10} {'LAR':>10} {'V*':>10} {'floor':>10}")
    for name, value in learned.items():
        star = lar["values"].get(name)
        floor = lar["floors"].get(name)
        print(f"{name:<10} {value:10.3f} {lar['policy_values'][name]:10.3f} "
              + " ".join(f"{'-' if v is None else f'{v:.3f}':>10}" for v in (star, floor)))
    verdicts = "; ".join(f"{label}: {'yes' if result[key] else 'no'}" for key, label in (
        ("lar_correct", "LAR-correct"), ("strict", "strict"), ("same_values", "same values")))
    print("learned: exact values of the learned greedy policy; LAR: of LAR's policy; V*: each "
          "objective's own optimum; floor: the least LAR allows an ancestor")
    relaxed = "" if lar["feasible"] else " (infeasible: judged against the relaxed solution)"
    print(f"{verdicts}{relaxed}")


def print_reference_result(result: dict) -> None:
    """A continuous run: the noise-free greedy return beside the finite reference's
    LAR values, the value-level verdict and the paths' categories."""
    ref, learned = result["reference"], result["mc_noise_free"]
    noisy = result["mc"]["greedy"]["discounted"]
    print(f"{'objective':<10} {'learned':>10} {'with noise':>10} {'reference':>10} {'V*':>10} "
          f"{'floor':>10}")
    for name, value in learned.items():
        star, floor = ref["values"].get(name), ref["floors"].get(name)
        print(f"{name:<10} {value:10.3f} {noisy[name]['mean']:10.3f} "
              f"{ref['policy_values'][name]:10.3f} "
              + " ".join(f"{'-' if v is None else f'{v:.3f}':>10}" for v in (star, floor)))
    print("learned: discounted return of the greedy policy without noise (with noise: the "
          f"training noise, mean of Monte Carlo episodes); reference: LAR on a lattice of "
          f"{ref['resolution']}x{ref['resolution']} points per cell (tpo solve --dynamics "
          "continuous)")
    paths = "; ".join(f"{key.replace('_', ' ')}: {'yes' if result['path'][key] else 'no'}"
                      f" (reference {'yes' if ref['path'][key] else 'no'})"
                      for key in result["path"])
    relaxed = "" if ref["feasible"] else " (infeasible: judged against the relaxed solution)"
    print(f"LAR-correct at value level (5 %): {'yes' if result['lar_correct'] else 'no'}"
          f"{relaxed}; path: {paths}")


def run_model(args: argparse.Namespace) -> contextlib.AbstractContextManager:
    """A context in which the saved model of ``args.run_dir`` loads (``load()``), no
    other tpo process changing the run meanwhile."""
    from tpo.algo import TPO

    run_dir = Path(args.run_dir)
    # Not a run (load says why), or read-only (no tpo process can change it): no lock.
    locked = (run_dir / "config.toml").is_file() and os.access(run_dir, os.W_OK)

    @contextlib.contextmanager
    def held():
        with exclusive(run_dir) if locked else contextlib.nullcontext():
            yield lambda: TPO.load(run_dir / "model", trust_env_module=args.trust_module)

    return held()


def cmd_eval(args: argparse.Namespace) -> int:
    with run_model(args) as load:
        result = load().evaluate(episodes=args.episodes)
    print(json.dumps(result, indent=2))
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from tpo.algo.export import export_policy

    out = Path(args.out)
    if args.out.endswith(("/", os.sep)) or out.is_dir():
        raise UsageError(f"--out {args.out} is a directory; give a file name")
    if out.exists() or out.is_symlink():
        raise UsageError(f"{out} exists; choose another file name (export replaces nothing)")
    if not out.parent.is_dir():
        raise UsageError(f"--out {out}: the folder {out.parent} does not exist")
    with run_model(args) as load:
        model = load()
        export_policy(model, out, args.format)
    done = "" if model.finished else " (its training is not finished)"
    print(f"policy of {args.run_dir}{done} exported to {out} ({args.format})")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from tpo.envs.render import save_figure
    from tpo.experiments.picture import policy_figure
    from tpo.experiments.runs import check_no_links

    run_dir = Path(args.run_dir)
    outs = ([check_plot_file(args.out, args.force, "--out")] if args.out
            else [run_dir / "policy.png", run_dir / "policy.pdf"])  # the run's own files
    if not args.out:
        check_no_links(run_dir, [out.name for out in outs])
    for out in outs:
        if out.is_dir():
            raise UsageError(f"{out} is a directory; move it, or pass --out FILE")
    with run_model(args) as load:
        fig = policy_figure(load())
    for out in outs:
        save_figure(fig, out)
    print(f"policy drawn to {', '.join(map(str, outs))}")
    return 0


def backend_of(args: argparse.Namespace):
    """The engine's backend that ``--backend``, ``--workers``, ``--address`` and
    ``--storage`` name (:func:`add_backend_options`)."""
    from tpo.experiments.engine import backend

    return backend(args.backend or "local", args.workers, args.address, args.storage)


# ---------------------------------------------------------------- reproduce
def cmd_reproduce(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from tqdm import tqdm

    from tpo.experiments.paper import CONTINUOUS_PANELS, Settings
    from tpo.experiments.reproduce import check_settings, reproduce

    if not args.out.strip():
        raise UsageError("--out must name a directory")
    settings = Settings.quick() if args.quick else Settings()
    changes: dict = {}
    if args.map:
        load_map(args.map)
        changes["map"] = args.map
    if args.slacks:
        slacks = tuple(parse_slack(args.slacks, "--slacks"))
        if len(slacks) < 2 or any(b <= a for a, b in pairwise(slacks)) \
                or slacks[0] < 0:
            raise UsageError("--slacks needs at least two increasing values >= 0")
        changes["slacks"] = slacks
    if args.seeds is not None:
        if not 1 <= args.seeds <= 1000:
            raise UsageError("--seeds must be from 1 to 1000")
        changes["seeds"] = tuple(range(args.seeds))
    if args.steps is not None:
        changes["steps"] = args.steps
    if args.constraint is not None:
        changes["forms"] = {"all": FORMS, "both": ("penalty", "restriction")}.get(
            args.constraint, (args.constraint,))
    if args.completion:
        changes["completion"] = True
    if args.continuous is not None:
        changes["action"] = args.continuous
        if not args.quick:
            changes["continuous"] = CONTINUOUS_PANELS
    if args.continuous_steps is not None:
        changes["continuous_steps"] = args.continuous_steps
    settings = replace(settings, **changes)
    check_settings(settings)  # before the progress bar and before anything is made
    engine = backend_of(args)
    with exclusive(args.out, create=True) as out:
        weights = {name: len(runs) * len(settings.seeds) * settings.steps_of(runs[0][0])
                   for name, _, runs in settings.units()}
        bar = tqdm(total=sum(weights.values()), unit="step", unit_scale=True,
                   disable=args.quiet, desc="reproduce")
        t0 = time.monotonic()

        def progress(fractions: dict[str, float]) -> None:
            bar.update(sum(weights[n] * f for n, f in fractions.items()) - bar.n)

        try:
            result = reproduce(out, settings, progress, engine)
        finally:
            bar.close()
    print(f"{result.summary()}; {time.monotonic() - t0:.0f} s in all")
    return 0


# -------------------------------------------------------------------- sweep
def cmd_sweep(args: argparse.Namespace) -> int:
    from tpo.experiments.slack_sweep import SweepSpec, exact_table, sweep

    if not args.out.strip():
        raise UsageError("--out must name a directory")
    budget = {k: getattr(args, k) for k in ("seeds", "steps", "slacks_per_unit")
              if getattr(args, k) is not None}
    config = read_fields(args, TPOConfig)
    if args.exact_only:  # gamma is part of the exact problem; the rest trains
        given = [*budget, *(k for k in ("backend", "workers", "address", "storage", "profile")
                            if getattr(args, k) is not None), *(k for k in config if k != "gamma")]
        if given:
            raise UsageError(f"--exact-only trains nothing: drop --{given[0].replace('_', '-')}")
    if args.action and args.dynamics != "continuous":
        raise UsageError("--action is an option of --dynamics continuous")
    budget.setdefault("steps", DEFAULT_STEPS[args.dynamics])
    spec = SweepSpec(map=args.map, dag=args.dag, dynamics=args.dynamics,
                     action=args.action or SweepSpec.action, xs=tuple(parse_slack(args.slack)),
                     edge_slack=tuple(v.strip() for v in args.edge_slack.split(","))
                     if args.edge_slack else (), config=learner_defaults(
                         args.dynamics, args.action or SweepSpec.action, args.profile or "",
                         **config),
                     **budget)
    spec.check(learned=not args.exact_only)  # before anything is made
    engine = None if args.exact_only else backend_of(args)
    with exclusive(args.out, create=True) as out:
        if args.exact_only:
            result = sweep(out, spec, exact_only=True, on_exact=lambda c: print(exact_table(c)))
        else:
            result = _learned_sweep(args, out, spec, engine)
    print(result.summary())
    return 0


def _learned_sweep(args: argparse.Namespace, out: Path, spec, engine):
    """The sweep with a progress bar over its runs, after the exact curve."""
    from tqdm import tqdm

    from tpo.experiments.slack_sweep import exact_table, sweep

    runs = {name: len(xs) * spec.seeds for name, xs in spec.units()}
    bars = []

    def on_exact(curve: dict) -> None:
        print(exact_table(curve))
        print(f"exact curve written to {out / 'exact.csv'}; training "
              f"{sum(runs.values())} runs", flush=True)
        bars.append(tqdm(total=sum(runs.values()), unit="run", disable=args.quiet,
                         desc="sweep", bar_format="{desc}: {percentage:3.0f}%|{bar}| "
                         "{n:.1f}/{total_fmt} runs [{elapsed}<{remaining}, {rate_fmt}]"))

    def progress(tracker) -> None:
        bars[0].update(sum(runs[n] * f for n, f in tracker.fractions.items()) - bars[0].n)

    try:
        return sweep(out, spec, engine, on_exact=on_exact, progress=progress)
    finally:
        for bar in bars:
            bar.close()


# ------------------------------------------------------------------- parser
class OneLineParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line, as every other error of tpo."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (see '{self.prog} --help')")


def add_loading_options(p: argparse.ArgumentParser) -> None:
    """What ``train`` and ``eval`` share: the evaluation's episodes, and the one
    package a saved model may import."""
    p.add_argument("--episodes", type=episodes, default=100,
                   help="Monte Carlo episodes (1 to 1,000,000)")
    add_trust_module(p)


def add_trust_module(p: argparse.ArgumentParser) -> None:
    p.add_argument("--trust-module", metavar="PACKAGE",
                   help="the package of a Gymnasium env that a saved model names, to "
                        "import on load (tpo imports no module named in a file otherwise)")


def add_run_dir(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN_DIR", help="run directory written by tpo train")


def add_backend_options(p: argparse.ArgumentParser) -> None:
    """Where the units of a sweep run (:mod:`tpo.experiments.engine`)."""
    p.add_argument("--backend", choices=("local", "ray"), help="local worker processes "
                   "(default) or tasks on a Ray cluster (pip install 'tpo[ray]')")
    p.add_argument("--workers", type=int, help="local: worker processes (default 2)")
    p.add_argument("--address", help="ray: the cluster's address (default auto: the cluster "
                                     "this machine belongs to)")
    p.add_argument("--storage", metavar="DIR",
                   help="ray: a folder every node and this machine share, for the units' "
                        "checkpoints (default: sent to this machine)")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="tpo", description="Multi-objective RL with prioritised, slack-tolerant objectives.")
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of a system error or of a bug in tpo")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("maps", help="list the bundled maps")
    p.set_defaults(handler=cmd_maps)

    p = sub.add_parser("solve", help="exact LAR solution of a map for a DAG and slack")
    p.add_argument("--map", default="home", help="bundled map name or TOML file (default home)")
    p.add_argument("--dag", default="M>A>G",
                   help='objective DAG, e.g. "M>A>G" or "A>G, M>G" (default M>A>G)')
    p.add_argument("--slack", default="0", help="one slack, or one per edge: 0,100")
    p.add_argument("--slack-kind", choices=("local", "global"), default="local",
                   help="local eta (default) or global delta = eta / (1 - gamma)")
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--slip", type=float, default=0.0, help="grid: slip probability (default 0)")
    p.add_argument("--dynamics", choices=("grid", "continuous"), default="grid",
                   help="grid (default) or continuous: the continuous env's finite "
                        "reference, solved at --resolution and twice it")
    p.add_argument("--action", choices=("velocity", "heading"),
                   help="continuous: the action kind (default velocity)")
    p.add_argument("--resolution", type=int,
                   help="continuous: lattice points per cell along each axis, even "
                        "(default 8)")
    p.add_argument("--relax", action="store_true",
                   help="relax infeasible states instead of failing")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", metavar="FILE", help="draw the greedy path to FILE (.png/.pdf)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --plot file")
    p.set_defaults(handler=cmd_solve)

    p = sub.add_parser("train", help="train TPO on a map and write a run directory",
                       description="Train TPO on a map (or a Gymnasium env) into a run "
                                   "directory. Every option of the last four groups is also "
                                   "a config.toml key (with _ for -).",
                       epilog=PROFILES_EPILOG)
    p.add_argument("--config", metavar="FILE.toml",
                   help="settings from TOML (the keys are the option names below, with _); "
                        "options given on the command line win")
    p.add_argument("--out", help="run directory to create")
    p.add_argument("--force", action="store_true", help="replace an existing run directory")
    p.add_argument("--resume", metavar="RUN_DIR",
                   help="continue a run from its last checkpoint (e.g. after a kill)")
    add_loading_options(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_fields(p, RunSpec, "problem and budget", skip={"config"})
    add_fields(p, TPOConfig, "hyperparameters (TPOConfig)", groups=GROUPS)
    p.set_defaults(handler=cmd_train)

    p = sub.add_parser("reproduce", help="the paper's Figures 2 and 3, with plots and report")
    p.add_argument("--out", required=True, help="output directory (resumed if it exists)")
    p.add_argument("--quick", action="store_true",
                   help="small budget on the small map (CI): 2 slacks, 2 seeds, one "
                        "continuous panel")
    p.add_argument("--map", help="bundled map or TOML file (default home)")
    p.add_argument("--slacks", help="slack values of the x-axis (default 0,1,2,5,10,20,50,100)")
    p.add_argument("--seeds", type=int, help="number of seeds (default 5; at most 1000)")
    p.add_argument("--steps", type=int,
                   help="env steps per run of a panel of full share (default 1,000,000; "
                        "each panel's runs train its share: docs/reproduce.md)")
    add_backend_options(p)
    p.add_argument("--constraint", choices=(*FORMS, "both", "all"),
                   help="the form of the learner (default penalty, the default learner's; "
                        "paper: the paper's TPO as printed, Eq. 10's penalized advantage); "
                        "both: penalty and restriction, all: every form, side by side on "
                        "the same seeds")
    p.add_argument("--completion", action="store_true",
                   help="completion phases after the leaf (docs/design.md §5)")
    p.add_argument("--continuous", choices=ACTION_KINDS,
                   help="add the continuous robot's panels (the four DAGs and Figure 3 at "
                        "slack 0 and 100) with velocity or heading actions (--quick runs "
                        "one, with velocity actions unless this names heading)")
    p.add_argument("--continuous-steps", type=int,
                   help="env steps per continuous run of a panel of full share (default "
                        "2,000,000; each panel trains its share: docs/reproduce.md)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(handler=cmd_reproduce)

    p = sub.add_parser("sweep", epilog=PROFILES_EPILOG,
                       help="LAR's curve and TPO's runs against slack, any map",
                       description="A slack sweep of one DAG: LAR's exact curve at once, "
                                   "then TPO trained at every slack x seed (units of slacks "
                                   "x seeds, each one compiled program, on local workers or "
                                   "a Ray cluster), judged exactly. A killed sweep restarted "
                                   "on its --out redoes nothing finished.")
    p.add_argument("--out", required=True, help="output directory (resumed if it exists)")
    p.add_argument("--map", default="home", help="bundled map or TOML file (default home)")
    p.add_argument("--dag", default="M>A>G", help='objective DAG (default "M>A>G")')
    p.add_argument("--slack", required=True,
                   help="the x-axis: increasing slack values, e.g. 0,1,2,5,10,100")
    p.add_argument("--edge-slack", metavar="E,...",
                   help="per edge (in the order tpo solve prints): x for the swept value or "
                        "a fixed slack, e.g. 0,x (default: every edge takes x)")
    p.add_argument("--dynamics", choices=("grid", "continuous"), default="grid",
                   help="grid (default) or continuous: judged at value level against the "
                        "continuous env's finite reference (tpo solve --dynamics continuous)")
    p.add_argument("--action", choices=("velocity", "heading"),
                   help="continuous: the action kind (default velocity)")
    p.add_argument("--exact-only", action="store_true",
                   help="LAR's curve alone (seconds), no training")
    p.add_argument("--seeds", type=int, help="seeds per slack value (default 5)")
    p.add_argument("--steps", type=int,
                   help=f"env steps per run (default {DEFAULT_STEPS['grid']:,}; with "
                        f"--dynamics continuous {DEFAULT_STEPS['continuous']:,})")
    p.add_argument("--slacks-per-unit", type=int,
                   help="slack values per unit of work (one compiled program of these x "
                        "every seed; default 1)")
    add_backend_options(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--profile", metavar="NAME,...",
                   help="the learner's named profile(s), applied in order (listed below; "
                        "default grid, or continuous with --dynamics continuous)")
    add_fields(p, TPOConfig, "hyperparameters (TPOConfig)", groups=GROUPS)
    p.set_defaults(handler=cmd_sweep)

    p = sub.add_parser("eval", help="re-evaluate a saved run directory")
    add_run_dir(p)
    add_loading_options(p)
    p.set_defaults(handler=cmd_eval)

    p = sub.add_parser("export", help="export a run's policy for a robot (ONNX or NumPy)",
                       description="Write the trained actor (greedy action and the action "
                                   "distribution's parameters) with its metadata; run an "
                                   ".npz with tpo.deploy (NumPy only), an .onnx with any "
                                   "ONNX runtime.")
    add_run_dir(p)
    p.add_argument("--format", choices=("onnx", "npz"), required=True)
    p.add_argument("--out", required=True, metavar="FILE", help="file to create")
    add_trust_module(p)
    p.set_defaults(handler=cmd_export)

    p = sub.add_parser("render", help="draw what a run's policy does on its map",
                       description="The greedy action of every cell (red where it leaves "
                                   "LAR's admissible set) and the greedy path, or for a "
                                   "continuous run its trajectories from several starts, "
                                   "beside the run's exact values and LAR's.")
    add_run_dir(p)
    p.add_argument("--out", metavar="FILE",
                   help="figure file (.png, .pdf, ...; default RUN_DIR/policy.png and .pdf)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    add_trust_module(p)
    p.set_defaults(handler=cmd_render)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command. Every error ends in one line on stderr: a user's mistake or
    the system's refusal (a full disk, a read-only directory) with exit code 2, an
    interrupt with 130, anything else (a bug in tpo) with 1; ``--debug`` shows the
    traceback of the last two."""
    args = None
    try:
        args = build_parser().parse_args(argv)
        return args.handler(args)
    except (TPOError, OSError) as err:
        if args is not None and args.debug and not isinstance(err, TPOError):
            raise
        print(f"tpo: error: {_describe(err)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        if args is not None and args.debug:
            raise
        print("tpo: interrupted", file=sys.stderr)
        return 130
    except Exception as err:
        if args is not None and args.debug:
            raise
        text = f"{type(err).__name__}: {err}".replace("\n", " ")
        print(f"tpo: error: internal error {text} (rerun with --debug for the traceback, "
              "and please report it)", file=sys.stderr)
        return 1


def _describe(err: Exception) -> str:
    """One line for an error: an OSError as 'what: file'."""
    if isinstance(err, OSError) and err.strerror:
        files = [f for f in (err.filename, err.filename2) if f is not None]
        return f"{err.strerror}: {' -> '.join(map(str, files))}" if files else err.strerror
    return str(err).replace("\n", " ")


if __name__ == "__main__":
    sys.exit(main())
