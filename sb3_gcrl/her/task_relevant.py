"""Task-relevant HER relabeling, thesis Section 3.4.2 ("Learning to Achieve Relevant Goals in Imagination").

MoReFree trains its goal-conditioned policy on goals drawn from rho_g* with probability alpha/2, from rho_0 with
probability alpha/2 and from replayed states with probability 1 - alpha (Algorithm 2, line 14). The thesis does
this with imagined rollouts of a world model; MoReFree-SAC (:mod:`sb3_gcrl.morefree_sac`) puts the same bias into
HER relabeling: of the relabeled part of each batch (``her_ratio = n_sampled_goal / (n_sampled_goal + 1)``), a
fraction alpha/2 gets an evaluation goal, alpha/2 an initial-state goal, and the rest the standard strategy
(``future`` by default). Rewards are recomputed with the env's ``compute_reward`` as in :class:`HerReplayBuffer`.

alpha is stated once: left out (``task_goal_ratio=None``), it is read from the env's Back-and-Forth scheduler
(:attr:`sb3_gcrl.wrappers.GoalCommandWrapper.task_goal_alpha`), the same alpha that selects the goals of data
collection (Algorithm 2 uses one alpha for both). Give ``task_goal_ratio`` only where the env's scheduler has no
alpha (e.g. the ablation without Back-and-Forth); giving it with a different value than the scheduler's is an error.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from sb3_gcrl.common.validation import check_n_sampled_goal
from sb3_gcrl.her.executed_action import ExecutedActionHerReplayBuffer

#: the env method (provided by :class:`sb3_gcrl.wrappers.GoalCommandWrapper`) serving rho_0 / rho_g* goals for
#: relabeled transitions, drawn with the env's seeded generator
TASK_GOALS_METHOD = "sample_relabel_task_goals"


def _serves_task_goals(env: VecEnv) -> bool:
    """Whether every env of ``env`` serves the task-relevant goals (checked without pickling bound methods)."""
    from sb3_gcrl.wrappers.goal_command import GoalCommandWrapper

    if all(env.env_is_wrapped(GoalCommandWrapper)):
        return True
    try:
        return env.has_attr(TASK_GOALS_METHOD)
    except Exception:  # e.g. a SubprocVecEnv that cannot send the attribute back
        return False


class TaskRelevantHerReplayBuffer(ExecutedActionHerReplayBuffer):
    """HER buffer relabeling toward task-relevant goals (rho_g*, rho_0) w.p. alpha; stores executed actions.

    The env must be wrapped in :class:`~sb3_gcrl.wrappers.GoalCommandWrapper` (or :class:`GoExploreWrapper`),
    which serves the task-relevant goals. From an RL-Zoo YAML (where ``replay_buffer_class`` is ``eval``-ed and a
    dotted path fails) write ``replay_buffer_class: "__import__('sb3_gcrl.her').her.TaskRelevantHerReplayBuffer"``.

    :param args: the :class:`~sb3_gcrl.her.ExecutedActionHerReplayBuffer` arguments (``buffer_size``,
        ``observation_space``, ``action_space``, ``env``: the training VecEnv, which serves ``compute_reward`` and
        the task-relevant goals, ...).
    :param task_goal_ratio: alpha of Section 3.4.2 (thesis: 0.2); 0 gives standard HER (with executed actions);
        ``None`` (default) reads alpha from the env's scheduler.
    :param kwargs: the other :class:`HerReplayBuffer` arguments (``n_sampled_goal``, ``goal_selection_strategy``...);
        ``n_sampled_goal`` must be >= 1 while alpha > 0 (alpha acts on the relabeled goals).
    """

    def __init__(self, *args: Any, task_goal_ratio: float | None = None, **kwargs: Any) -> None:
        if task_goal_ratio is not None and not 0.0 <= task_goal_ratio <= 1.0:
            raise ValueError(f"task_goal_ratio (alpha) must be in [0, 1], got {task_goal_ratio}")
        super().__init__(*args, **kwargs)
        #: alpha as given (None: the env's scheduler's); the alpha in use is :attr:`task_goal_ratio`
        self.given_task_goal_ratio = None if task_goal_ratio is None else float(task_goal_ratio)
        self.task_goal_ratio: float | None = self.given_task_goal_ratio
        if self.env is not None:
            self._resolve_task_goal_ratio(self.env)

    def _resolve_task_goal_ratio(self, env: VecEnv) -> None:
        """Settle alpha against the env: read it from the scheduler, or check the given one matches it."""
        given = self.given_task_goal_ratio
        serves = _serves_task_goals(env)
        alphas = set(env.get_attr("task_goal_alpha")) if serves and env.has_attr("task_goal_alpha") else {None}
        if len(alphas) > 1:
            raise ValueError(f"the envs' schedulers have different alphas {sorted(alphas, key=str)}: use one alpha")
        (env_alpha,) = alphas
        if given is None:
            if env_alpha is None:
                raise ValueError(
                    "TaskRelevantHerReplayBuffer: pass task_goal_ratio (alpha of Sec. 3.4.2), or wrap the env in "
                    "GoExploreWrapper/GoalCommandWrapper with scheduler='back_and_forth', whose alpha is then used"
                )
            self.task_goal_ratio = env_alpha
        elif env_alpha is not None and env_alpha != given:
            raise ValueError(
                f"alpha given twice with different values: task_goal_ratio={given} but the env's back_and_forth "
                f"scheduler has alpha={env_alpha}; drop task_goal_ratio (the scheduler's alpha is used)"
            )
        if self.task_goal_ratio:
            why = (
                f"; task_goal_ratio (alpha) = {self.task_goal_ratio} picks task-relevant goals among the relabeled "
                "ones, so it needs some (or set task_goal_ratio=0)"
            )
            check_n_sampled_goal(self.n_sampled_goal, minimum=1, why=why)
        if self.task_goal_ratio and not serves:
            raise TypeError(
                "TaskRelevantHerReplayBuffer needs the env to serve task-relevant goals: wrap it in "
                "sb3_gcrl.wrappers.GoalCommandWrapper or GoExploreWrapper (env_wrapper in an RL-Zoo YAML), "
                "or set task_goal_ratio=0."
            )

    def set_env(self, env: VecEnv) -> None:
        """Set the env (after loading the buffer) and settle alpha against it."""
        super().set_env(env)
        self._resolve_task_goal_ratio(env)

    def _sample_goals(self, batch_indices: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        goals = super()._sample_goals(batch_indices, env_indices)
        if self.task_goal_ratio is None:
            raise RuntimeError("TaskRelevantHerReplayBuffer has no env to read alpha from: call set_env() first")
        if self.task_goal_ratio == 0.0:
            return goals
        assert self.env is not None, "call set_env() after loading the buffer"
        # the env draws which relabeled transitions get a rho_g* / rho_0 goal (alpha/2 each), with its seeded generator
        rows, task_goals = self.env.env_method(TASK_GOALS_METHOD, len(goals), self.task_goal_ratio, indices=[0])[0]
        goals[rows] = task_goals.reshape(len(rows), *goals.shape[1:])  # the buffer's goal layout (image, Discrete (1,))
        return goals
