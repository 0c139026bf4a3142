"""Learning curves: load per-run evaluation CSVs and average them over seeds with bootstrap confidence bands."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pandas as pd

#: metrics a curve can show, in order of preference (success when the env reports it)
METRICS: tuple[str, ...] = ("success_rate", "mean_return")

#: identifying columns of a tidy curves table
KEY_COLUMNS: tuple[str, ...] = ("env", "method", "seed")


def load_curves(runs: Iterable[tuple[str, str, int, Path]]) -> pd.DataFrame:
    """Concatenate per-run ``evaluations.csv`` files into one tidy table.

    :param runs: ``(env_id, method, seed, csv_path)`` per run.
    :return: columns ``env, method, seed`` + the CSV's columns, sorted by env, method, seed, timesteps.
    """
    frames = []
    for env_id, method, seed, path in runs:
        frame = pd.read_csv(path)
        frame.insert(0, "seed", seed)
        frame.insert(0, "method", method)
        frame.insert(0, "env", env_id)
        frames.append(frame)
    if not frames:
        return pd.DataFrame(columns=[*KEY_COLUMNS, "timesteps", *METRICS])
    return pd.concat(frames, ignore_index=True).sort_values([*KEY_COLUMNS, "timesteps"], ignore_index=True)


def choose_metric(curves: pd.DataFrame) -> str:
    """``success_rate`` when every evaluation of the table reports it, else ``mean_return``.

    :param curves: tidy curves of one env (or more).
    """
    if "success_rate" in curves and len(curves) and curves["success_rate"].notna().all():
        return "success_rate"
    return "mean_return"


def bootstrap_mean_ci(
    values: np.ndarray, confidence: float = 0.95, n_resamples: int = 2000, rng: np.random.Generator | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over runs and its percentile-bootstrap confidence interval, for every column at once.

    :param values: shape ``(n_runs, n_points)``; NaN-free.
    :param confidence: coverage of the interval.
    :param n_resamples: bootstrap resamples (runs drawn with replacement).
    :param rng: random generator (default: seeded with 0, so reports are reproducible).
    :return: ``(mean, low, high)``, each of shape ``(n_points,)``; with a single run low = high = mean.
    """
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2 or values.shape[0] == 0:
        raise ValueError(f"values must have shape (n_runs >= 1, n_points), got {values.shape}")
    mean = values.mean(axis=0)
    n_runs = values.shape[0]
    if n_runs == 1:
        return mean, mean.copy(), mean.copy()
    rng = rng if rng is not None else np.random.default_rng(0)
    indices = rng.integers(0, n_runs, size=(n_resamples, n_runs))
    resampled_means = values[indices].mean(axis=1)  # (n_resamples, n_points)
    alpha = (1.0 - confidence) / 2.0
    low, high = np.quantile(resampled_means, [alpha, 1.0 - alpha], axis=0)
    return mean, low, high


def aggregate_curves(
    curves: pd.DataFrame, metric: str, confidence: float = 0.95, n_resamples: int = 2000, seed: int = 0
) -> pd.DataFrame:
    """Mean curve and bootstrap band per (env, method), on the evaluation steps shared by all its runs.

    Runs of one method are evaluated at the same scheduled steps; a run that stopped early (failed runs are
    not loaded, but a budget may differ) only contributes to the steps it has: the band at each step uses the
    runs that reached it, and ``n_runs`` says how many.

    :param curves: tidy table from :func:`load_curves`.
    :param metric: column to aggregate (``success_rate`` or ``mean_return``).
    :param confidence: coverage of the band.
    :param n_resamples: bootstrap resamples.
    :param seed: seed of the bootstrap.
    :return: columns ``env, method, timesteps, mean, low, high, n_runs``.
    """
    rng = np.random.default_rng(seed)
    rows = []
    for (env_id, method), group in curves.groupby(["env", "method"], sort=True):
        table = group.pivot_table(index="seed", columns="timesteps", values=metric, aggfunc="mean")
        complete = table.columns[table.notna().all(axis=0)]
        # steps every run reached: one vectorised bootstrap; the others (some runs shorter): step by step
        blocks = [(list(complete), table[complete].to_numpy())] if len(complete) else []
        blocks += [([step], table[step].dropna().to_numpy()[:, None]) for step in table.columns.difference(complete)]
        for steps, values in blocks:
            mean, low, high = bootstrap_mean_ci(values, confidence, n_resamples, rng)
            rows.extend(
                {"env": env_id, "method": method, "timesteps": step, "mean": m, "low": lo, "high": hi}
                | {"n_runs": values.shape[0]}
                for step, m, lo, hi in zip(steps, mean, low, high)
            )
    result = pd.DataFrame(rows, columns=["env", "method", "timesteps", "mean", "low", "high", "n_runs"])
    return result.sort_values(["env", "method", "timesteps"], ignore_index=True)
