"""PEG's planner of exploratory goals (Hu et al., 2023) for the model-based MoReFree agent.

:func:`plan_goal` is PEG's cross-entropy search over goal space for the goal whose imagined pi_G path is worth most
to the explorer (:func:`peg_fitness`), inside the box of :func:`goal_box`.
:meth:`~sb3_gcrl.morefree.MoReFree.plan_exploratory_goal` answers the Go/Explore wrapper's goal requests with it
(:class:`~sb3_gcrl.morefree.goals.PEGScheduler`).
"""

from __future__ import annotations

import numpy as np
import torch as th
from gymnasium import spaces

from sb3_gcrl.morefree.buffer import SequenceReplayBuffer
from sb3_gcrl.morefree.functional import lambda_returns, symlog
from sb3_gcrl.morefree.losses import imagine_path
from sb3_gcrl.morefree.networks import LatentState
from sb3_gcrl.morefree.policies import MoReFreePolicy


def goal_box(goal_space: spaces.Box, replay_buffer: SequenceReplayBuffer) -> tuple[np.ndarray, np.ndarray]:
    """The box PEG's planner searches: the ``desired_goal`` space, or the span of the replayed achieved goals
    (padded by 10% each side) where that space is unbounded.

    :param goal_space: the ``desired_goal`` space.
    :param replay_buffer: the agent's replay (its achieved goals span the unbounded sides).
    :return: (low, high), float64.
    """
    low, high = goal_space.low.reshape(-1).astype(np.float64), goal_space.high.reshape(-1).astype(np.float64)
    if np.isfinite(low).all() and np.isfinite(high).all():
        return low, high
    visited = replay_buffer.achieved_goals().astype(np.float64)
    lo, hi = visited.min(0), visited.max(0)
    pad = 0.1 * np.maximum(hi - lo, 1e-3)
    return np.where(np.isfinite(low), low, lo - pad), np.where(np.isfinite(high), high, hi + pad)


def peg_fitness(
    policy: MoReFreePolicy,
    start: LatentState,
    candidates: np.ndarray,
    horizon: int,
    gamma: float,
    lambda_: float,
    expl_reward_scale: float,
) -> th.Tensor:
    """PEG's score of candidate goals: pi_G is imagined from ``start`` toward each for ``horizon`` steps; the score
    sums, over the imagined path, the lambda-returns of pi_E's intrinsic reward (the ensemble's disagreement)
    bootstrapped from V_E (PEG's ``cost_use_p2e_value``).

    :param policy: the agent's networks.
    :param start: the latent state of the env (one row).
    :param candidates: goals ``(K, G)`` in the env's units.
    :param horizon: imagined steps toward each goal.
    :param gamma: discount.
    :param lambda_: TD(lambda) parameter.
    :param expl_reward_scale: scale of pi_E's disagreement reward.
    :return: the scores ``(K,)``.
    """
    goals = symlog(th.as_tensor(candidates, dtype=th.float32, device=policy.device))
    feat, action = imagine_path(
        policy.world_model.rssm, start.expand(len(candidates)), lambda f: policy.actor_g.act(f, goals)[0], horizon
    )
    rewards = expl_reward_scale * policy.ensemble.disagreement(feat[:-1], action)
    returns = lambda_returns(rewards, policy.critic_e_target(feat), gamma, lambda_)
    return returns.sum(0)


def plan_goal(
    policy: MoReFreePolicy,
    state: th.Tensor,
    achieved_goal: np.ndarray,
    box: tuple[np.ndarray, np.ndarray],
    rng: np.random.Generator,
    samples: int,
    iterations: int,
    elite_fraction: float,
    horizon: int,
    gamma: float,
    lambda_: float,
    expl_reward_scale: float,
) -> np.ndarray:
    """PEG's exploratory goal: cross-entropy search over goal space for the goal whose imagined pi_G path is worth
    most to the explorer.

    A diagonal Gaussian starts at the env's achieved goal with half the goal box as std; each of ``iterations``
    rounds scores ``samples`` goals drawn from it (clipped to the box, see :func:`peg_fitness`, imagined from the
    env's current latent) and refits it to the best ``elite_fraction``. The goal is a draw from the final Gaussian,
    as in PEG.

    :param policy: the agent's networks.
    :param state: the env's state vector ``(1, S)`` (its latent is the memoryless one of
        :meth:`~sb3_gcrl.morefree.policies.MoReFreePolicy.hold_latent`).
    :param achieved_goal: the env's achieved goal.
    :param box: (low, high) of the search (:func:`goal_box`).
    :param rng: the scheduler's generator (candidate draws).
    :param samples: goals scored per round.
    :param iterations: rounds.
    :param elite_fraction: share of the best goals the search refits to.
    :param horizon: imagined steps toward each goal.
    :param gamma: discount.
    :param lambda_: TD(lambda) parameter.
    :param expl_reward_scale: scale of pi_E's disagreement reward.
    :return: the goal.
    """
    low, high = box
    mean = np.asarray(achieved_goal, dtype=np.float64).reshape(-1)
    std = 0.5 * (high - low)
    n_elite = max(2, int(round(elite_fraction * samples)))
    with th.no_grad():
        start = policy.hold_latent(state)
        for _ in range(iterations):
            candidates = np.clip(mean + std * rng.standard_normal((samples, mean.size)), low, high)
            fitness = peg_fitness(policy, start, candidates, horizon, gamma, lambda_, expl_reward_scale)
            elite = candidates[th.topk(fitness, n_elite).indices.cpu().numpy()]
            mean, std = elite.mean(0), np.sqrt(elite.var(0) + 1e-6)
    return np.clip(mean + std * rng.standard_normal(mean.size), low, high)
