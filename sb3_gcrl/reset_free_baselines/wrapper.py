"""Forward/backward phases of the reset-free baselines MEDAL and R3L (thesis Ch. 3, Section 3.7.2).

MEDAL (Sharma et al. 2022) and R3L (Zhu et al. 2020) alternate two controllers in one reset-free stream: a forward
policy commanded the task goal g* ~ rho_g*, then a backward policy that brings the agent back (to the demonstrations'
states, MEDAL) or perturbs it (to novel states, R3L), then the forward policy again. The official MEDAL code switches
after ``policy_switch_frequency`` = 300 steps, and ends a forward phase early when the task goal is reached.

This is built on the package's reset-free layer, not beside it:

* :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` (below) does the physical resets (interventions), the evaluation-mode
  episodes and cuts each phase after ``segment_length`` steps (MEDAL's switch frequency);
* :class:`ForwardBackwardWrapper` is a :class:`~sb3_gcrl.wrappers.GoalCommandWrapper` whose
  :class:`ForwardBackwardScheduler` commands a rho_g* goal at every segment and labels the segments ``"forward"`` and
  ``"backward"`` alternately (forward first after every physical reset). The wrapper adds only the early end of a
  forward segment at the task goal, and exposes the phase of the next step as :attr:`ForwardBackwardWrapper.phase`,
  which :class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardSAC` reads to choose the controller and the buffer.

Evaluation mode (the eval env, ``rl_zoo3 enjoy``) is the :class:`GoalCommandWrapper`'s: the env's own goal, episodes
of ``eval_horizon`` steps, and the phase is always ``"forward"`` (the forward policy is the one evaluated).
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from stable_baselines3.common.env_util import unwrap_wrapper

from sb3_gcrl.common.validation import check_bool
from sb3_gcrl.goals.schedulers import EvaluationGoalScheduler
from sb3_gcrl.goals.task_goals import TaskRelevantGoals
from sb3_gcrl.wrappers.goal_command import GoalCommandWrapper
from sb3_gcrl.wrappers.goal_env import record_constructor_args
from sb3_gcrl.wrappers.reset_free import ResetFreeWrapper

#: the two phases, in the order they alternate
PHASES = ("forward", "backward")


class ForwardBackwardScheduler(EvaluationGoalScheduler):
    """A task goal g* ~ rho_g* for every segment; the segments are labelled forward and backward in turn.

    Each call to :meth:`next_goal` (a new segment) switches the phase; the first segment after a physical reset in
    training mode is a forward one (MEDAL's code starts the forward policy after a hard reset). The phase before the
    first call is forward: the segment that starts in evaluation mode, before the training env is switched to
    training mode, counts as a forward one, so the next is a backward one.

    :param task_goals: the env's task-relevant goals.
    """

    kind = "forward"

    def __init__(self, task_goals: TaskRelevantGoals) -> None:
        super().__init__(task_goals)
        self._physical_reset = False

    def reset_pending(self) -> None:
        """After a physical reset the next segment is a forward one."""
        self._physical_reset = True

    def next_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        self.kind = "forward" if self._physical_reset or self.kind == "backward" else "backward"
        self._physical_reset = False
        return super().next_goal(obs, rng)


class ForwardBackwardWrapper(GoalCommandWrapper):
    """Alternate forward and backward segments on a reset-free goal env (MEDAL's and R3L's data collection).

    Wrap a :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` whose ``segment_length`` is the phase length (MEDAL: 300).

    :param env: goal env wrapped in :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` with a ``segment_length``.
    :param end_forward_on_success: end a forward segment as soon as the task goal is reached (MEDAL's code does).
    :param success_distance: see :class:`~sb3_gcrl.wrappers.GoalCommandWrapper`.
    :param task_goal_capacity: see :class:`~sb3_gcrl.wrappers.GoalCommandWrapper`.
    """

    def __init__(
        self,
        env: gym.Env,
        end_forward_on_success: bool = True,
        success_distance: float | None = None,
        task_goal_capacity: int = 10_000,
    ) -> None:
        # record this class's arguments (so gym.make can re-create the wrapper), before the parent records its own
        record_constructor_args(self, locals())
        reset_free = unwrap_wrapper(env, ResetFreeWrapper)
        if reset_free is None or reset_free.segment_length is None:
            raise ValueError(
                "ForwardBackwardWrapper needs a ResetFreeWrapper below it with segment_length set (the phase length, "
                "MEDAL: 300): wrap the env as ForwardBackwardWrapper(ResetFreeWrapper(env, segment_length=300, ...))"
            )
        super().__init__(env, "evaluation", None, success_distance, task_goal_capacity)
        self.scheduler = ForwardBackwardScheduler(self.task_goals)
        self.end_forward_on_success = check_bool("end_forward_on_success", end_forward_on_success)
        #: steps taken in each phase (training mode)
        self.forward_backward_steps = dict.fromkeys(PHASES, 0)

    @property
    def phase(self) -> str:
        """The phase of the next step: ``"forward"`` or ``"backward"`` (always ``"forward"`` in evaluation mode)."""
        return self.scheduler.kind if self.training else "forward"

    def _training_step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        phase = self.phase
        obs, reward, terminated, truncated, info = super()._training_step(action)
        self.forward_backward_steps[phase] += 1
        info["phase"] = phase
        if phase == "forward" and self.end_forward_on_success and info["is_success"]:
            truncated = True  # MEDAL switches to the backward policy at the task goal
        return obs, reward, terminated, truncated, info
