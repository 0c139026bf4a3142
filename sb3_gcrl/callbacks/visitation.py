"""Replay-buffer visitation analysis, thesis Fig. 3.5 and Section 3.8: heatmaps and task-relevant percentage.

The thesis shows state-visitation heatmaps of each agent's replay buffer and overlays the percentage of
"task-relevant" states, i.e. states in the initial or goal regions. Here a replay state (its ``achieved_goal``) is
task-relevant when it lies within ``radius`` of a sample of rho_0 or rho_g* (drawn from the env through
:meth:`sb3_gcrl.wrappers.GoalCommandWrapper.sample_task_goals`, or given explicitly).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback


def nearest_distances(achieved: np.ndarray, targets: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Euclidean distance from each ``achieved`` goal to its nearest ``targets`` row.

    :param achieved: visited goals ``(n, dim)``.
    :param targets: goals to measure against, e.g. samples of rho_0 and rho_g* ``(m, dim)``.
    :param chunk: rows per distance block (bounds memory at ``chunk * m`` floats).
    :return: ``(n,)`` distances.
    """
    nearest = np.empty(len(achieved), dtype=np.float64)
    for start in range(0, len(achieved), chunk):
        block = achieved[start : start + chunk, None, :] - targets[None, :, :]
        nearest[start : start + chunk] = np.einsum("ijk,ijk->ij", block, block).min(axis=1)
    return np.sqrt(nearest)


def task_relevant_fraction(achieved: np.ndarray, task_goals: np.ndarray, radius: float, chunk: int = 4096) -> float:
    """Fraction of ``achieved`` goals within ``radius`` of at least one task-relevant goal.

    :param achieved: visited goals ``(n, dim)``.
    :param task_goals: samples of rho_0 and rho_g* ``(m, dim)``.
    :param radius: distance under which a state counts as task-relevant (e.g. the env's success threshold).
    :param chunk: rows per distance block (bounds memory at ``chunk * m`` floats).
    :return: fraction in [0, 1] (0 for an empty ``achieved``).
    """
    if len(achieved) == 0:
        return 0.0
    return float(np.mean(nearest_distances(achieved, task_goals, chunk) <= radius))


