"""Callback that switches post-exploration on for the training env and logs the chapter's statistics."""

from __future__ import annotations

import numpy as np

from sb3_gcrl.callbacks.step_logging import StepLoggingCallback
from sb3_gcrl.her.executed_action import check_stores_executed_actions
from sb3_gcrl.post_exploration.metrics import coverage, training_visit_counts, visitation_entropy
from sb3_gcrl.wrappers.mode import switch_training_envs


class PostExplorationCallback(StepLoggingCallback):
    """Enable :class:`~sb3_gcrl.post_exploration.PostExplorationWrapper` training mode; log its statistics.

    At the start of training it calls ``set_training_mode(True)`` on the training env only (the eval env that
    RL-Zoo wraps the same way stays episodic) and checks that the replay buffer stores executed actions. Every
    ``log_freq`` calls it records (``post_exploration/`` prefix): ``steps`` (post-exploration steps so far),
    ``goals_reached_rate`` (commanded goals reached per episode), ``goal_space_size`` (visited bins),
    ``visitation_entropy`` (Eq. 6.7 over the bins of the goal space) and ``coverage`` (fraction of those bins
    visited; the bins cover the box ``goal_low``-``goal_high``, walls included). Training curves: the wrapper reports
    every IMGEP episode as an SB3 episode (``rollout/ep_rew_mean``, ``success_rate``, the Monitor CSV), and this
    callback records ``rollout/goal_success_<kind>`` (kind of the commanded goal, e.g. ``exploratory`` for novelty
    goals) over the last ``window`` episodes.

    :param log_freq: log every this many calls of ``on_step``.
    :param require_executed_actions: raise when the replay buffer would store the ignored policy actions
        (use :class:`~sb3_gcrl.her.ExecutedActionHerReplayBuffer`).
    :param window: episodes per goal kind in ``rollout/goal_success_<kind>``.
    :param verbose: 1 prints when training mode is switched on and the statistics at the end of training.
    """

    def __init__(
        self, log_freq: int = 1000, require_executed_actions: bool = True, window: int = 100, verbose: int = 0
    ) -> None:
        super().__init__(log_freq, window, verbose)
        self.require_executed_actions = require_executed_actions

    def _on_training_start(self) -> None:
        env = self.training_env
        if not env.has_attr("switching_callback"):
            raise TypeError(
                "PostExplorationCallback: the training env is not wrapped in "
                "sb3_gcrl.post_exploration.PostExplorationWrapper; add it (e.g. env_wrapper in the RL-Zoo YAML)"
            )
        if self.require_executed_actions:
            check_stores_executed_actions(self.model, "PostExplorationCallback", "post-exploration")
        switch_training_envs(
            env, "sb3_gcrl.post_exploration.PostExplorationCallback", "sb3_gcrl.post_exploration.PostExplorationWrapper"
        )
        if self.verbose > 0:
            print(f"PostExplorationCallback: IMGEP training mode on for {env.num_envs} training env(s)")

    def _on_training_end(self) -> None:
        super()._on_training_end()
        if self.verbose > 0:
            values = self.logger.name_to_value
            print(
                "PostExplorationCallback: "
                + ", ".join(f"{key.split('/')[1]}={values[key]:.4g}" for key in values if key.startswith("post_expl"))
            )

    def log_statistics(self) -> None:
        """Record the statistics in the SB3 logger."""
        env = self.training_env
        episodes = sum(env.get_attr("episodes"))
        self.logger.record("post_exploration/steps", sum(env.get_attr("post_exploration_steps")))
        self.logger.record("post_exploration/goals_reached_rate", sum(env.get_attr("goals_reached")) / max(episodes, 1))
        counts = training_visit_counts(env)
        if counts is not None:
            self.logger.record("post_exploration/goal_space_size", int(np.count_nonzero(counts)))
            self.logger.record("post_exploration/visitation_entropy", visitation_entropy(counts))
            self.logger.record("post_exploration/coverage", coverage(counts))
