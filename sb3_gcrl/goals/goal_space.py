"""Visited-goal space with per-dimension binning and visit counts (thesis Section 6.4, used by Ch. 3 and Ch. 6).

For continuous tasks the thesis "discretize[s] the whole state space into bins, so the goal space [...] is the
set of bins we have observed so far" (Section 6.4): a goal is drawn by first picking a visited bin, then a point
inside it. :class:`BinnedGoalSpace` keeps the visit count of every bin in one preallocated array indexed by the
flattened bin index, so recording a visit is a few numpy operations and sampling is one pass over the visited
bins.

Bounds: given (``goal_low``/``goal_high``), or inferred from the goals the env shows. A goal env's nominal
``achieved_goal`` bounds are often far wider than the goals that occur (panda-gym: +-10 m around a 0.3 m
workspace), and ten bins over them would put every goal in one bin, so novelty would do nothing. Without given
bounds the box is the bounding box of the goals seen so far (the task-relevant goals at resets and every
achieved goal); when a goal falls outside, the box doubles along that dimension and every two old bins merge
into one new bin, so the counts stay exact and the box stays within a factor 4 of the data's extent.
:func:`binned_goal_space_for` builds the goal space of a gymnasium space (discrete spaces: one bin per value).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from gymnasium import spaces

WithinBin = Literal["uniform", "visited"]

#: hard cap on the number of bins (counts and representatives are dense arrays)
MAX_BINS = 10_000_000
#: smallest extent of an inferred dimension, relative to max(1, |value|) (all goals seen so far equal there)
MIN_RELATIVE_EXTENT = 1e-6


class BinnedGoalSpace:
    """Goal space of visited bins with visit counts n(g).

    :param low: lower bound of each goal dimension (values below are clipped into the first bin); ``None``
        (with ``high=None``) infers the bounds from the goals seen, see the module docstring.
    :param high: upper bound of each goal dimension (values above are clipped into the last bin).
    :param n_bins: bins per dimension (an int for all dimensions, or one per dimension); thesis Table 6.3
        ``n_bins``.
    :param within_bin: how a goal is drawn inside a chosen bin: ``"uniform"`` (thesis Section 6.4: uniformly
        inside the bin's box) or ``"visited"`` (the most recent achieved goal recorded in that bin; always a
        reachable point, e.g. never inside a maze wall that shares the bin).
    :param dim: goal dimension, needed when the bounds are inferred.
    """

    def __init__(
        self,
        low: np.ndarray | list[float] | None = None,
        high: np.ndarray | list[float] | None = None,
        n_bins: int | list[int] = 10,
        within_bin: WithinBin = "uniform",
        dim: int | None = None,
    ) -> None:
        #: whether the bounds are inferred from the goals seen (and grow with them)
        self.adaptive = low is None and high is None
        if self.adaptive:
            if dim is None or int(dim) < 1:
                raise ValueError("BinnedGoalSpace without low/high infers its bounds from the goals seen: pass dim")
            self.low = np.full(int(dim), np.nan)
            self.high = np.full(int(dim), np.nan)
        elif low is None or high is None:
            raise ValueError("pass both goal_low and goal_high, or neither (then the bounds follow the goals seen)")
        else:
            self.low = np.asarray(low, dtype=np.float64).reshape(-1)
            self.high = np.asarray(high, dtype=np.float64).reshape(-1)
            if self.low.shape != self.high.shape:
                raise ValueError(f"low {self.low.shape} and high {self.high.shape} must have the same shape")
            if dim is not None and int(dim) != self.low.shape[0]:
                raise ValueError(f"dim={dim} does not match the {self.low.shape[0]} bounds given")
            if not (np.all(np.isfinite(self.low)) and np.all(np.isfinite(self.high))):
                raise ValueError(
                    "BinnedGoalSpace needs finite bounds: pass finite goal_low/goal_high, or leave both out to infer "
                    f"them from the goals seen; got low={self.low}, high={self.high}"
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
        if self.adaptive and np.isnan(self.low[0]):
            raise RuntimeError("No goal seen yet: the bounds are inferred from the goals, record some with add()")
        multi = np.floor((goals - self.low) / self.bin_width).astype(np.int64)
        np.clip(multi, 0, self.n_bins - 1, out=multi)
        return multi @ self._strides

    def add(self, goals: np.ndarray) -> None:
        """Record visits of achieved goals.

        :param goals: array ``(dim,)`` or ``(n, dim)``.
        """
        goals = np.asarray(goals, dtype=np.float64)
        if self.adaptive:
            self.extend(goals)
        idx = self.bin_index(goals)
        if goals.ndim == 1:
            self._counts[idx] += 1
            self._representative[idx] = goals
        else:
            np.add.at(self._counts, idx, 1)
            self._representative[idx] = goals

    def extend(self, goals: np.ndarray) -> None:
        """Grow inferred bounds to contain ``goals`` without counting them as visits (no-op for given bounds).

        Used for goals the env shows but the agent has not reached (the desired goals at resets, rho_g*), and by
        :meth:`add` for achieved goals. Each growth doubles one dimension and merges pairs of bins, counts exact.

        :param goals: array ``(dim,)`` or ``(n, dim)``.
        """
        if not self.adaptive:
            return
        goals = np.asarray(goals, dtype=np.float64).reshape(-1, self.dim)
        if goals.shape[0] == 0:
            return
        lo, hi = goals.min(axis=0), goals.max(axis=0)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError(f"goals must be finite to infer the goal-space bounds, got {goals}")
        if np.isnan(self.low[0]):  # the first goals set the box
            extent = np.maximum(hi - lo, MIN_RELATIVE_EXTENT * np.maximum(1.0, np.abs(lo)))
            # the box is half-open, [low, high): no goal on the upper edge, so merged bins equal fresh binning
            self.low, self.high = lo.copy(), np.maximum(lo + extent, np.nextafter(hi, np.inf))
            self.bin_width = (self.high - self.low) / self.n_bins
            return
        for d in np.flatnonzero((lo < self.low) | (hi >= self.high)):
            while lo[d] < self.low[d] or hi[d] >= self.high[d]:
                self._double(int(d), downward=bool(lo[d] < self.low[d]))

    def _double(self, d: int, downward: bool) -> None:
        """Double the extent of dimension ``d`` (below or above); old bin i joins new bin (i + offset) // 2."""
        n = int(self.n_bins[d])
        shape = tuple(self.n_bins)
        target = (np.arange(n) + (n if downward else 0)) // 2
        old_counts = np.moveaxis(self._counts.reshape(shape), d, 0)
        old_rep = np.moveaxis(self._representative.reshape(*shape, self.dim), d, 0)
        counts = np.zeros(shape, dtype=np.int64)
        rep = np.zeros((*shape, self.dim), dtype=np.float64)
        new_counts, new_rep = np.moveaxis(counts, d, 0), np.moveaxis(rep, d, 0)
        for i in range(n):
            new_counts[target[i]] += old_counts[i]
            visited = old_counts[i] > 0
            new_rep[target[i]][visited] = old_rep[i][visited]
        self._counts, self._representative = counts.reshape(-1), rep.reshape(-1, self.dim)
        width = self.high[d] - self.low[d]
        if downward:
            self.low[d] -= width
        else:
            self.high[d] += width
        self.bin_width[d] = (self.high[d] - self.low[d]) / n

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


