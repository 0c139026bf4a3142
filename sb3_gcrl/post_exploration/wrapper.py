"""Post-exploration for deep goal-conditioned agents (thesis Ch. 6, Algorithm 3 with DDPG/SAC + HER).

:class:`PostExplorationWrapper` is a :class:`~sb3_gcrl.wrappers.GoalCommandWrapper` (shared goal commanding:
the goal space of visited bins with counts and the count-based novelty scheduler of Eq. 6.5 live in
:mod:`sb3_gcrl.goals`). In training mode, switched on for the training env by
:class:`~sb3_gcrl.post_exploration.PostExplorationCallback`, each episode is one IMGEP episode:

1. a goal is commanded at reset (``scheduler="novelty"``, ``tau`` of Table 6.3);
2. the agent acts; when the commanded goal is reached (first success), post-exploration starts if enabled: the
   wrapper replaces the agent's actions by uniformly random ones for ``rule.length(...)`` steps (thesis: a fixed
   ``n_pe``), reports each as ``info["executed_action"]`` so that
   :class:`~sb3_gcrl.her.ExecutedActionHerReplayBuffer` stores the action actually executed, then ends the
   episode (``truncated``, so SB3 bootstraps); without post-exploration the episode ends at the goal;
3. the whole episode, post-exploration included, is one HER episode ('future', k = 4).

``info["is_success"]`` stays True for the rest of the episode once the goal was reached, so SB3's
``rollout/success_rate`` (read at the episode's last step) is the goal-reaching rate. These episodes end above SB3's
``Monitor`` (it sees only the ones that hit the env's time limit), so the wrapper reports each one itself, as
``info["episode"]`` and a row of the Monitor's CSV (:mod:`sb3_gcrl.wrappers.segments`): ``rollout/ep_rew_mean`` and
``rl_zoo3 plot_train`` count every episode, the successful ones included.

In episodic mode (the eval env that RL-Zoo builds with the same ``env_wrapper``; ``rl_zoo3 enjoy``) the env's own
goal is used and nothing is replaced; ``reset(options={"goal": g})`` commands ``g`` instead, which
:func:`~sb3_gcrl.post_exploration.evaluate_all_goals` uses for the all-goals evaluation.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from sb3_gcrl.common.validation import check_bool
from sb3_gcrl.goals.goal_space import BinnedGoalSpace
from sb3_gcrl.goals.schedulers import GoalScheduler
from sb3_gcrl.post_exploration.rules import NoveltyAdaptive, PostExplorationRule, make_post_exploration_rule
from sb3_gcrl.wrappers.go_explore import EXECUTED_ACTION_KEY
from sb3_gcrl.wrappers.goal_command import GoalCommandWrapper, scalar_reward
from sb3_gcrl.wrappers.goal_env import record_constructor_args

#: info key marking post-exploration steps
POST_EXPLORATION_KEY = "post_exploration"


class PostExplorationWrapper(GoalCommandWrapper):
    """IMGEP episodes with optional post-exploration after the commanded goal is reached (Algorithm 3).

    :param env: a gymnasium-robotics style goal env (FetchReach, PointMaze, ``GCRL/*Goal-v0``).
    :param post_exploration: the on/off switch of the chapter's ablation.
    :param n_pe: post-exploration length in steps (thesis Table 6.3: 30 FetchReach, 50 PointUMaze).
    :param p_pe: alternatively a fraction of the steps taken to reach the goal (Table 6.2, tabular: 0.5).
    :param adaptive: alternatively ``True`` / kwargs of :class:`~sb3_gcrl.post_exploration.NoveltyAdaptive`.
        Exactly one of ``n_pe``, ``p_pe``, ``adaptive``, or a ready ``rule``.
    :param rule: a :class:`~sb3_gcrl.post_exploration.PostExplorationRule` (Python use).
    :param scheduler: goal scheduler or its name (default ``"novelty"``, Eq. 6.5); see
        :class:`~sb3_gcrl.wrappers.GoalCommandWrapper`.
    :param scheduler_kwargs: kwargs of :func:`~sb3_gcrl.goals.make_scheduler`, e.g. ``{"tau": 0.01,
        "goal_low": [-1.5, -1.5], "goal_high": [1.5, 1.5], "n_bins": 100, "within_bin": "uniform"}``.
    :param success_distance: see :class:`~sb3_gcrl.wrappers.GoalCommandWrapper`.

    ``set_training_mode(True)`` (called by the callback) switches training mode on: command goals, post-explore,
    end episodes at the goal; episodes stay episodic (no reset-free segments).
    """

    switching_callback = "sb3_gcrl.post_exploration.PostExplorationCallback"

    run_state_attributes = (
        *GoalCommandWrapper.run_state_attributes,
        "post_exploration_steps",
        "episodes",
        "goals_reached",
    )

    def __init__(
        self,
        env: gym.Env,
        post_exploration: bool = True,
        n_pe: int | None = None,
        p_pe: float | None = None,
        adaptive: bool | dict[str, Any] | None = None,
        rule: PostExplorationRule | None = None,
        scheduler: GoalScheduler | str = "novelty",
        scheduler_kwargs: dict[str, Any] | None = None,
        success_distance: float | None = None,
    ) -> None:
        # record this class's arguments (so gym.make can re-create the wrapper), before the parent records its own
        record_constructor_args(self, locals())
        super().__init__(env, scheduler, scheduler_kwargs, success_distance)
        if rule is None:
            rule = make_post_exploration_rule(n_pe=n_pe, p_pe=p_pe, adaptive=adaptive)
        elif n_pe or p_pe or adaptive:
            raise ValueError("Give either rule or one of n_pe / p_pe / adaptive, not both")
        if not isinstance(rule, PostExplorationRule):
            raise TypeError(f"rule must be a PostExplorationRule, got {type(rule).__name__}")
        self.rule = rule
        self.post_exploration = check_bool("post_exploration", post_exploration)
        self.goal_space: BinnedGoalSpace | None = getattr(self.scheduler, "goal_space", None)
        if self.goal_space is None and isinstance(rule, NoveltyAdaptive):
            raise ValueError(
                "adaptive post-exploration needs visit counts: use a visited-goal scheduler ('novelty' or "
                "'uniform_visited' with goal_low/goal_high/n_bins)"
            )
        #: totals over the wrapper's life (training mode): post-exploration steps, episodes, goals reached
        self.post_exploration_steps = 0
        self.episodes = 0
        self.goals_reached = 0
        self._post_left = 0
        self._steps = 0
        self._reached_episode = False
        self._requested_goal: np.ndarray | None = None

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if seed is not None:
            self.action_space.seed(seed)
        options = dict(options or {})
        requested = options.pop("goal", None)
        obs, info = super().reset(seed=seed, options=options or None)
        if requested is not None:  # explicit goal (all-goals evaluation), in either mode
            self._set_goal(requested)
            self._requested_goal = self.goal
            obs = self._command(obs)
        else:
            self._requested_goal = None
        self._post_left, self._steps, self._reached_episode = 0, 0, False
        if self.training:
            self.episodes += 1
        return obs, info

    def _visits(self, goal: np.ndarray) -> tuple[float, float]:
        """``n(g)`` of the goal's bin and the median count over visited bins (0, 0 without a goal space)."""
        if self.goal_space is None:
            return 0.0, 0.0
        counts = self.goal_space.counts
        return float(counts[self.goal_space.bin_index(goal)]), float(np.median(counts[counts > 0]))

    def _evaluation_step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        if self._requested_goal is None:
            return super()._evaluation_step(action)
        obs, _, terminated, truncated, info = self.env.step(action)
        reward = scalar_reward(self._compute_reward(obs["achieved_goal"], self._goal_obs, info))
        info["is_success"] = self.is_success(obs["achieved_goal"], self.goal, info)  # type: ignore[arg-type]
        return self._command(obs), reward, terminated, truncated, info

    def _training_step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        post_exploring = self._post_left > 0
        if post_exploring:
            action = self.action_space.sample()
        obs, reward, terminated, truncated, info = super()._training_step(action)
        self._steps += 1
        info[POST_EXPLORATION_KEY] = post_exploring
        if post_exploring:
            info[EXECUTED_ACTION_KEY] = action
            self.post_exploration_steps += 1
            self._post_left -= 1
            if self._post_left == 0:
                truncated = True
        elif info["is_success"] and not self._reached_episode:
            self._reached_episode = True
            self.goals_reached += 1
            length = 0
            if self.post_exploration:
                length = self.rule.length(self._steps, *self._visits(self.goal))  # type: ignore[arg-type]
            if length > 0:
                self._post_left = length
            else:
                truncated = True  # thesis: the episode ends at the goal without post-exploration
        info["is_success"] = self._reached_episode
        return obs, reward, terminated, truncated, info
