"""Probes of the learned dynamical distance D against the env's ground truth (the shortest path through a maze, or
the Euclidean distance).

* :func:`distance_rank_correlation`: Spearman rank correlation between ``D(achieved, goal)`` and the env's true
  distance between the same points (``path_distance`` when the env defines it, e.g. the shortest path through a
  maze; the Euclidean distance otherwise). Near 1: D orders states as the task's geometry does; near 0: pi_G's
  reward carries no information about where the goal is.
* :func:`distance_minimum_error`: how far from the goal the learned distance puts its minimum, beyond the replayed
  state nearest to it (0: pi_G's reward peaks at the goal).

The ground truth (:func:`true_distance`, :class:`VecEnvGeometry`) serves the other probes too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from scipy.stats import spearmanr
from stable_baselines3.common.vec_env import VecEnv

from sb3_gcrl.morefree.functional import symlog

if TYPE_CHECKING:
    from sb3_gcrl.morefree.morefree import MoReFree


def true_distance(env: Any, achieved: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Ground-truth distance from each point of ``achieved (N, G)`` to ``goal (G,)``: the env's
    ``path_distance`` (e.g. shortest paths through a maze) when it has one, else the Euclidean distance.

    :param env: a gymnasium env (wrapped or not) or a :class:`VecEnvGeometry`.
    """
    if isinstance(env, VecEnvGeometry):
        if env.has_path_distance:
            return np.asarray(env.path_distance(achieved, goal), dtype=np.float64)
        base = None
    else:
        base = getattr(env, "unwrapped", env)
    if base is not None and hasattr(base, "path_distance"):
        return np.asarray(base.path_distance(achieved, goal), dtype=np.float64)
    return np.linalg.norm(np.asarray(achieved, np.float64) - np.asarray(goal, np.float64).reshape(1, -1), axis=-1)


class VecEnvGeometry:
    """The ground truth of the first env of a VecEnv, for :func:`true_distance`: its ``path_distance`` called through
    ``VecEnv.env_method`` (so that it works in any VecEnv, a ``SubprocVecEnv`` included), else Euclidean distances.

    :param env: the VecEnv.
    """

    def __init__(self, env: VecEnv) -> None:
        self.env = env
        self.has_path_distance = env.has_attr("path_distance")

    def path_distance(self, achieved: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """The first env's ``path_distance(achieved, goal)``."""
        return self.env.env_method("path_distance", achieved, goal, indices=[0])[0]


def finite_mean(x: np.ndarray) -> float:
    """Mean of the finite entries (a point inside a wall has no path distance), nan when there are none."""
    finite = x[np.isfinite(x)]
    return float(finite.mean()) if finite.size else float("nan")


def _learned_and_true_distances(
    model: MoReFree, env: Any, n_states: int, n_goals: int, seed: int, goals: str, goal_rng: np.random.Generator | None
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(D(s, g), true distance(s, g))`` over ``n_states`` replayed states ``s``, for each of ``n_goals`` goals
    (``"replay"``: replayed achieved goals; ``"evaluation"``: rho_g*)."""
    rng = np.random.default_rng(seed)
    goal_dim = model.policy.goal_dim
    achieved = model.replay_buffer.sample_states(n_states, rng)[:, -goal_dim:]
    if goals == "replay":
        targets = model.replay_buffer.sample_states(n_goals, rng)[:, -goal_dim:]
    elif goals == "evaluation":
        targets = model.task_goal_samples("evaluation", n_goals, goal_rng).reshape(-1, goal_dim)
    else:
        raise ValueError(f"goals must be 'replay' or 'evaluation', got {goals!r}")
    pairs = []
    with th.no_grad():
        points = symlog(th.as_tensor(achieved, dtype=th.float32, device=model.device))
        for goal in targets:
            target = symlog(th.as_tensor(goal, dtype=th.float32, device=model.device)).expand_as(points)
            pairs.append((model.policy.distance(points, target).cpu().numpy(), true_distance(env, achieved, goal)))
    return pairs


def distance_rank_correlation(
    model: MoReFree,
    env: Any,
    n_states: int = 512,
    n_goals: int = 8,
    seed: int = 0,
    goals: str = "replay",
    goal_rng: np.random.Generator | None = None,
) -> float:
    """Spearman correlation of ``D(s, g)`` with the true distance over replayed states ``s`` and ``n_goals`` goals.

    :param model: the agent (its replay buffer holds the states).
    :param env: the env whose geometry is the ground truth (see :func:`true_distance`).
    :param n_states: replayed states.
    :param n_goals: goals; the pairs of all of them are pooled.
    :param seed: seed of the draws.
    :param goals: ``"replay"`` (replayed achieved goals: does D know the geometry of the data?) or
        ``"evaluation"`` (rho_g*: does pi_G's reward point to the task's goals?).
    :param goal_rng: generator of the evaluation goals drawn as the agent draws them (``None``: the agent's own).
    :return: the rank correlation (nan if the distances are constant).
    """
    pairs = _learned_and_true_distances(model, env, n_states, n_goals, seed, goals, goal_rng)
    learned, truth = zip(*pairs, strict=True)
    d, t = np.concatenate(learned), np.concatenate(truth)
    finite = np.isfinite(t)
    return float(spearmanr(d[finite], t[finite]).statistic)


def distance_minimum_error(
    model: MoReFree,
    env: Any,
    n_states: int = 4096,
    n_goals: int = 8,
    seed: int = 0,
    goals: str = "evaluation",
    goal_rng: np.random.Generator | None = None,
) -> float:
    """How far from its goal the learned distance puts its minimum: over ``n_states`` replayed states ``s``, the true
    distance to ``g`` of ``argmin_s D(s, g)`` minus that of the replayed state truly nearest to ``g``, mean over
    ``n_goals`` goals.

    0: of the replayed states, D's nearest to the goal is the nearest one (pi_G's reward peaks at the goal); a value
    near the success radius: pi_G is rewarded for stopping beside the goal, not in it.

    :param model: the agent (its replay buffer holds the states).
    :param env: the env whose geometry is the ground truth (see :func:`true_distance`).
    :param n_states: replayed states (the candidates; more of them reach closer to each goal).
    :param n_goals: goals.
    :param seed: seed of the draws.
    :param goals: ``"evaluation"`` (rho_g*) or ``"replay"`` (replayed achieved goals).
    :param goal_rng: generator of the evaluation goals drawn as the agent draws them (``None``: the agent's own).
    :return: the mean error in the env's units (nan when no goal has a finite true distance to any state).
    """
    errors = []
    for learned, truth in _learned_and_true_distances(model, env, n_states, n_goals, seed, goals, goal_rng):
        finite = np.isfinite(truth)
        if finite.any():
            best = int(np.flatnonzero(finite)[np.argmin(learned[finite])])
            errors.append(truth[best] - truth[finite].min())
    return float(np.mean(errors)) if errors else float("nan")
