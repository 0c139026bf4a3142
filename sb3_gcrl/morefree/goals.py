"""Goals of the model-based MoReFree agent: PEG exploratory goals and the Go/Explore wrapper it acts through.

The Back-and-Forth schedule (Algorithm 3) and the Go/Explore phases (Algorithm 1) are the package's one
implementation (:class:`~sb3_gcrl.goals.BackAndForthScheduler`, :class:`~sb3_gcrl.wrappers.GoExploreWrapper`);
this module only plugs the agent into them, through the wrapper's public interface (``VecEnv.get_attr`` /
``env_method``, so any VecEnv works):

* :class:`PEGScheduler`: the exploratory goal distribution rho_E, planned by the agent
  (:meth:`~sb3_gcrl.morefree.MoReFree.plan_exploratory_goal`: PEG's cross-entropy search over goal space, scoring
  each goal by the explorer's returns along pi_G's imagined path toward it), an
  :class:`~sb3_gcrl.wrappers.go_explore.AgentGoalScheduler`: the wrapper asks the agent for each goal. While the
  agent is not training or cannot plan yet, goals come from a fallback scheduler (count-based novelty).
* pi_E in the Explore phase: the wrapper built with ``explore_policy="agent"`` executes the agent's action, and the
  agent acts with pi_E where the wrapper's ``acting_policy`` says ``"explorer"``.
* :func:`morefree_go_explore`: ``env_wrapper`` entry that builds both into a :class:`GoExploreWrapper`.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from sb3_gcrl.goals.schedulers import BackAndForthScheduler
from sb3_gcrl.wrappers.go_explore import AgentGoalScheduler, GoExploreWrapper


class PEGScheduler(AgentGoalScheduler):
    """PEG's exploratory goals (rho_E), planned by :meth:`~sb3_gcrl.morefree.MoReFree.plan_exploratory_goal`.

    An :class:`~sb3_gcrl.wrappers.go_explore.AgentGoalScheduler`: while :class:`~sb3_gcrl.morefree.MoReFree`
    trains on the env it answers the wrapper's goal requests; otherwise (and while it cannot plan) the goals come
    from ``fallback``.

    :param fallback: scheduler used until the agent can plan (e.g. :class:`~sb3_gcrl.goals.NoveltyScheduler`);
        it also sees every achieved goal.
    """


#: exploratory goal distributions of :func:`morefree_go_explore`
EXPLORATORY = ("peg", "novelty")


def morefree_go_explore(
    env: gym.Env,
    alpha: float = 0.2,
    exploratory: str = "peg",
    explorer: str = "agent",
    scheduler_kwargs: dict[str, Any] | None = None,
    end_go_on_success: bool = False,
    **go_explore_kwargs: Any,
) -> GoExploreWrapper:
    """Back-and-Forth Go-Explore (Algorithm 3) for the model-based agent: an ``env_wrapper`` entry.

    Builds the package's :class:`~sb3_gcrl.wrappers.GoExploreWrapper` with the ``back_and_forth`` scheduler and
    swaps in the agent's parts: PEG goals as rho_E (:class:`PEGScheduler`, falling back to count-based novelty) and
    pi_E as the Explore-phase policy (``explore_policy="agent"``). ``alpha = 0`` is reset-free PEG. Each Go phase
    runs its full H_G steps (Algorithm 1), so pi_G also acts where it has arrived: the replay holds pi_G holding its
    goals, which its critic otherwise never sees (docs/morefree.md, "Departures").

    :param env: goal env, wrapped in :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` (which states ``eval_horizon``).
    :param alpha: probability of a forward/back pair (thesis Sec. 3.7.3: 0.2).
    :param exploratory: ``"peg"`` (goals planned with the world model) or ``"novelty"`` (count-based, Eq. 6.5).
    :param explorer: ``"agent"`` (pi_E, Plan2Explore) or ``"random"`` (uniform actions in the Explore phase).
    :param scheduler_kwargs: keyword arguments of the novelty scheduler (``goal_low``, ``goal_high``, ``n_bins``,
        ``tau``, ``within_bin``), the fallback of PEG.
    :param end_go_on_success: end a Go phase when the env reports the commanded goal reached, instead of after
        H_G steps (Algorithm 1); the wrapper's default for MoReFree-SAC, an ablation here.
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
    wrapped = GoExploreWrapper(
        env,
        "back_and_forth",
        kwargs,
        explore_policy=explorer,
        end_go_on_success=end_go_on_success,
        **go_explore_kwargs,
    )
    scheduler = wrapped.scheduler
    assert isinstance(scheduler, BackAndForthScheduler)
    if exploratory == "peg":
        scheduler.exploratory = PEGScheduler(scheduler.exploratory)
    return wrapped
