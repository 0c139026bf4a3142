"""Base of the callbacks that log the statistics of a training env's mode-switched wrappers while SB3 steps it.

:class:`~sb3_gcrl.callbacks.ResetFreeCallback` and :class:`~sb3_gcrl.post_exploration.PostExplorationCallback` share
one loop: at every step they record the commanded-goal success per goal kind
(:class:`~sb3_gcrl.callbacks.goal_success.GoalSuccessLog`), every ``log_freq`` steps and at the end of training their
own statistics (:meth:`StepLoggingCallback.log_statistics`).
"""

from __future__ import annotations

from abc import abstractmethod

from stable_baselines3.common.callbacks import BaseCallback

from sb3_gcrl.callbacks.goal_success import GoalSuccessLog
from sb3_gcrl.common.validation import check_int


class StepLoggingCallback(BaseCallback):
    """Record the goal success per kind at every step, and :meth:`log_statistics` every ``log_freq`` calls of
    ``on_step`` and at the end of training.

    :param log_freq: log the statistics every ``log_freq`` calls of ``on_step`` (i.e. ``log_freq * n_envs`` env
        steps).
    :param window: segments (episodes) per goal kind in ``rollout/goal_success_<kind>``.
    :param verbose: verbosity.
    """

    def __init__(self, log_freq: int = 1000, window: int = 100, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.log_freq = check_int("log_freq", log_freq)
        self.goal_success = GoalSuccessLog(window)

    def _on_step(self) -> bool:
        # SB3 calls on_step before it reads the infos, so these values join its next rollout/* dump
        self.goal_success.update(self.locals["infos"], self.locals["dones"], self.logger)
        if self.n_calls % self.log_freq == 0:
            self.log_statistics()
        return True

    def _on_training_end(self) -> None:
        self.log_statistics()

    @abstractmethod
    def log_statistics(self) -> None:
        """Record the current statistics in the SB3 logger."""
