"""Goal schedulers: small objects a goal-commanding wrapper asks for a goal at each episode/phase start.

A scheduler answers :meth:`GoalScheduler.next_goal` (and labels the goal with :attr:`GoalScheduler.kind`) and
may learn from every achieved goal through :meth:`GoalScheduler.observe`. Schedulers of the thesis:

* :class:`EnvDefaultScheduler`: keep the goal the env proposes (naive reset-free training);
* :class:`EvaluationGoalScheduler`: always a goal from rho_g* (MoReFree with alpha = 1 in exploration);
* :class:`UniformVisitedScheduler`: uniform over visited (binned) achieved goals;
* :class:`NoveltyScheduler`: count-based novelty over visited bins, thesis Eq. 6.5 (Ch. 6, also the
  exploratory goal distribution rho_E of MoReFree-SAC, replacing PEG's world-model planner);
* :class:`BackAndForthScheduler`: thesis Algorithm 3, w.p. alpha the pair (g* ~ rho_g*, then g0 ~ rho_0),
  else an exploratory goal from a pluggable scheduler.

:func:`make_scheduler` builds any of them from a name and keyword arguments (the form an RL-Zoo YAML can hold).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_gcrl.goals.goal_space import BinnedGoalSpace, binned_goal_space_for
from sb3_gcrl.goals.task_goals import TaskRelevantGoals


class GoalScheduler(ABC):
    """Base class: chooses the commanded goal of each Go phase / segment.

    :attr kind: label of the goal last returned (e.g. ``"forward"``, ``"back"``, ``"explore"``), used for logging.
    """

    kind: str = "goal"

    @abstractmethod
    def next_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        """Return the next goal to command.

        :param obs: current Dict observation (its ``desired_goal`` is the env's own goal).
        :param rng: random generator owned by the wrapper (seeded with the env).
        :return: goal, shape ``(goal_dim,)``.
        """

    def observe(self, achieved_goal: np.ndarray) -> None:  # noqa: B027 (optional hook)
        """Learn from an achieved goal (called after every env step and reset). No-op by default.

        :param achieved_goal: shape ``(goal_dim,)``.
        """

    def observe_task_goal(self, goal: np.ndarray) -> None:  # noqa: B027 (optional hook)
        """Learn from a task-relevant goal the env showed (its desired goal at a physical reset). No-op by default.

        :param goal: shape ``(goal_dim,)``.
        """

    def reset_pending(self) -> None:  # noqa: B027 (optional hook)
        """Forget any goal sequence in progress (called after a physical reset). No-op by default."""


class EnvDefaultScheduler(GoalScheduler):
    """Command the goal the env itself proposes (``obs["desired_goal"]``): no scheduling."""

    kind = "env"

    def next_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        return np.array(obs["desired_goal"], dtype=np.float64)


class EvaluationGoalScheduler(GoalScheduler):
    """Always command an evaluation goal g* ~ rho_g*.

    :param task_goals: the env's task-relevant goals.
    """

    kind = "forward"

    def __init__(self, task_goals: TaskRelevantGoals) -> None:
        self.task_goals = task_goals

    def next_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        return self.task_goals.sample("evaluation", rng)[0]


class UniformVisitedScheduler(GoalScheduler):
    """Uniform over visited bins of the goal space (each achieved goal is recorded).

    Achieved goals are recorded with :meth:`BinnedGoalSpace.record` (binned per block, one row copy per step).

    :param goal_space: the binned visited-goal space (shared objects are fine, e.g. with a logger).
    """

    kind = "explore"

    def __init__(self, goal_space: BinnedGoalSpace) -> None:
        self.goal_space = goal_space

    def observe(self, achieved_goal: np.ndarray) -> None:
        self.goal_space.record(achieved_goal)

    def observe_task_goal(self, goal: np.ndarray) -> None:
        self.goal_space.extend(goal)  # inferred bounds cover the task's goals from the start

    def _prepare(self, obs: dict[str, np.ndarray]) -> None:
        if self.goal_space.n_visited == 0:
            self.goal_space.add(obs["achieved_goal"])

    def next_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        self._prepare(obs)
        return self.goal_space.sample_uniform(rng)[0]


class NoveltyScheduler(UniformVisitedScheduler):
    """Count-based novelty over visited bins, thesis Eq. 6.5: p(g) = (1/n(g))^tau / sum_g' (1/n(g'))^tau.

    :param goal_space: the binned visited-goal space.
    :param tau: temperature of Eq. 6.5 (thesis Table 6.3 uses tau in {0, ..., 10}; 1 by default).
    """

    def __init__(self, goal_space: BinnedGoalSpace, tau: float = 1.0) -> None:
        super().__init__(goal_space)
        if not np.isfinite(tau) or tau < 0:
            raise ValueError(f"tau must be a finite number >= 0, got {tau}")
        self.tau = float(tau)

    def next_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        self._prepare(obs)
        return self.goal_space.sample_novel(self.tau, rng)[0]


class BackAndForthScheduler(GoalScheduler):
    """Back-and-Forth Go-Explore goal selection, thesis Algorithm 3.

    With probability ``alpha`` the pair (g*, g0) ~ (rho_g*, rho_0) is drawn and commanded in two consecutive
    Go phases ("forward" then "back"); otherwise one exploratory goal from ``exploratory`` ("explore").

    :param task_goals: the env's task-relevant goals.
    :param exploratory: scheduler of exploratory goals rho_E (thesis: PEG; here e.g. :class:`NoveltyScheduler`).
    :param alpha: probability of a forward/back pair (thesis: 0.2 for all tasks, Section 3.7.3).
    """

    def __init__(self, task_goals: TaskRelevantGoals, exploratory: GoalScheduler, alpha: float = 0.2) -> None:
        if not 0.0 <= alpha <= 1.0:
            raise ValueError(f"alpha must be in [0, 1], got {alpha}")
        self.task_goals = task_goals
        self.exploratory = exploratory
        self.alpha = float(alpha)
        self.kind = "explore"
        self._pending_back: np.ndarray | None = None

    def observe(self, achieved_goal: np.ndarray) -> None:
        self.exploratory.observe(achieved_goal)

    def observe_task_goal(self, goal: np.ndarray) -> None:
        self.exploratory.observe_task_goal(goal)

    def reset_pending(self) -> None:
        self._pending_back = None
        self.exploratory.reset_pending()

    def next_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        if self._pending_back is not None:
            goal, self._pending_back = self._pending_back, None
            self.kind = "back"
            return goal
        if rng.random() < self.alpha:
            self._pending_back = self.task_goals.sample("initial", rng)[0]
            self.kind = "forward"
            return self.task_goals.sample("evaluation", rng)[0]
        goal = self.exploratory.next_goal(obs, rng)
        self.kind = "explore"
        return goal


#: scheduler names accepted by :func:`make_scheduler`
SCHEDULERS = ("env_default", "evaluation", "uniform_visited", "novelty", "back_and_forth")
#: scheduler name -> the options of :func:`make_scheduler` it uses (``back_and_forth`` also passes on those of its
#: exploratory scheduler)
_SCHEDULER_OPTIONS: dict[str, tuple[str, ...]] = {
    "env_default": ("achieved_goal_space",),
    "evaluation": ("achieved_goal_space",),
    "uniform_visited": ("achieved_goal_space", "goal_low", "goal_high", "n_bins", "within_bin"),
    "novelty": ("achieved_goal_space", "goal_low", "goal_high", "n_bins", "within_bin", "tau"),
    "back_and_forth": ("alpha", "exploratory"),
}


def _scheduler_options(name: str, exploratory: str | None = None) -> list[str]:
    """The options of :func:`make_scheduler` that scheduler ``name`` uses (with its exploratory scheduler's)."""
    options = _SCHEDULER_OPTIONS[name]
    if name == "back_and_forth":
        inner = "novelty" if exploratory is None else exploratory
        options += _SCHEDULER_OPTIONS.get(inner, ())
    return sorted(set(options))


def make_scheduler(
    name: str,
    task_goals: TaskRelevantGoals,
    goal_low: np.ndarray | list[float] | None = None,
    goal_high: np.ndarray | list[float] | None = None,
    n_bins: int | list[int] | None = None,
    within_bin: str | None = None,
    tau: float | None = None,
    alpha: float | None = None,
    exploratory: str | None = None,
    achieved_goal_space: spaces.Space | None = None,
    **unknown: Any,
) -> GoalScheduler:
    """Build a scheduler from plain values (what an RL-Zoo YAML ``env_wrapper`` entry can hold).

    An option that the chosen scheduler would not use, or that no scheduler has, is an error naming the options
    the scheduler takes, not silently ignored.

    :param name: one of :data:`SCHEDULERS`.
    :param task_goals: the env's task-relevant goals (rho_0, rho_g*).
    :param goal_low: lower bounds of the binned goal space; leave ``goal_low`` and ``goal_high`` out to infer the
        bounds from the goals the env shows (rho_0/rho_g* at resets and the achieved goals).
    :param goal_high: upper bounds of the binned goal space.
    :param n_bins: bins per goal dimension (default 10).
    :param within_bin: ``"uniform"`` (thesis Ch. 6) or ``"visited"`` (default: a recorded achieved goal of the bin).
    :param tau: temperature of Eq. 6.5 (``novelty``; default 1).
    :param alpha: probability of a forward/back pair (``back_and_forth`` only; default 0.2, thesis Sec. 3.7.3).
    :param exploratory: name of the exploratory scheduler inside ``back_and_forth`` (default ``"novelty"``).
    :param achieved_goal_space: the env's ``achieved_goal`` space; visited-goal schedulers bin it with
        :func:`~sb3_gcrl.goals.binned_goal_space_for` (discrete spaces one bin per value, image goals refused).
        ``None`` means a vector goal of ``len(goal_low)`` dimensions.
    :param unknown: none; a name that is not an option above is refused with the scheduler's options.
    :return: the scheduler.
    :raises ValueError: for an unknown scheduler or option, an option the scheduler does not use, or a value out of
        range; the message lists the valid choices.
    """
    given = {
        key: value
        for key, value in locals().items()
        if key not in ("name", "task_goals", "unknown") and value is not None
    }
    if name not in SCHEDULERS:
        raise ValueError(f"Unknown goal scheduler {name!r}; choose one of {list(SCHEDULERS)}")
    if unknown:
        raise ValueError(
            f"Unknown option(s) {sorted(unknown)} of goal scheduler {name!r}; it takes "
            f"{_scheduler_options(name, exploratory)}"
        )
    if name == "back_and_forth":
        exploratory = "novelty" if exploratory is None else exploratory
        if exploratory == "back_and_forth":
            raise ValueError("the exploratory scheduler of back_and_forth cannot itself be back_and_forth")
        inner_kwargs: dict[str, Any] = {key: val for key, val in given.items() if key not in ("alpha", "exploratory")}
        inner = make_scheduler(exploratory, task_goals, **inner_kwargs)
        return BackAndForthScheduler(task_goals, inner, 0.2 if alpha is None else alpha)
    uses = _scheduler_options(name)
    unused = sorted(set(given) - set(uses))
    if unused:
        raise ValueError(
            f"scheduler {name!r} does not use {unused}: remove them; it takes {uses} (only back_and_forth takes alpha)"
        )
    if name == "env_default":
        return EnvDefaultScheduler()
    if name == "evaluation":
        return EvaluationGoalScheduler(task_goals)
    if achieved_goal_space is None:
        if goal_low is None:
            raise ValueError(f"scheduler {name!r} bins visited goals: pass goal_low and goal_high, or the goal space")
        achieved_goal_space = spaces.Box(-np.inf, np.inf, (len(np.asarray(goal_low).reshape(-1)),))
    space = binned_goal_space_for(
        achieved_goal_space,
        goal_low,
        goal_high,
        n_bins,
        "visited" if within_bin is None else within_bin,  # type: ignore[arg-type]
    )
    if name == "novelty":
        return NoveltyScheduler(space, 1.0 if tau is None else tau)
    return UniformVisitedScheduler(space)
