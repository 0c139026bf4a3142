"""Per-run scores (final, area under the curve, steps to a threshold) and their aggregates over seeds.

Aggregates follow Agarwal et al. (2021, "Deep RL at the edge of the statistical precipice"): the
interquartile mean (IQM) with a 95% stratified-bootstrap confidence interval, computed by ``rliable``.
With fewer than ``min_runs_for_iqm`` runs (default 3) an IQM and a bootstrap interval say nothing, so
the table shows the plain mean and the [min, max] range of the runs instead, and names the estimator.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.integrate import trapezoid

from sb3_gcrl.common.metrics import visitation_entropy  # Eq. 6.7, re-exported for the reports
from sb3_gcrl.common.validation import check_int

__all__ = [
    "SCORE_COLUMNS",
    "aggregate_scores",
    "iqm_with_ci",
    "probability_of_improvement",
    "run_scores",
    "visitation_entropy",
]

SCORE_COLUMNS: tuple[str, ...] = ("final", "auc")


def run_scores(
    curves: pd.DataFrame, metric: str, final_window: int = 1, solve_threshold: float | None = None
) -> pd.DataFrame:
    """Scores of every run.

    - ``final``: mean of the metric over the run's last ``final_window`` evaluations;
    - ``auc``: normalised area under the curve, trapezoid over env steps divided by the steps spanned
      (the average level during training; equals the value itself for a one-point curve);
    - ``solved_at``: first evaluated step from which the metric stays >= ``solve_threshold`` until the end
      (NaN if the last evaluation is below it, or no threshold): a lucky early evaluation that is lost
      again does not count as solving;
    - ``reached_at``: first evaluated step at which the metric is >= ``solve_threshold`` (NaN if never, or no
      threshold), kept or not: how soon a method first gets there.

    :param curves: tidy curves (``env, method, seed, timesteps`` + metric columns).
    :param metric: the column scored.
    :param final_window: evaluations averaged for ``final``.
    :param solve_threshold: level that counts as solved.
    :return: one row per run: ``env, method, seed, final, auc, solved_at, reached_at, last_timesteps``.
    """
    check_int("final_window", final_window)
    rows = []
    for (env_id, method, seed), run in curves.groupby(["env", "method", "seed"], sort=True):
        run = run.sort_values("timesteps")
        steps = run["timesteps"].to_numpy(dtype=np.float64)
        values = run[metric].to_numpy(dtype=np.float64)
        span = steps[-1] - steps[0]
        auc = float(trapezoid(values, steps) / span) if span > 0 else float(values[-1])
        solved_at = reached_at = np.nan
        if solve_threshold is not None and (values >= solve_threshold).any():
            reached_at = float(steps[np.argmax(values >= solve_threshold)])
        if solve_threshold is not None and values[-1] >= solve_threshold:
            below = np.flatnonzero(values < solve_threshold)
            solved_at = float(steps[below[-1] + 1]) if below.size else float(steps[0])
        rows.append(
            {
                "env": env_id,
                "method": method,
                "seed": seed,
                "final": float(values[-final_window:].mean()),
                "auc": auc,
                "solved_at": solved_at,
                "reached_at": reached_at,
                "last_timesteps": int(steps[-1]),
            }
        )
    columns = ["env", "method", "seed", "final", "auc", "solved_at", "reached_at", "last_timesteps"]
    return pd.DataFrame(rows, columns=columns)


def iqm_with_ci(
    scores: np.ndarray, confidence: float = 0.95, reps: int = 2000, seed: int = 0
) -> tuple[float, float, float]:
    """Interquartile mean over runs (x tasks) and its stratified-bootstrap percentile interval, via ``rliable``.

    The resampling draws from a ``numpy.random.Generator`` seeded with ``seed`` (rliable's own
    ``StratifiedBootstrap`` draws from numpy's global generator), so the interval is reproducible and the global
    random state is left alone.

    :param scores: shape ``(n_runs,)`` or ``(n_runs, n_tasks)``.
    :param confidence: coverage of the interval.
    :param reps: bootstrap replications.
    :param seed: seed of the bootstrap.
    :return: ``(iqm, low, high)``.
    """
    from rliable import library as rly
    from rliable import metrics

    class SeededStratifiedBootstrap(rly.StratifiedBootstrap):
        """rliable's stratified bootstrap (runs resampled within each task) drawing from ``self.generator``."""

        def update_indices(self) -> tuple[np.ndarray, ...]:
            indices = self.generator.choice(self._num_items, self._args_shape, replace=True)
            return (indices, *self._strata_indices)

    matrix = np.asarray(scores, dtype=np.float64)
    matrix = matrix[:, None] if matrix.ndim == 1 else matrix

    def iqm(x: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(x)])

    bootstrap = SeededStratifiedBootstrap(matrix, seed=np.random.default_rng(seed))
    interval = bootstrap.conf_int(iqm, reps=reps, size=confidence, method="percentile")
    return float(iqm(matrix)[0]), float(interval[0, 0]), float(interval[1, 0])


