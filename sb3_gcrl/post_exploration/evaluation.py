"""The chapter's metric: greedy success at reaching *every* goal (thesis Sec. 6.5.1).

Unlike Go-Explore, which scores one final goal, the thesis tests "the ability of the agent to reach every
possible state in the whole state space" with the greedy policy. :func:`evaluate_all_goals` does this for
discrete goal envs (every reachable goal of a :class:`~sb3_gcrl.imgep.TabularGoalEnv`) and for continuous goal
envs (a fixed grid of goals over the reachable space, commanded through ``reset(options={"goal": g})`` of
:class:`~sb3_gcrl.post_exploration.PostExplorationWrapper` or any env accepting that option);
:class:`AllGoalsEvalCallback` runs it periodically and logs ``eval/all_goals_success``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback


def evaluate_all_goals(
    model: BaseAlgorithm,
    env: gym.Env,
    goals: np.ndarray | None = None,
    max_steps: int | None = None,
    stop_on_loop: bool = True,
) -> np.ndarray:
    """Greedy success for every goal (one episode per goal).

    :param model: a goal-conditioned model (``predict`` on Dict observations).
    :param env: a goal env whose ``reset(options={"goal": g})`` commands ``g`` and whose ``info["is_success"]``
        says whether it was reached (e.g. :class:`~sb3_gcrl.imgep.TabularGoalEnv` with ``terminate_at_goal``).
    :param goals: goals to test (default: ``env.reachable_goals``).
    :param max_steps: step cap per goal (default: the env's time limit ends the episode).
    :param stop_on_loop: stop a goal as failed as soon as the greedy policy revisits an observation. Exact for
        deterministic envs and policies (the tabular MiniGrid tasks): the agent is then in a cycle. Only used for
        Discrete observations.
    :return: boolean array, one entry per goal.
    """
    if goals is None:
        goals = getattr(env.unwrapped if not hasattr(env, "reachable_goals") else env, "reachable_goals", None)
        if goals is None:
            raise ValueError("Pass goals=... (the env declares no reachable_goals)")
    goals = np.asarray(goals)
    tabular = isinstance(env.observation_space, gym.spaces.Dict) and isinstance(
        env.observation_space["observation"], gym.spaces.Discrete
    )
    q = getattr(getattr(model, "policy", None), "q", None) if tabular else None
    success = np.zeros(len(goals), dtype=bool)
    for i, goal in enumerate(goals):
        obs, _ = env.reset(options={"goal": goal})
        seen: set[int] = set()
        steps = 0
        while True:
            if q is not None:
                state = int(obs["observation"])
                if stop_on_loop:
                    if state in seen:
                        break
                    seen.add(state)
                action: Any = int(q[state, int(goal)].argmax())
            else:
                action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            steps += 1
            if info.get("is_success", False):
                success[i] = True
                break
            if terminated or truncated or (max_steps is not None and steps >= max_steps):
                break
    return success


class AllGoalsEvalCallback(BaseCallback):
    """Every ``eval_freq`` steps, log the greedy success rate over all goals (``eval/all_goals_success``).

    The history is kept in :attr:`timesteps` / :attr:`success_rates` (and per goal in :attr:`per_goal`) for
    curves (Fig. 6.3 / 6.5).

    :param eval_env: separate goal env for evaluation (see :func:`evaluate_all_goals`).
    :param eval_freq: evaluate every this many training env steps (at the first step at or past each multiple,
        so any ``n_envs`` works), at the start and at the end of training.
    :param goals: goals to test (default: the env's ``reachable_goals``).
    :param max_steps: step cap per goal.
    :param verbose: 1 prints each result.
    """

    def __init__(
        self,
        eval_env: gym.Env,
        eval_freq: int = 10_000,
        goals: np.ndarray | None = None,
        max_steps: int | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if int(eval_freq) < 1:
            raise ValueError(f"eval_freq must be >= 1, got {eval_freq}")
        self.eval_env = eval_env
        self.eval_freq = int(eval_freq)
        self.goals = goals
        self.max_steps = max_steps
        self.timesteps: list[int] = []
        self.success_rates: list[float] = []
        self.per_goal: list[np.ndarray] = []
        self._last_eval = -1
        self._next_eval = self.eval_freq

    def _evaluate(self) -> None:
        if self._last_eval == self.num_timesteps:
            return  # on_training_end may follow an evaluation at the same step
        self._last_eval = self.num_timesteps
        success = evaluate_all_goals(self.model, self.eval_env, self.goals, self.max_steps)
        self.timesteps.append(self.num_timesteps)
        self.success_rates.append(float(success.mean()))
        self.per_goal.append(success)
        self.logger.record("eval/all_goals_success", float(success.mean()))
        if self.verbose:
            print(f"{self.num_timesteps} steps: success over {success.size} goals = {success.mean():.3f}")

    def _on_training_start(self) -> None:
        self._evaluate()
        self._next_eval = (self.num_timesteps // self.eval_freq + 1) * self.eval_freq

    def _on_step(self) -> bool:
        # ">=" and not "% eval_freq == 0": with n_envs > 1, num_timesteps grows by n_envs and can skip multiples
        if self.num_timesteps >= self._next_eval:
            self._evaluate()
            self._next_eval = (self.num_timesteps // self.eval_freq + 1) * self.eval_freq
        return True

    def _on_training_end(self) -> None:
        self._evaluate()
