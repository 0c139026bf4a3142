"""Task-relevant goal distributions rho_0 (initial states) and rho_g* (evaluation goals), thesis Section 3.4.

MoReFree conditions exploration (Back-and-Forth Go-Explore, Algorithm 3) and policy training (Section 3.4.2)
on two task-relevant goal distributions:

* rho_0: initial states of the task, expressed in goal space (the "back" goals that emulate a reset);
* rho_g*: the evaluation goals (the "forward" goals).

An env *declares* them with two methods on its unwrapped env,
``sample_initial_goal(rng) -> np.ndarray`` and ``sample_evaluation_goal(rng) -> np.ndarray``. Any other
goal env works unchanged: the distributions are *learned* from what the env shows at its own resets
(``achieved_goal`` at reset is a sample of rho_0, ``desired_goal`` at reset a sample of rho_g*), and sampled
uniformly from the recorded resets.

Goals of any shape are handled flat: a sample is a row of ``goal_dim = prod(achieved_goal shape)`` values
(a ``Discrete`` goal is one value, an image goal its flattened pixels); callers reshape to their layout.
"""

from __future__ import annotations

from typing import Any, Literal

import gymnasium as gym
import numpy as np

GoalKind = Literal["initial", "evaluation"]

#: names of the methods a goal env declares to expose its task-relevant goals
INITIAL_GOAL_METHOD = "sample_initial_goal"
EVALUATION_GOAL_METHOD = "sample_evaluation_goal"


def declares_task_goals(env: gym.Env) -> bool:
    """Whether ``env.unwrapped`` declares both task-relevant goal samplers.

    :param env: any gymnasium env (wrapped or not).
    :return: True when ``sample_initial_goal`` and ``sample_evaluation_goal`` are both callable.
    """
    unwrapped = env.unwrapped
    return callable(getattr(unwrapped, INITIAL_GOAL_METHOD, None)) and callable(
        getattr(unwrapped, EVALUATION_GOAL_METHOD, None)
    )


class TaskRelevantGoals:
    """Sampler of rho_0 and rho_g*, declared by the env or learned from its resets.

    Learned samples are kept in ring buffers of at most ``capacity`` rows (grown by doubling as resets come,
    so a reset-free run with a few hard resets keeps a few rows even for image goals); once full, the oldest
    reset is overwritten (so a non-stationary reset distribution is tracked).

    :param env: the goal env (its ``unwrapped`` is checked for the two sampler methods).
    :param goal_dim: number of values of one goal (``prod`` of the ``achieved_goal`` shape).
    :param capacity: number of learned resets remembered (only used when the env does not declare samplers).
    """

    def __init__(self, env: gym.Env, goal_dim: int, capacity: int = 10_000) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self._unwrapped = env.unwrapped
        self.declared = declares_task_goals(env)
        self.goal_dim = goal_dim
        self.capacity = capacity
        self._initial = np.zeros((min(capacity, 16), goal_dim), dtype=np.float64)
        self._evaluation = np.zeros_like(self._initial)
        self._n_recorded = 0

    def attach(self, env: gym.Env) -> None:
        """Sample declared goals from ``env`` (after unpickling, which leaves the env out).

        :param env: the goal env, wrapped or not.
        """
        self._unwrapped = env.unwrapped

    def __getstate__(self) -> dict[str, Any]:
        # the env is not pickled with the goals (run checkpoints): attach() reconnects it
        return {**self.__dict__, "_unwrapped": None}

    @property
    def n_recorded(self) -> int:
        """Number of resets recorded so far (learned mode)."""
        return self._n_recorded

    def record_reset(self, obs: dict[str, np.ndarray]) -> None:
        """Record the goals an env shows at one of its own (physical) resets.

        :param obs: the Dict observation returned by the env's ``reset``.
        """
        row = self._n_recorded % self.capacity
        if row == len(self._initial) < self.capacity:
            rows = min(2 * row, self.capacity)
            self._initial = np.concatenate([self._initial, np.zeros((rows - row, self.goal_dim))])
            self._evaluation = np.concatenate([self._evaluation, np.zeros((rows - row, self.goal_dim))])
        self._initial[row] = np.ravel(obs["achieved_goal"])
        self._evaluation[row] = np.ravel(obs["desired_goal"])
        self._n_recorded += 1

    def sample(self, kind: GoalKind, rng: np.random.Generator, n: int = 1) -> np.ndarray:
        """Draw ``n`` goals from rho_0 (``kind="initial"``) or rho_g* (``kind="evaluation"``).

        :param kind: ``"initial"`` or ``"evaluation"``.
        :param rng: random generator (used for learned distributions and passed to declared samplers).
        :param n: number of goals.
        :return: array of shape ``(n, goal_dim)`` (flat goals).
        """
        if kind not in ("initial", "evaluation"):
            raise ValueError(f"kind must be 'initial' or 'evaluation', got {kind!r}")
        if self.declared:
            method = getattr(self._unwrapped, INITIAL_GOAL_METHOD if kind == "initial" else EVALUATION_GOAL_METHOD)
            out = np.empty((n, self.goal_dim), dtype=np.float64)
            for i in range(n):
                out[i] = np.ravel(method(rng))
            return out
        if self._n_recorded == 0:
            raise RuntimeError(
                "No task-relevant goals known yet: the env does not declare sample_initial_goal/"
                "sample_evaluation_goal, so they are learned from its resets; call reset() first."
            )
        rows = rng.integers(0, min(self._n_recorded, self.capacity), size=n)
        return (self._initial if kind == "initial" else self._evaluation)[rows].copy()


def declared_task_goals(env: gym.Env, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` samples each of rho_0 and rho_g* from the samplers an env declares (for analysis and plots).

    :param env: a goal env whose unwrapped env declares ``sample_initial_goal`` and ``sample_evaluation_goal``.
    :param n: samples per distribution.
    :param seed: seed of the generator passed to the samplers.
    :return: ``(initial, evaluation)``, each ``(n, goal_dim)`` flat goals.
    :raises ValueError: the env declares no samplers.
    """
    if not declares_task_goals(env):
        raise ValueError(
            f"{env.unwrapped} does not declare {INITIAL_GOAL_METHOD} / {EVALUATION_GOAL_METHOD} (rho_0, rho_g*); "
            "add them to the env, or use TaskRelevantGoals to learn them from its resets"
        )
    goals = TaskRelevantGoals(env, int(np.prod(env.observation_space["achieved_goal"].shape)))
    rng = np.random.default_rng(seed)
    return goals.sample("initial", rng, n), goals.sample("evaluation", rng, n)