def _summarise(values: np.ndarray, min_runs_for_iqm: int, confidence: float, reps: int, seed: int) -> tuple:
    if len(values) >= min_runs_for_iqm:
        return (*iqm_with_ci(values, confidence, reps, seed), "IQM")
    return float(values.mean()), float(values.min()), float(values.max()), "mean"


def aggregate_scores(
    scores: pd.DataFrame,
    min_runs_for_iqm: int = 3,
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
    planned_runs: dict[tuple[str, str], int] | None = None,
) -> pd.DataFrame:
    """Aggregate the per-run scores of each (env, method).

    :param scores: table from :func:`run_scores`.
    :param min_runs_for_iqm: fewer runs -> mean and [min, max] instead of IQM and bootstrap CI.
    :param confidence: coverage of the intervals.
    :param reps: bootstrap replications.
    :param seed: seed of the bootstrap.
    :param planned_runs: ``(env, method) -> runs planned``, to report finished/planned (default: finished).
    :return: one row per (env, method): ``n_runs, n_planned, estimator``, ``final``/``final_low``/``final_high``,
        ``auc``/``auc_low``/``auc_high``, ``n_solved`` and ``median_solved_at`` (over solving runs), ``n_reached``
        and ``median_reached_at`` (over the runs that reached the threshold at least once).
    """
    rows = []
    for (env_id, method), group in scores.groupby(["env", "method"], sort=False):
        row: dict[str, object] = {"env": env_id, "method": method, "n_runs": len(group)}
        row["n_planned"] = (planned_runs or {}).get((env_id, method), len(group))
        for column in SCORE_COLUMNS:
            value, low, high, estimator = _summarise(
                group[column].to_numpy(dtype=np.float64), min_runs_for_iqm, confidence, reps, seed
            )
            row.update({column: value, f"{column}_low": low, f"{column}_high": high, "estimator": estimator})
        solved = group["solved_at"].dropna()
        row["n_solved"] = len(solved)
        row["median_solved_at"] = float(solved.median()) if len(solved) else np.nan
        reached = group["reached_at"].dropna()
        row["n_reached"] = len(reached)
        row["median_reached_at"] = float(reached.median()) if len(reached) else np.nan
        rows.append(row)
    columns = [
        "env", "method", "n_runs", "n_planned", "estimator",
        "final", "final_low", "final_high", "auc", "auc_low", "auc_high", "n_solved", "median_solved_at",
        "n_reached", "median_reached_at",
    ]  # fmt: skip
    return pd.DataFrame(rows, columns=columns)


def probability_of_improvement(scores_x: np.ndarray, scores_y: np.ndarray) -> float:
    """P(a run of X scores higher than a run of Y), ties counting one half (Mann-Whitney U / (n_x n_y)).

    :param scores_x: scores of method X's runs.
    :param scores_y: scores of method Y's runs.
    """
    x = np.asarray(scores_x, dtype=np.float64)[:, None]
    y = np.asarray(scores_y, dtype=np.float64)[None, :]
    return float(np.mean((x > y) + 0.5 * (x == y)))
