"""How long to post-explore once the commanded goal is reached (thesis Sec. 6.4.2 and Sec. 7.2.3).

A rule maps what is known at the moment of success to a number of random steps (0 = end the episode now):

- :class:`FixedSteps` -- ``n_pe`` steps (thesis, deep RL, Table 6.3: 30 FetchReach, 50 PointUMaze);
- :class:`ProportionalSteps` -- ``p_pe * l`` steps, ``l`` = steps it took to reach the goal (thesis,
  tabular, Table 6.2: ``p_pe = 0.5``);
- :class:`NoveltyAdaptive` -- ours (the thesis leaves adaptive post-exploration to future work, Sec. 6.6
  and 7.2.3): ``p_pe * l`` scaled by how novel the reached goal is, ``(n_median / n(g))^beta`` clipped to
  ``[0, max_scale]``, and no post-exploration at all when that scale is below ``min_scale`` (the goal was
  visited much more often than a typical goal: the agent is inside its known region, not on its border).
  Long-to-reach goals (large ``l``) and rarely visited goals (small ``n(g)``) therefore get the longest
  post-exploration, exactly the two intuitions of Sec. 7.2.3.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from sb3_gcrl.common.validation import check_float, check_int, check_optional_int


class PostExplorationRule(ABC):
    """Decides the number of post-exploration steps when a commanded goal is reached."""

    @abstractmethod
    def length(self, steps_to_goal: int, goal_visits: float, typical_visits: float) -> int:
        """Number of random steps to take after the goal was reached.

        :param steps_to_goal: ``l``, environment steps the agent needed to reach the goal this episode.
        :param goal_visits: ``n(g)``, visits of the reached goal (its bin) before this episode.
        :param typical_visits: median visit count over the goal space (the reference for novelty).
        :return: steps (>= 0); 0 ends the episode at the goal, as without post-exploration.
        """

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in vars(self).items())
        return f"{type(self).__name__}({args})"


class FixedSteps(PostExplorationRule):
    """Always ``n_pe`` random steps (thesis Table 6.3).

    :param n_pe: number of post-exploration steps.
    """

    def __init__(self, n_pe: int) -> None:
        self.n_pe = check_int("n_pe", n_pe, minimum=0)

    def length(self, steps_to_goal: int, goal_visits: float, typical_visits: float) -> int:
        return self.n_pe


class ProportionalSteps(PostExplorationRule):
    """``ceil(p_pe * l)`` random steps, ``l`` = steps taken to reach the goal (thesis Table 6.2).

    :param p_pe: fraction of the goal-reaching trajectory length (thesis: 0.5).
    :param min_steps: lower bound, so that a goal reached at the first step still post-explores.
    """

    def __init__(self, p_pe: float, min_steps: int = 1) -> None:
        self.p_pe = check_float("p_pe", p_pe, minimum=0.0)
        self.min_steps = check_int("min_steps", min_steps, minimum=0)

    def length(self, steps_to_goal: int, goal_visits: float, typical_visits: float) -> int:
        return max(self.min_steps, int(np.ceil(self.p_pe * steps_to_goal)))


class NoveltyAdaptive(PostExplorationRule):
    """Post-explore longer from novel, far goals; skip well-known ones (ours, see the module docstring).

    ``scale = min(max_scale, (typical_visits / max(goal_visits, 1)) ** beta)``; the length is 0 when
    ``scale < min_scale``, else ``max(min_steps, ceil(base * scale))`` capped by ``max_steps``, with
    ``base = p_pe * l`` (tabular, as :class:`ProportionalSteps`) or ``base = n_pe`` when ``n_pe`` is given (deep RL,
    as :class:`FixedSteps`).

    :param p_pe: base fraction of the goal-reaching length (as :class:`ProportionalSteps`).
    :param n_pe: base length in steps instead of ``p_pe * l`` (as :class:`FixedSteps`).
    :param beta: how strongly novelty stretches or shrinks the length (0 = :class:`ProportionalSteps`
        with a ``min_scale`` gate that never triggers).
    :param min_scale: below this novelty scale the reached goal is considered known: no post-exploration.
    :param max_scale: cap on the stretch for very novel goals.
    :param min_steps: lower bound when post-exploring.
    :param max_steps: optional absolute cap on the length.
    """

    def __init__(
        self,
        p_pe: float = 0.5,
        n_pe: int | None = None,
        beta: float = 1.0,
        min_scale: float = 0.25,
        max_scale: float = 4.0,
        min_steps: int = 1,
        max_steps: int | None = None,
    ) -> None:
        self.p_pe = check_float("p_pe", p_pe, minimum=0.0)
        self.n_pe = check_optional_int("n_pe", n_pe)
        self.beta = check_float("beta", beta, minimum=0.0)
        self.min_scale = check_float("min_scale", min_scale, minimum=0.0)
        self.max_scale = check_float("max_scale", max_scale, minimum=0.0)
        if self.min_scale > self.max_scale:
            raise ValueError(f"Need 0 <= min_scale <= max_scale, got {min_scale!r} and {max_scale!r}")
        self.min_steps = check_int("min_steps", min_steps, minimum=0)
        self.max_steps = check_optional_int("max_steps", max_steps, minimum=self.min_steps)

    def scale(self, goal_visits: float, typical_visits: float) -> float:
        """Novelty stretch ``(typical / n(g))^beta`` clipped to ``max_scale``."""
        return float(min(self.max_scale, (max(typical_visits, 1.0) / max(goal_visits, 1.0)) ** self.beta))

    def length(self, steps_to_goal: int, goal_visits: float, typical_visits: float) -> int:
        scale = self.scale(goal_visits, typical_visits)
        if scale < self.min_scale:
            return 0
        base = self.p_pe * steps_to_goal if self.n_pe is None else self.n_pe
        steps = max(self.min_steps, int(np.ceil(base * scale)))
        return steps if self.max_steps is None else min(steps, self.max_steps)


def make_post_exploration_rule(
    n_pe: int | None = None, p_pe: float | None = None, adaptive: bool | dict | None = None
) -> PostExplorationRule:
    """Build a rule from YAML-friendly arguments (exactly one of ``n_pe`` / ``p_pe`` / ``adaptive``).

    :param n_pe: fixed number of steps -> :class:`FixedSteps`.
    :param p_pe: fraction of the goal-reaching length -> :class:`ProportionalSteps`.
    :param adaptive: ``True`` or a dict of :class:`NoveltyAdaptive` kwargs.
    :return: the rule.
    """
    given = [name for name, value in (("n_pe", n_pe), ("p_pe", p_pe), ("adaptive", adaptive)) if value]
    if len(given) != 1:
        raise ValueError(
            f"Give exactly one of n_pe (fixed steps), p_pe (fraction of the path) or adaptive; got {given or 'none'}"
        )
    if n_pe:
        return FixedSteps(n_pe)
    if p_pe:
        return ProportionalSteps(p_pe)
    return NoveltyAdaptive(**(adaptive if isinstance(adaptive, dict) else {}))