def visitation_histogram(
    achieved: np.ndarray,
    low: np.ndarray | list[float],
    high: np.ndarray | list[float],
    n_bins: int = 50,
    dims: tuple[int, int] = (0, 1),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """2-D visitation histogram of two goal dimensions (Fig. 3.5 style).

    :param achieved: visited goals ``(n, dim)``.
    :param low: lower bounds of the two plotted dimensions.
    :param high: upper bounds of the two plotted dimensions.
    :param n_bins: bins per axis.
    :param dims: the two goal dimensions to plot (e.g. ``(0, 2)`` for the XZ plane of Fetch).
    :return: ``(counts (n_bins, n_bins), x edges, y edges)``.
    """
    x, y = achieved[:, dims[0]], achieved[:, dims[1]]
    hist, xedges, yedges = np.histogram2d(x, y, bins=n_bins, range=[[low[0], high[0]], [low[1], high[1]]])
    return hist, xedges, yedges


class VisitationCallback(BaseCallback):
    """Log the task-relevant percentage of the replay buffer; save its visitation histogram at the end.

    :param radius: task-relevance radius in goal space (e.g. the env's success threshold, 0.45 for PointMaze).
    :param low: lower bounds of the two plotted goal dimensions.
    :param high: upper bounds of the two plotted goal dimensions.
    :param log_freq: log every ``log_freq`` calls of ``on_step``.
    :param n_bins: heatmap bins per axis.
    :param dims: the two goal dimensions of the heatmap.
    :param n_task_samples: samples drawn from each of rho_0 and rho_g* to define the task-relevant regions.
    :param max_states: states subsampled from the buffer for the logged percentage (bounds the cost).
    :param save_path: folder for ``visitation.npz`` and ``visitation.png`` at the end of training (None: no files).
    :param verbose: verbosity.
    """

    def __init__(
        self,
        radius: float,
        low: list[float],
        high: list[float],
        log_freq: int = 10_000,
        n_bins: int = 50,
        dims: tuple[int, int] = (0, 1),
        n_task_samples: int = 256,
        max_states: int = 20_000,
        save_path: str | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if radius <= 0 or log_freq < 1:
            raise ValueError(f"need radius > 0 and log_freq >= 1, got radius={radius}, log_freq={log_freq}")
        self.radius = radius
        self.low, self.high = list(low), list(high)
        self.log_freq = log_freq
        self.n_bins = n_bins
        self.dims = tuple(dims)
        self.n_task_samples = n_task_samples
        self.max_states = max_states
        self.save_path = save_path
        self.last_fraction: float | None = None
        self._task_goals: np.ndarray | None = None
        self._rng = np.random.default_rng(0)

    def _on_training_start(self) -> None:
        if not self.training_env.has_attr("sample_task_goals"):
            raise TypeError(
                "VisitationCallback needs the training env wrapped in sb3_gcrl.wrappers.GoalCommandWrapper or "
                "GoExploreWrapper (it serves the task-relevant goals)"
            )
        buffer = getattr(self.model, "replay_buffer", None)
        if buffer is None or not isinstance(getattr(buffer, "next_observations", None), dict):
            raise TypeError("VisitationCallback needs an off-policy model with a Dict (goal-env) replay buffer")

    def task_goals(self) -> np.ndarray:
        """rho_0 and rho_g* samples (drawn once, from the first training env)."""
        if self._task_goals is None:
            env = self.training_env
            initial = env.env_method("sample_task_goals", "initial", self.n_task_samples, indices=[0])[0]
            evaluation = env.env_method("sample_task_goals", "evaluation", self.n_task_samples, indices=[0])[0]
            self._task_goals = np.concatenate([initial, evaluation])
        return self._task_goals

    def buffer_goals(self) -> np.ndarray:
        """All achieved goals stored in the replay buffer, shape ``(n, goal_dim)``."""
        buffer: Any = self.model.replay_buffer  # type: ignore[attr-defined]
        size = buffer.buffer_size if buffer.full else buffer.pos
        achieved = buffer.next_observations["achieved_goal"][:size]
        return achieved.reshape(-1, achieved.shape[-1]).astype(np.float64)

    def _on_step(self) -> bool:
        if self.n_calls % self.log_freq == 0:
            goals = self.buffer_goals()
            if len(goals) > self.max_states:
                goals = goals[self._rng.choice(len(goals), self.max_states, replace=False)]
            self.last_fraction = task_relevant_fraction(goals, self.task_goals(), self.radius)
            self.logger.record("reset_free/task_relevant_pct", 100.0 * self.last_fraction)
        return True

    def _on_training_end(self) -> None:
        goals = self.buffer_goals()
        if len(goals) == 0:
            return
        self.last_fraction = task_relevant_fraction(goals, self.task_goals(), self.radius)
        self.logger.record("reset_free/task_relevant_pct", 100.0 * self.last_fraction)
        if self.save_path is None:
            return
        hist, xedges, yedges = visitation_histogram(goals, self.low, self.high, self.n_bins, self.dims)  # type: ignore[arg-type]
        os.makedirs(self.save_path, exist_ok=True)
        np.savez(
            os.path.join(self.save_path, "visitation.npz"),
            hist=hist,
            xedges=xedges,
            yedges=yedges,
            task_relevant_fraction=self.last_fraction,
            task_goals=self.task_goals(),
        )
        from sb3_gcrl.analysis.plots import plot_visitation_heatmap  # matplotlib/seaborn only when plotting

        plot_visitation_heatmap(
            hist,
            bounds=((xedges[0], xedges[-1]), (yedges[0], yedges[-1])),
            title=f"replay buffer ({100 * self.last_fraction:.1f}% task-relevant)",
            path=os.path.join(self.save_path, "visitation.png"),
            points=self.task_goals()[:, list(self.dims)],
        )
