"""Callback that switches the training env to reset-free mode and logs interventions and goal statistics.

The reset-free wrappers (:mod:`sb3_gcrl.wrappers`) start episodic, because RL-Zoo builds the eval env with the same
``env_wrapper`` as the train env and evaluation must stay episodic (:mod:`sb3_gcrl.wrappers.mode`). This callback, in
the ``callback`` list of the config, calls ``set_training_mode(True)`` on the *training* env only, at the start of
``learn``; the eval env is never touched and keeps resetting to rho_0 with goals from rho_g* for T_eval steps.

Logged every ``log_freq`` calls (``reset_free/`` prefix): ``interventions`` (physical resets, summed over envs),
``terminal_interventions``, per goal kind (``forward``, ``back``, ``explore``, ...) the number of commanded goals
and the fraction reached since the start, and the share of Go/Explore steps.

Training curves (``rollout/`` prefix, with SB3's next ``rollout/*`` dump): SB3's own ``ep_rew_mean``,
``ep_len_mean`` and ``success_rate`` over the last 100 segments, which the wrappers report as episodes
(:mod:`sb3_gcrl.wrappers.segments`; the Monitor CSV gets one row per segment), and
``goal_success_<evaluation|initial|exploratory>``, the success rate of the last ``window`` segments that were
commanded a goal of that kind (:class:`~sb3_gcrl.callbacks.goal_success.GoalSuccessLog`).
"""

from __future__ import annotations

from sb3_gcrl.callbacks.step_logging import StepLoggingCallback
from sb3_gcrl.her.executed_action import check_stores_executed_actions
from sb3_gcrl.her.first_update import check_her_first_update
from sb3_gcrl.wrappers.mode import switch_training_envs


class ResetFreeCallback(StepLoggingCallback):
    """Switch the training env to training (reset-free) mode; log interventions and commanded-goal statistics.

    :param log_freq: log every ``log_freq`` calls of ``on_step`` (i.e. ``log_freq * n_envs`` env steps).
    :param window: segments per goal kind in ``rollout/goal_success_<kind>``.
    :param verbose: verbosity.
    """

    def _on_training_start(self) -> None:
        env = self.training_env
        switch_training_envs(
            env,
            "sb3_gcrl.callbacks.ResetFreeCallback",
            "sb3_gcrl.wrappers.ResetFreeWrapper (and GoExploreWrapper/GoalCommandWrapper), e.g. with env_wrapper "
            "in the RL-Zoo YAML",
        )
        if env.has_attr("replaces_actions") and any(env.get_attr("replaces_actions")):
            check_stores_executed_actions(self.model, "ResetFreeCallback", "GoExploreWrapper's Explore phase")
        check_her_first_update(self.model, env, self.model._total_timesteps, "ResetFreeCallback")
        if self.verbose > 0:
            print(f"ResetFreeCallback: reset-free mode on for {env.num_envs} training env(s)")

    def log_statistics(self) -> None:
        """Record the current statistics in the SB3 logger (also called at the end of training)."""
        env = self.training_env
        for name in ("interventions", "terminal_interventions"):
            if env.has_attr(name):
                self.logger.record(f"reset_free/{name}", sum(env.get_attr(name)))
        if env.has_attr("goal_counts"):
            counts: dict[str, int] = {}
            reached: dict[str, int] = {}
            for c, r in zip(env.get_attr("goal_counts"), env.get_attr("goal_reached")):
                for kind, value in c.items():
                    counts[kind] = counts.get(kind, 0) + value
                for kind, value in r.items():
                    reached[kind] = reached.get(kind, 0) + value
            for kind, value in counts.items():
                self.logger.record(f"reset_free/goals_{kind}", value)
                self.logger.record(f"reset_free/reached_{kind}", reached.get(kind, 0) / max(value, 1))
        if env.has_attr("phase_steps_total"):
            go = sum(p["go"] for p in env.get_attr("phase_steps_total"))
            explore = sum(p["explore"] for p in env.get_attr("phase_steps_total"))
            self.logger.record("reset_free/explore_step_share", explore / max(go + explore, 1))
