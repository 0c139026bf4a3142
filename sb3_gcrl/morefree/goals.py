"""Goals of the model-based MoReFree agent: PEG exploratory goals, the agent's Explore actions, imagination goals.

The Back-and-Forth schedule (Algorithm 3) and the Go/Explore phases (Algorithm 1) are the package's one
implementation (:class:`~sb3_gcrl.goals.BackAndForthScheduler`, :class:`~sb3_gcrl.wrappers.GoExploreWrapper`);
this module only plugs the agent into them:

* :class:`PEGScheduler`: the exploratory goal distribution rho_E, planned by the agent
  (:meth:`~sb3_gcrl.morefree.MoReFree.plan_exploratory_goal`: PEG's cross-entropy search over goal space, scoring
  each goal by the explorer's returns along pi_G's imagined path toward it). Before the agent is attached or has
  data, goals come from a fallback scheduler (count-based novelty).
* :class:`AgentExploreAction`: the ``explore_policy`` of the Go/Explore wrapper that executes the action the agent
  chose with pi_E (the agent fills it before each step).
* :func:`morefree_go_explore`: ``env_wrapper`` entry that builds both into a :class:`GoExploreWrapper`.
"""

from __future__ import annotations

from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from sb3_gcrl.goals.schedulers import BackAndForthScheduler, GoalScheduler
from sb3_gcrl.wrappers.go_explore import GoExploreWrapper


class ExploratoryGoalSource(Protocol):
    """What :class:`PEGScheduler` asks the agent (implemented by :class:`~sb3_gcrl.morefree.MoReFree`)."""

    def plan_exploratory_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray | None:
        """The exploratory goal for the env showing ``obs``, or None when the agent cannot plan yet."""


class PEGScheduler(GoalScheduler):
    """PEG's exploratory goals (rho_E), planned by the agent attached with :meth:`attach`.

    :param fallback: scheduler used until the agent can plan (e.g. :class:`~sb3_gcrl.goals.NoveltyScheduler`);
        it also sees every achieved goal.
    """

    kind = "explore"

    def __init__(self, fallback: GoalScheduler) -> None:
        self.fallback = fallback
        self.agent: ExploratoryGoalSource | None = None
        #: goals planned by the agent / taken from the fallback
        self.n_planned = 0
        self.n_fallback = 0

    def attach(self, agent: ExploratoryGoalSource | None) -> None:
        """Let ``agent`` plan the goals (None detaches)."""
        self.agent = agent

    def observe(self, achieved_goal: np.ndarray) -> None:
        self.fallback.observe(achieved_goal)

    def observe_task_goal(self, goal: np.ndarray) -> None:
        self.fallback.observe_task_goal(goal)

    def reset_pending(self) -> None:
        self.fallback.reset_pending()

    def next_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        goal = None if self.agent is None else self.agent.plan_exploratory_goal(obs, rng)
        if goal is None:
            self.n_fallback += 1
            return self.fallback.next_goal(obs, rng)
        self.n_planned += 1
        return goal

    def __getstate__(self) -> dict[str, Any]:
        # the agent is re-attached at the start of learn; never pickle it with the env
        return {**self.__dict__, "agent": None}


class AgentExploreAction:
    """``explore_policy`` of a :class:`~sb3_gcrl.wrappers.GoExploreWrapper` that executes the agent's pi_E action.

    The agent writes :attr:`action` before each env step in which the wrapper is in its Explore phase. Without an
    agent (e.g. ``rl_zoo3 enjoy``, or before the agent's first action) it falls back to uniform random actions.

    :param action_space: the env's action space.
    """

    def __init__(self, action_space: gym.spaces.Box) -> None:
        self.action_space = action_space
        self.action: np.ndarray | None = None
        self.n_agent = 0
        self.n_random = 0

    def __call__(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        action, self.action = self.action, None
        if action is None:
            self.n_random += 1
            low, high = self.action_space.low, self.action_space.high
            return rng.uniform(low, high).astype(self.action_space.dtype)
        self.n_agent += 1
        return action


#: exploratory goal distributions of :func:`morefree_go_explore`
EXPLORATORY = ("peg", "novelty")


def morefree_go_explore(
    env: gym.Env,
    alpha: float = 0.2,
    exploratory: str = "peg",
    explorer: str = "agent",
    scheduler_kwargs: dict[str, Any] | None = None,
    **go_explore_kwargs: Any,
) -> GoExploreWrapper:
    """Back-and-Forth Go-Explore (Algorithm 3) for the model-based agent: an ``env_wrapper`` entry.

    Builds the package's :class:`~sb3_gcrl.wrappers.GoExploreWrapper` with the ``back_and_forth`` scheduler and
    swaps in the agent's parts: PEG goals as rho_E (:class:`PEGScheduler`, falling back to count-based novelty) and
    pi_E as the Explore-phase policy (:class:`AgentExploreAction`). ``alpha = 0`` is reset-free PEG.

    :param env: goal env, wrapped in :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` (which states ``eval_horizon``).
    :param alpha: probability of a forward/back pair (thesis Sec. 3.7.3: 0.2).
    :param exploratory: ``"peg"`` (goals planned with the world model) or ``"novelty"`` (count-based, Eq. 6.5).
    :param explorer: ``"agent"`` (pi_E, Plan2Explore) or ``"random"`` (uniform actions in the Explore phase).
    :param scheduler_kwargs: keyword arguments of the novelty scheduler (``goal_low``, ``goal_high``, ``n_bins``,
        ``tau``, ``within_bin``), the fallback of PEG.
    :param go_explore_kwargs: other keyword arguments of :class:`~sb3_gcrl.wrappers.GoExploreWrapper`.
    :return: the wrapped env.
    """
    if exploratory not in EXPLORATORY:
        raise ValueError(f"exploratory must be one of {EXPLORATORY}, got {exploratory!r}")
    if explorer not in ("agent", "random"):
        raise ValueError(f"explorer must be 'agent' or 'random', got {explorer!r}")
    for key in ("scheduler", "explore_policy"):
        if key in go_explore_kwargs:
            raise ValueError(f"morefree_go_explore sets {key} itself: remove it")
    kwargs = {**(scheduler_kwargs or {}), "alpha": alpha, "exploratory": "novelty"}
    slot = AgentExploreAction(env.action_space) if explorer == "agent" else "random"
    wrapped = GoExploreWrapper(env, "back_and_forth", kwargs, explore_policy=slot, **go_explore_kwargs)
    scheduler = wrapped.scheduler
    assert isinstance(scheduler, BackAndForthScheduler)
    if exploratory == "peg":
        scheduler.exploratory = PEGScheduler(scheduler.exploratory)
    return wrapped


def find_agent_hooks(env: gym.Env) -> tuple[PEGScheduler | None, AgentExploreAction | None]:
    """The PEG scheduler and the Explore-action slot inside one (wrapped) env, if any."""
    from stable_baselines3.common.env_util import unwrap_wrapper

    wrapper = unwrap_wrapper(env, GoExploreWrapper)
    if wrapper is None:
        return None, None
    scheduler = wrapper.scheduler
    if isinstance(scheduler, BackAndForthScheduler):
        scheduler = scheduler.exploratory
    peg = scheduler if isinstance(scheduler, PEGScheduler) else None
    slot = getattr(wrapper, "_explore_policy", None)
    return peg, slot if isinstance(slot, AgentExploreAction) else None
