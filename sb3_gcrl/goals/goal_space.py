"""Visited-goal space with per-dimension binning and visit counts (thesis Section 6.4, used by Ch. 3 and Ch. 6).

For continuous tasks the thesis "discretize[s] the whole state space into bins, so the goal space [...] is the
set of bins we have observed so far" (Section 6.4): a goal is drawn by first picking a visited bin, then a point
inside it. :class:`BinnedGoalSpace` keeps the visit count of every bin in one preallocated array indexed by the
flattened bin index, so recording a visit is a few numpy operations and sampling is one pass over the visited
bins.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

WithinBin = Literal["uniform", "visited"]

#: hard cap on the number of bins (counts and representatives are dense arrays)
MAX_BINS = 10_000_000


class BinnedGoalSpace:
    """Goal space of visited bins with visit counts n(g).

    :param low: lower bound of each goal dimension (values below are clipped into the first bin).
    :param high: upper bound of each goal dimension (values above are clipped into the last bin).
    :param n_bins: bins per dimension (an int for all dimensions, or one per dimension); thesis Table 6.3
        ``n_bins``.
    :param within_bin: how a goal is drawn inside a chosen bin: ``"uniform"`` (thesis Section 6.4: uniformly
        inside the bin's box) or ``"visited"`` (the most recent achieved goal recorded in that bin; always a
        reachable point, e.g. never inside a maze wall that shares the bin).
    """

    def __init__(
        self,
        low: np.ndarray | list[float],
        high: np.ndarray | list[float],
        n_bins: int | list[int] = 10,
        within_bin: WithinBin = "uniform",
    ) -> None:
        self.low = np.asarray(low, dtype=np.float64).reshape(-1)
        self.high = np.asarray(high, dtype=np.float64).reshape(-1)
        if self.low.shape != self.high.shape:
            raise ValueError(f"low {self.low.shape} and high {self.high.shape} must have the same shape")
        if not (np.all(np.isfinite(self.low)) and np.all(np.isfinite(self.high))):
            raise ValueError(
                "BinnedGoalSpace needs finite bounds: pass goal_low/goal_high (the goal env's achieved_goal space "
                f"is unbounded), got low={self.low}, high={self.high}"
            )
        if np.any(self.high <= self.low):
            raise ValueError(f"high must exceed low in every dimension, got low={self.low}, high={self.high}")
        self.dim = self.low.shape[0]
        bins = np.broadcast_to(np.asarray(n_bins, dtype=np.int64), (self.dim,)).copy()
        if np.any(bins < 1):
            raise ValueError(f"n_bins must be >= 1 in every dimension, got {n_bins}")
        n_cells = int(np.prod(bins))
        if n_cells > MAX_BINS:
            raise ValueError(f"{n_cells} bins exceed {MAX_BINS}: use fewer n_bins per dimension")
        if within_bin not in ("uniform", "visited"):
            raise ValueError(f"within_bin must be 'uniform' or 'visited', got {within_bin!r}")
        self.n_bins = bins
        self.within_bin: WithinBin = within_bin
        self.bin_width = (self.high - self.low) / bins
        # row-major strides to flatten a multi-index
        self._strides = np.cumprod(np.concatenate([bins[1:], [1]])[::-1])[::-1].astype(np.int64)
        self._counts = np.zeros(n_cells, dtype=np.int64)
        self._representative = np.zeros((n_cells, self.dim), dtype=np.float64)
        # goals recorded one at a time are binned per block (one row copy per env step on the hot path)
        self._pending = np.empty((1024, self.dim), dtype=np.float64)
        self._n_pending = 0

    @property
    def counts(self) -> np.ndarray:
        """Visit count n(g) of every bin (flattened), including goals recorded with :meth:`record`."""
        self.flush()
        return self._counts

    def record(self, goal: np.ndarray) -> None:
        """Record one achieved goal (buffered; binned with the next block or when counts are read)."""
        self._pending[self._n_pending] = goal
        self._n_pending += 1
        if self._n_pending == len(self._pending):
            self.flush()

    def flush(self) -> None:
        """Bin the goals buffered by :meth:`record`."""
        if self._n_pending:
            n, self._n_pending = self._n_pending, 0
            self.add(self._pending[:n])

    @property
    def n_cells(self) -> int:
        """Total number of bins."""
        return self._counts.shape[0]

    @property
    def n_visited(self) -> int:
        """Number of bins visited at least once (the size of the goal space G)."""
        return int(np.count_nonzero(self.counts))

    def bin_index(self, goals: np.ndarray) -> np.ndarray:
        """Flattened bin index of each goal.

        :param goals: array ``(dim,)`` or ``(n, dim)``.
        :return: int array ``()`` or ``(n,)``.
        """
        multi = np.floor((goals - self.low) / self.bin_width).astype(np.int64)
        np.clip(multi, 0, self.n_bins - 1, out=multi)
        return multi @ self._strides

    def add(self, goals: np.ndarray) -> None:
        """Record visits of achieved goals.

        :param goals: array ``(dim,)`` or ``(n, dim)``.
        """
        goals = np.asarray(goals, dtype=np.float64)
        idx = self.bin_index(goals)
        if goals.ndim == 1:
            self._counts[idx] += 1
            self._representative[idx] = goals
        else:
            np.add.at(self._counts, idx, 1)
            self._representative[idx] = goals

    def bin_center(self, idx: np.ndarray) -> np.ndarray:
        """Centre of flattened bins ``idx`` (shape ``(n,)`` -> ``(n, dim)``)."""
        multi = np.stack(np.unravel_index(np.asarray(idx), tuple(self.n_bins)), axis=-1)
        return self.low + (multi + 0.5) * self.bin_width

    def goals_in_bins(self, idx: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Draw one goal inside each bin of ``idx`` according to ``within_bin``.

        :param idx: flattened bin indices ``(n,)``.
        :param rng: random generator.
        :return: goals ``(n, dim)``.
        """
        idx = np.asarray(idx, dtype=np.int64)
        if self.within_bin == "visited":
            return self._representative[idx].copy()
        centre = self.bin_center(idx)
        return centre + (rng.random(centre.shape) - 0.5) * self.bin_width

    def novelty_probabilities(self, tau: float) -> tuple[np.ndarray, np.ndarray]:
        """Count-based novelty distribution over visited bins, thesis Eq. 6.5: p(g) ~ (1/n(g))^tau.

        :param tau: temperature (0: uniform over visited bins; larger: prefer rarely visited bins).
        :return: ``(visited bin indices, probabilities)``.
        """
        visited = np.flatnonzero(self.counts)
        if visited.size == 0:
            raise RuntimeError("No goal visited yet: record achieved goals with add() before sampling")
        # (1/n)^tau computed in log space, max-subtracted, so large counts or tau cannot under/overflow
        logits = -tau * np.log(self.counts[visited].astype(np.float64))
        weights = np.exp(logits - logits.max())
        return visited, weights / weights.sum()

    def sample_novel(self, tau: float, rng: np.random.Generator, n: int = 1) -> np.ndarray:
        """Sample goals by count-based novelty (Eq. 6.5), then inside the chosen bins.

        :param tau: temperature of Eq. 6.5.
        :param rng: random generator.
        :param n: number of goals.
        :return: goals ``(n, dim)``.
        """
        visited, p = self.novelty_probabilities(tau)
        return self.goals_in_bins(rng.choice(visited, size=n, p=p), rng)

    def sample_uniform(self, rng: np.random.Generator, n: int = 1) -> np.ndarray:
        """Sample goals uniformly over visited bins (Eq. 6.5 with tau = 0)."""
        visited = np.flatnonzero(self.counts)
        if visited.size == 0:
            raise RuntimeError("No goal visited yet: record achieved goals with add() before sampling")
        return self.goals_in_bins(rng.choice(visited, size=n), rng)

    def entropy(self) -> float:
        """Entropy (nats) of the visitation distribution over bins (thesis Eq. 6.7)."""
        visited = self.counts[self.counts > 0].astype(np.float64)
        if visited.size == 0:
            return 0.0
        p = visited / visited.sum()
        return float(-(p * np.log(p)).sum())