def binned_goal_space_for(
    space: spaces.Space,
    goal_low: np.ndarray | list[float] | None = None,
    goal_high: np.ndarray | list[float] | None = None,
    n_bins: int | list[int] | None = None,
    within_bin: WithinBin = "visited",
) -> BinnedGoalSpace:
    """The binned visited-goal space of a goal env's ``achieved_goal`` space.

    * ``Box`` of one dimension (vector goals): ``n_bins`` (default 10) per dimension over ``goal_low``-``goal_high``,
      or over bounds inferred from the goals seen when both are left out (never the space's nominal bounds,
      which are often far wider than the goals that occur);
    * ``Discrete``, ``MultiBinary``, ``MultiDiscrete`` (e.g. SB3's ``BitFlippingEnv``): one bin per value, i.e.
      count-based novelty over the discrete goals themselves;
    * anything else (an image goal) cannot be binned: a ``ValueError`` names the schedulers that work.

    :param space: the ``achieved_goal`` space.
    :param goal_low: lower bounds (``Box`` only).
    :param goal_high: upper bounds (``Box`` only).
    :param n_bins: bins per dimension (``Box`` only; default 10).
    :param within_bin: see :class:`BinnedGoalSpace` (discrete spaces need ``"visited"``).
    :return: the goal space.
    """
    if isinstance(space, (spaces.Discrete, spaces.MultiBinary, spaces.MultiDiscrete)):
        if goal_low is not None or goal_high is not None or n_bins is not None:
            raise ValueError(
                f"the goal space {space} is discrete and is binned exactly, one bin per value: drop goal_low, "
                "goal_high and n_bins"
            )
        if within_bin != "visited":
            raise ValueError(
                f"the goal space {space} is discrete: use within_bin='visited' (a point drawn uniformly inside a bin "
                "is not a value of the space)"
            )
        if isinstance(space, spaces.Discrete):
            start, sizes = np.array([int(space.start)]), np.array([int(space.n)])
        elif isinstance(space, spaces.MultiBinary):
            if len(space.shape) != 1:
                raise ValueError(f"a MultiBinary goal space must be one-dimensional to be binned, got {space.shape}")
            start, sizes = np.zeros(space.shape[0], dtype=np.int64), np.full(space.shape[0], 2)
        else:
            if space.nvec.ndim != 1:
                raise ValueError(f"a MultiDiscrete goal space must be one-dimensional to be binned, got {space.shape}")
            start, sizes = np.asarray(space.start, dtype=np.int64), np.asarray(space.nvec, dtype=np.int64)
        if float(np.prod(sizes.astype(np.float64))) > MAX_BINS:
            raise ValueError(
                f"the discrete goal space {space} has more than {MAX_BINS} values, too many to count visits densely: "
                "use scheduler='env_default' or 'evaluation', or a GoalScheduler of your own"
            )
        return BinnedGoalSpace(start - 0.5, start + sizes - 0.5, sizes.tolist(), "visited")
    if isinstance(space, spaces.Box) and len(space.shape) <= 1:
        bins = 10 if n_bins is None else n_bins
        if goal_low is None and goal_high is None:
            return BinnedGoalSpace(None, None, bins, within_bin, dim=int(np.prod(space.shape)))
        return BinnedGoalSpace(goal_low, goal_high, bins, within_bin)
    raise ValueError(
        f"binned visited-goal schedulers ('novelty', 'uniform_visited') count visits per bin of each goal dimension; "
        f"the goal space {space} (shape {space.shape}, e.g. an image goal) cannot be binned. Use scheduler="
        "'env_default' or 'evaluation', 'back_and_forth' with exploratory='env_default', or a GoalScheduler of your own"
    )
