"""Visit counts of the training envs for the exploration metrics of thesis Ch. 6.

The metrics themselves, visitation entropy (Eq. 6.7) and coverage (Fig. 6.4), are in :mod:`sb3_gcrl.common.metrics`
(re-exported here and by :mod:`sb3_gcrl.post_exploration`).
"""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from sb3_gcrl.common.metrics import coverage, visitation_entropy

__all__ = ["coverage", "training_visit_counts", "visitation_entropy"]


def training_visit_counts(env: VecEnv) -> np.ndarray | None:
    """Visit counts of the goal-space bins, summed over the training envs that keep them.

    :param env: training envs; those wrapped in a :class:`~sb3_gcrl.wrappers.GoalCommandWrapper` with a
        visited-goal scheduler (e.g. :class:`~sb3_gcrl.post_exploration.PostExplorationWrapper`, ``novelty``)
        expose its ``goal_space``.
    :return: the summed ``counts``, or None when no env counts visits.
    """
    if not env.has_attr("goal_space"):
        return None
    spaces = [space for space in env.get_attr("goal_space") if space is not None]
    if not spaces:
        return None
    return np.sum([space.counts for space in spaces], axis=0)
