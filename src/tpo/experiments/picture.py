"""A picture of what a trained policy does (``tpo render``): its greedy action in
every cell of a grid map, coloured where it leaves LAR's admissible set, and its
greedy path; for the continuous env, its trajectories from several starts; beside
either, the run's exact (or reference) values next to LAR's."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from tpo.algo import TPO
from tpo.algo.evaluate import exact_evaluation, greedy_path, reference_evaluation
from tpo.envs.continuous import ContinuousNav
from tpo.envs.grid_model import MOVES
from tpo.envs.render import PATH_COLORS, draw_map, draw_path
from tpo.envs.spec import from_spec
from tpo.errors import TPOError
from tpo.tabular import VERDICTS, solve_lar

ADMISSIBLE_COLOR, OUTSIDE_COLOR = "0.25", "tab:red"
RANDOM_START_COLOR = "tab:orange"
CONTINUOUS_STARTS = 6  # trajectories drawn: the map's start and random starts


def policy_figure(model: TPO) -> Figure:
    """The figure of ``model``'s policy on its map (grid or continuous)."""
    env = model.eval_env
    if hasattr(env, "tabular"):
        return _grid_figure(model)
    if isinstance(env, ContinuousNav):
        return _continuous_figure(model)
    raise TPOError("tpo render draws policies of the navigation maps; this run's env is a "
                   "Gymnasium env of its own")


def _grid_figure(model: TPO) -> Figure:
    env, trainer, gamma = model.eval_env, model._need_trainer(), model.config.gamma
    grid = env.tabular(gamma)
    acting = trainer.acting(model._need_state(), trainer.slack_array())
    greedy = np.asarray(trainer.policy(acting, jnp.asarray(env.tabular_observations())).mode())
    lar = solve_lar(grid.model, model.graph, relax=True)
    allowed = lar.allowed[model.graph.leaf]
    result = exact_evaluation(trainer.policy, acting, env, model.graph, gamma)
    fig, ax, side = _layout(env.navmap)
    moving = ~grid.model.terminal
    cells, actions = grid.cells[moving], greedy[moving]
    inside = allowed[np.flatnonzero(moving), actions]
    for keep, color, label in ((inside, ADMISSIBLE_COLOR, "greedy action"),
                               (~inside, OUTSIDE_COLOR, "outside LAR's admissible set")):
        if keep.any():
            d = MOVES[actions[keep]]
            ax.quiver(cells[keep, 1], cells[keep, 0], d[:, 1] * 0.5, -d[:, 0] * 0.5,
                      color=color, pivot="mid", scale=1, scale_units="xy", width=0.004,
                      label=label)
    path = grid.rollout(greedy)
    draw_path(ax, path, PATH_COLORS[0], f"greedy path ({len(path) - 1} steps)")
    rows = [(n, result["exact"]["greedy"][n], result["lar"]["policy_values"][n],
             result["lar"]["floors"].get(n)) for n in model.env.objectives]
    _side_panel(side, "exact value", rows, result, model)
    _finish(fig, ax, model)
    return fig


def _continuous_figure(model: TPO) -> Figure:
    env, trainer, gamma = model.eval_env, model._need_trainer(), model.config.gamma
    acting = trainer.acting(model._need_state(), trainer.slack_array())
    result = reference_evaluation(trainer.policy, acting, env, model.graph, gamma)
    spec = env.to_spec()
    quiet = from_spec({**spec, "noise": 0.0, "random_start": True})
    fig, ax, side = _layout(env.navmap)
    run = jax.jit(lambda key: greedy_path(trainer.policy, acting, quiet, gamma, key)[:2])
    starts = [(env, None)] + [(quiet, jax.random.key(i)) for i in range(CONTINUOUS_STARTS - 1)]
    for i, (start_env, key) in enumerate(starts):
        if key is None:
            pos, alive = greedy_path(trainer.policy, acting, start_env, gamma)[:2]
        else:
            pos, alive = run(key)
        pos = np.asarray(pos)[np.asarray(alive)] - 0.5  # cell (r, c) is drawn centred at (r, c)
        color = PATH_COLORS[0] if key is None else RANDOM_START_COLOR
        label = "from the start" if key is None else "from random starts" if i == 1 else None
        draw_path(ax, pos, color, label)
        ax.plot(pos[0, 1], pos[0, 0], "o", color=color, markersize=4)
    rows = [(n, result["mc_noise_free"][n], result["reference"]["policy_values"][n],
             result["reference"]["floors"].get(n)) for n in model.env.objectives]
    _side_panel(side, "noise-free", rows, result, model)
    _finish(fig, ax, model)
    return fig


def _layout(navmap: Any) -> tuple[Figure, Axes, Axes]:
    h, w = navmap.shape
    fig = Figure(figsize=(max(4.0, w * 0.3) + 3.4, max(3.4, h * 0.3 + 0.8)))
    grid = fig.add_gridspec(1, 2, width_ratios=[max(4.0, w * 0.3), 3.4])
    ax, side = fig.add_subplot(grid[0]), fig.add_subplot(grid[1])
    draw_map(ax, navmap)
    side.axis("off")
    return fig, ax, side


def _side_panel(ax: Axes, learned: str, rows: list[tuple[str, float, float, float | None]],
                result: dict[str, Any], model: TPO) -> None:
    lines = [f"{'objective':<9} {learned:>11} {'LAR':>8} {'floor':>8}"]
    lines += [f"{n:<9} {v + 0.0:>11.2f} {lar + 0.0:>8.2f} "
              f"{'-' if floor is None else f'{floor + 0.0:.2f}':>8}" for n, v, lar, floor in rows]
    lines.append("")
    verdicts = [k for k in VERDICTS if k in result]
    lines += [f"{k.replace('_', ' ')}: {'yes' if result[k] else 'no'}" for k in verdicts]
    if "path_matches" in result:
        lines.append(f"path as the reference's: {'yes' if result['path_matches'] else 'no'}")
    feasible = result.get("lar", result.get("reference", {})).get("feasible", True)
    if not feasible:
        lines.append("(infeasible: against the relaxed solution)")
    ax.text(0.0, 1.0, "\n".join(lines), family="monospace", fontsize=8, va="top",
            transform=ax.transAxes)


def _finish(fig: Figure, ax: Axes, model: TPO) -> None:
    slack = ", ".join(f"{s:g}" for s in model.graph.slacks)
    ax.set_title(f"{model.env.navmap.name}: {model.graph.spec} at slack ({slack})",
                 fontsize=10)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.01), ncol=2, frameon=False,
              fontsize=8)
    fig.tight_layout()
