"""Exploration metrics of thesis Ch. 6: visitation entropy (Eq. 6.7) and coverage (Fig. 6.4).

Both are computed from a table of visit counts ``n(x_i)`` over ``N`` bins of the state (or goal) space:
continuous spaces are discretised per dimension by the shared :class:`~sb3_gcrl.goals.BinnedGoalSpace`
(its ``counts``), discrete (tabular) spaces use their own indices as bins. Shared by the IMGEP agent
(:mod:`sb3_gcrl.imgep`), post-exploration (:mod:`sb3_gcrl.post_exploration`) and the reports
(:mod:`sb3_gcrl.analysis`), which all depend on this module and not on each other.
"""

from __future__ import annotations

import numpy as np

__all__ = ["coverage", "visitation_entropy"]


def visitation_entropy(counts: np.ndarray, base: float | None = None) -> float:
    """Entropy of the visitation distribution (thesis Eq. 6.7).

    ``H = -sum_i p(x_i) log p(x_i)`` with ``p(x_i) = n(x_i) / sum_j n(x_j)``; empty bins contribute 0.

    :param counts: visit counts ``n(x_i)`` of the ``N`` bins (any shape, non-negative).
    :param base: logarithm base; ``None`` for the natural logarithm (nats). The thesis does not state the
        base; the maximum is ``log(N)`` (uniform visitation).
    :return: the entropy (0 when nothing was visited).
    """
    counts = np.asarray(counts, dtype=np.float64).ravel()
    if np.any(counts < 0) or not np.all(np.isfinite(counts)):
        raise ValueError("Visit counts must be finite and non-negative")
    total = counts.sum()
    if total == 0:
        return 0.0
    p = counts[counts > 0] / total
    entropy = float(-(p * np.log(p)).sum())
    if base is not None:
        entropy /= np.log(base)
    return entropy


def coverage(counts: np.ndarray, reachable: np.ndarray | None = None) -> float:
    """Fraction of (reachable) bins visited at least once.

    :param counts: visit counts per bin.
    :param reachable: optional boolean mask of the bins that can be reached at all (e.g. the free cells
        of a maze); by default every bin counts.
    :return: coverage in [0, 1].
    """
    counts = np.asarray(counts).ravel()
    if reachable is None:
        return float(np.count_nonzero(counts) / counts.size)
    reachable = np.asarray(reachable, dtype=bool).ravel()
    if reachable.shape != counts.shape:
        raise ValueError(f"reachable mask has {reachable.size} bins, counts have {counts.size}: pass one per bin")
    n_reachable = int(reachable.sum())
    if n_reachable == 0:
        raise ValueError("reachable mask selects no bin")
    return float(np.count_nonzero(counts[reachable]) / n_reachable)
