"""The interface between post-exploration's evaluation and an agent that runs the whole IMGEP loop itself.

Post-exploration is one step of the IMGEP loop (thesis Ch. 6: define a goal space, select a goal, reach it,
post-explore). Deep agents get that loop from the env (:class:`~sb3_gcrl.post_exploration.PostExplorationWrapper`
keeps the goal space and its visit counts), an IMGEP agent keeps it itself (:class:`~sb3_gcrl.imgep.TabularIMGEP`).
So the IMGEP package depends on this one (its rules, its metrics, this interface) and not the other way round:
:class:`~sb3_gcrl.post_exploration.AllGoalsEvalCallback` asks an agent that implements
:class:`GoalExplorationAgent` for its exploration statistics and its evaluation env, and asks the training envs
otherwise.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import gymnasium as gym


class GoalExplorationAgent(ABC):
    """An agent that keeps its own goal space and visit counts (an IMGEP, thesis Ch. 6, Algorithm 3).

    Subclass it next to the SB3 base class (``class TabularIMGEP(ModelFileMixin, BaseAlgorithm,
    GoalExplorationAgent)``) and :class:`~sb3_gcrl.post_exploration.AllGoalsEvalCallback` logs the agent's own
    visitation entropy and coverage, and evaluates it on :meth:`make_all_goals_env` when no eval env is given.
    """

    @abstractmethod
    def visitation_entropy(self) -> float:
        """Entropy of the agent's goal visits so far (thesis Eq. 6.7), in nats."""

    @abstractmethod
    def coverage(self) -> float:
        """Fraction of the reachable goals the agent has visited so far, in [0, 1]."""

    @abstractmethod
    def make_all_goals_env(self) -> gym.Env:
        """A new goal env for the all-goals evaluation (Sec. 6.5.1) of the task the agent learns.

        :return: an env whose ``reset(options={"goal": g})`` commands ``g``, whose ``info["is_success"]`` says
            whether it was reached, and which declares its ``reachable_goals``.
        """
