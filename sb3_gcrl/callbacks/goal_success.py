"""Commanded-goal success per goal kind, logged as ``rollout/goal_success_<kind>`` (thesis Algorithm 3's goal kinds).

The outermost mode-switched wrapper marks the last step of every training segment with ``info["goal_kind"]`` and the
segment's success (:mod:`sb3_gcrl.wrappers.segments`). :class:`GoalSuccessLog`, called by
:class:`~sb3_gcrl.callbacks.ResetFreeCallback` and :class:`~sb3_gcrl.post_exploration.PostExplorationCallback` at
every step, keeps the last ``window`` segments of each kind and records their success rate in the ``rollout/``
section, next to SB3's own ``rollout/success_rate`` (all kinds together). Kinds are named as in the thesis:
``evaluation`` (rho_g*: "forward", or the env's own goal), ``initial`` (rho_0, "back") and ``exploratory`` (rho_E);
other labels are kept.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.logger import Logger

from sb3_gcrl.common.validation import check_int
from sb3_gcrl.wrappers.segments import GOAL_KIND_KEY, GOAL_KIND_NAMES


class GoalSuccessLog:
    """Success rate of the last ``window`` training segments of each commanded-goal kind.

    :param window: segments per kind in the running mean (SB3's ``stats_window_size`` is 100 too).
    """

    def __init__(self, window: int = 100) -> None:
        self.window = check_int("window", window)
        #: recent successes (0/1) per goal kind, by thesis name
        self.successes: dict[str, deque[float]] = {}
        #: current success rate per logger key
        self.rates: dict[str, float] = {}

    def update(self, infos: Sequence[dict[str, Any]], dones: Sequence[bool] | np.ndarray, logger: Logger) -> None:
        """Add the segments that ended at this step and record every kind's success rate.

        The rates are recorded at every call, so each dump of the logger (SB3's ``rollout/*`` dump, an evaluation's
        dump) holds the current values.

        :param infos: the VecEnv's infos of this step (``self.locals["infos"]`` of a callback).
        :param dones: the VecEnv's dones of this step.
        :param logger: the SB3 logger to record ``rollout/goal_success_<kind>`` in.
        """
        for info, done in zip(infos, dones):
            if not done or GOAL_KIND_KEY not in info:
                continue
            kind = GOAL_KIND_NAMES.get(info[GOAL_KIND_KEY], info[GOAL_KIND_KEY])
            window = self.successes.setdefault(kind, deque(maxlen=self.window))
            window.append(float(info["is_success"]))
            self.rates[f"rollout/goal_success_{kind}"] = float(np.mean(window))
        for key, rate in self.rates.items():
            logger.record(key, rate)
