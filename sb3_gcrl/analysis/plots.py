"""Figures: learning curves with confidence bands (Figs. 3.4, 4.3-4.6, 6.3, 6.5 analogues), state-visitation
heatmaps (Fig. 3.5), coverage maps (Fig. 6.4 c-d) and the 2M memory choice over time (Fig. 5.6, top row).

Figures are built with matplotlib's object API (``matplotlib.figure.Figure``, no ``pyplot`` state), so they
can be made in worker processes and on machines without a display. Every function returns the figure and
saves it when ``path`` is given.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import seaborn as sns
from matplotlib.axes import Axes
from matplotlib.colors import ListedColormap, LogNorm
from matplotlib.figure import Figure

#: axis labels of the curve metrics
METRIC_LABELS: dict[str, str] = {
    "success_rate": "success rate",
    "mean_return": "evaluation return",
    "all_goals_success": "success over all goals",
    "visitation_entropy": "visitation entropy (nats)",
}

#: colours of the two memories of 2M (the thesis's Fig. 5.6 uses orange for EC and grey for RL)
MEMORY_COLORS: dict[str, str] = {"ec": "#f28e2b", "rl": "#8c8c8c"}


def method_colors(methods: Sequence[str]) -> dict[str, tuple[float, float, float]]:
    """A colour-blind-safe colour per method, stable across the panels of a figure."""
    palette = sns.color_palette("colorblind", n_colors=max(len(methods), 1))
    return dict(zip(methods, palette))


def _save(figure: Figure, path: str | Path | None) -> Figure:
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        figure.savefig(path, dpi=150, bbox_inches="tight")
    return figure


def plot_learning_curves(
    aggregated: pd.DataFrame,
    metrics: dict[str, str] | str,
    path: str | Path | None = None,
    title: str | None = None,
    confidence: float = 0.95,
) -> Figure:
    """One panel per env: mean curve of each method with its bootstrap confidence band.

    :param aggregated: table from :func:`sb3_gcrl.analysis.curves.aggregate_curves` (may hold several envs).
    :param metrics: the metric shown, or one per env.
    :param path: where to save (png, pdf, svg...).
    :param title: figure title.
    :param confidence: coverage of the bands (for the legend text only).
    :return: the figure.
    """
    envs = list(dict.fromkeys(aggregated["env"]))
    if not envs:
        raise ValueError("No curves to plot (every run failed or none finished)")
    colors = method_colors(list(dict.fromkeys(aggregated["method"])))
    figure = Figure(figsize=(4.6 * len(envs), 3.4), layout="constrained")
    with sns.axes_style("whitegrid"):  # the style applies to axes created inside the block
        axes = figure.subplots(1, len(envs), squeeze=False)[0]
        for ax, env_id in zip(axes, envs):
            metric = metrics if isinstance(metrics, str) else metrics[env_id]
            for method, curve in aggregated[aggregated["env"] == env_id].groupby("method", sort=False):
                n_runs = int(curve["n_runs"].max())
                ax.plot(curve["timesteps"], curve["mean"], color=colors[method], label=f"{method} (n={n_runs})")
                ax.fill_between(curve["timesteps"], curve["low"], curve["high"], color=colors[method], alpha=0.2, lw=0)
            ax.set_title(env_id)
            ax.set_xlabel("env steps")
            ax.set_ylabel(METRIC_LABELS.get(metric, metric))
            if metric == "success_rate":
                ax.set_ylim(-0.03, 1.03)
            ax.grid(alpha=0.3)
        axes[0].legend(
            loc="best", fontsize="small", title=f"mean, {confidence:.0%} bootstrap CI", title_fontsize="small"
        )
    if title:
        figure.suptitle(title)
    return _save(figure, path)


def visitation_counts(
    positions: np.ndarray, bins: int | Sequence[int], bounds: Sequence[Sequence[float]]
) -> np.ndarray:
    """2-D histogram of visited positions (e.g. the agent's x, y) for :func:`plot_visitation_heatmap`.

    :param positions: shape ``(n, 2)``.
    :param bins: bins per axis.
    :param bounds: ``((x_min, x_max), (y_min, y_max))``.
    :return: counts of shape ``(bins_x, bins_y)`` (x along the first axis).
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 2:
        raise ValueError(f"positions must have shape (n, 2), got {positions.shape}")
    counts, _, _ = np.histogram2d(positions[:, 0], positions[:, 1], bins=bins, range=bounds)
    return counts


def plot_visitation_heatmap(
    counts: np.ndarray,
    bounds: Sequence[Sequence[float]] | None = None,
    relevant: np.ndarray | None = None,
    ax: Axes | None = None,
    title: str | None = None,
    path: str | Path | None = None,
    points: np.ndarray | None = None,
) -> Figure:
    """State-visitation heatmap on a log colour scale (Fig. 3.5 analogue).

    :param counts: visits per cell, shape ``(n_x, n_y)`` (x along the first axis, as :func:`visitation_counts`).
    :param bounds: ``((x_min, x_max), (y_min, y_max))`` of the grid, for axis ticks in env units.
    :param relevant: boolean mask of task-relevant cells (initial and goal regions); outlined in white and
        their share of all visits written in the corner, as in the thesis.
    :param ax: axes to draw into (default: a new figure).
    :param title: panel title.
    :param path: where to save.
    :param points: optional ``(n, 2)`` positions drawn as small white dots (e.g. samples of rho_0 / rho_g*).
    :return: the figure.
    """
    counts = np.asarray(counts, dtype=np.float64)
    if counts.ndim != 2 or np.any(counts < 0) or not np.all(np.isfinite(counts)):
        raise ValueError("counts must be a finite, non-negative 2-D array")
    figure, ax = _figure_and_axes(ax)
    extent = None if bounds is None else (bounds[0][0], bounds[0][1], bounds[1][0], bounds[1][1])
    visited = np.ma.masked_less_equal(counts.T, 0)
    norm = LogNorm(vmin=1, vmax=max(counts.max(), 1))
    image = ax.imshow(visited, origin="lower", extent=extent, cmap="viridis", norm=norm, interpolation="nearest")
    ax.set_facecolor("#20124d")
    figure.colorbar(image, ax=ax, label="visits")
    if relevant is not None:
        relevant = np.asarray(relevant, dtype=bool)
        if relevant.shape != counts.shape:
            raise ValueError(f"relevant mask shape {relevant.shape} != counts shape {counts.shape}")
        ax.contour(
            relevant.T.astype(float), levels=[0.5], colors="white", linewidths=1.5, origin="lower", extent=extent
        )
        share = counts[relevant].sum() / max(counts.sum(), 1.0)
        ax.text(0.02, 0.97, f"task-relevant: {share:.1%}", transform=ax.transAxes, va="top", color="white", fontsize=9)
    if points is not None:
        points = np.asarray(points, dtype=np.float64)
        ax.scatter(points[:, 0], points[:, 1], s=4, c="white", alpha=0.5)
    if title:
        ax.set_title(title)
    return _save(figure, path)


def plot_coverage_map(
    counts: np.ndarray,
    walls: np.ndarray | None = None,
    goal: tuple[int, int] | None = None,
    ax: Axes | None = None,
    title: str | None = None,
    path: str | Path | None = None,
) -> Figure:
    """Coverage of a grid world (Fig. 6.4 c-d analogue): visit counts per cell, walls black, unvisited white.

    :param counts: visits per cell, shape ``(width, height)`` indexed ``[x, y]`` (MiniGrid convention).
    :param walls: boolean mask of wall cells, same shape.
    :param goal: ``(x, y)`` of a goal cell to outline in green.
    :param ax: axes to draw into.
    :param title: panel title; the share of free cells visited is appended.
    :param path: where to save.
    :param points: optional ``(n, 2)`` positions drawn as small white dots (e.g. samples of rho_0 / rho_g*).
    :return: the figure.
    """
    counts = np.asarray(counts, dtype=np.float64)
    walls = np.zeros(counts.shape, dtype=bool) if walls is None else np.asarray(walls, dtype=bool)
    if walls.shape != counts.shape:
        raise ValueError(f"walls mask shape {walls.shape} != counts shape {counts.shape}")
    figure, ax = _figure_and_axes(ax)
    free = ~walls
    coverage = float(np.mean(counts[free] > 0)) if free.any() else 0.0
    shown = np.ma.masked_where((counts <= 0) | walls, counts).T
    ax.set_facecolor("white")
    image = ax.imshow(shown, cmap="YlOrRd", norm=LogNorm(vmin=1, vmax=max(counts.max(), 1)), interpolation="nearest")
    ax.imshow(np.ma.masked_where(~walls.T, walls.T), cmap=ListedColormap(["black"]), interpolation="nearest")
    figure.colorbar(image, ax=ax, label="visits")
    if goal is not None:
        ax.add_patch(_cell_outline(goal, "green"))
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(f"{title + ': ' if title else ''}{coverage:.0%} of free cells visited")
    return _save(figure, path)


def plot_memory_choice(
    timesteps: np.ndarray,
    uses_ec: np.ndarray,
    curve: np.ndarray | None = None,
    curve_label: str = "evaluation return",
    title: str | None = None,
    path: str | Path | None = None,
) -> Figure:
    """Which memory 2M evaluates with over training (Fig. 5.6, top row), optionally above its return curve.

    :param timesteps: evaluation steps, shape ``(n_points,)``.
    :param uses_ec: shape ``(n_runs, n_points)`` (or ``(n_points,)``), True where the evaluation used 2M-EC
        (Eq. 5.6 picks the memory with the higher mean return over its last 50 training episodes).
    :param curve: evaluation returns, shape ``(n_runs, n_points)``, drawn below as mean and min-max band.
    :param curve_label: y label of the curve panel.
    :param title: figure title.
    :param path: where to save.
    :return: the figure; the top panel stacks the share of runs using EC (orange) and RL (grey).
    """
    timesteps = np.asarray(timesteps, dtype=np.float64)
    uses_ec = np.atleast_2d(np.asarray(uses_ec, dtype=bool))
    if uses_ec.shape[1] != timesteps.shape[0]:
        raise ValueError(f"uses_ec has {uses_ec.shape[1]} points but timesteps has {timesteps.shape[0]}")
    share_ec = uses_ec.mean(axis=0)
    n_rows = 1 if curve is None else 2
    figure = Figure(figsize=(5.0, 1.6 + 2.4 * (n_rows - 1)), layout="constrained")
    axes = figure.subplots(n_rows, 1, sharex=True, squeeze=False, height_ratios=[1, 3][:n_rows])[:, 0]
    # one bar per evaluation, centred on its step and as wide as the spacing of the schedule
    width = float(np.min(np.diff(timesteps))) if len(timesteps) > 1 else 1.0
    axes[0].bar(timesteps, share_ec, width=width, color=MEMORY_COLORS["ec"], label="2M-EC")
    axes[0].bar(timesteps, 1 - share_ec, width=width, bottom=share_ec, color=MEMORY_COLORS["rl"], label="2M-RL")
    axes[0].set_ylim(0, 1)
    axes[0].set_ylabel("share of runs")
    axes[0].legend(loc="upper right", fontsize="x-small", ncols=2)
    if curve is not None:
        curve = np.atleast_2d(np.asarray(curve, dtype=np.float64))
        axes[1].plot(timesteps, curve.mean(axis=0), color="C0")
        axes[1].fill_between(timesteps, curve.min(axis=0), curve.max(axis=0), color="C0", alpha=0.2, lw=0)
        axes[1].set_ylabel(curve_label)
    axes[-1].set_xlabel("env steps")
    if title:
        figure.suptitle(title)
    return _save(figure, path)


def _figure_and_axes(ax: Axes | None) -> tuple[Figure, Axes]:
    if ax is not None:
        return ax.figure, ax  # type: ignore[return-value]
    figure = Figure(figsize=(4.6, 3.8), layout="constrained")
    return figure, figure.add_subplot()


def _cell_outline(cell: tuple[int, int], color: str):  # noqa: ANN202 (matplotlib patch)
    from matplotlib.patches import Rectangle

    return Rectangle((cell[0] - 0.5, cell[1] - 0.5), 1, 1, fill=False, edgecolor=color, linewidth=2)
