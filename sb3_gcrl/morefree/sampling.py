"""What a training step of the model-based MoReFree agent draws besides its replayed sequences: the goals of the
imagined pi_G rollouts (thesis Sec. 3.4.2) and the replayed pairs of the dynamical distance.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch as th

from sb3_gcrl.morefree.buffer import SequenceReplayBuffer
from sb3_gcrl.morefree.functional import symlog
from sb3_gcrl.morefree.losses import ReplayPairs


def imagination_goals(
    n: int,
    alpha: float,
    task_goals: Callable[[str, int], np.ndarray],
    replay_buffer: SequenceReplayBuffer,
    rng: np.random.Generator,
    replay_goals: str = "batch",
    own_goal_fraction: float = 0.0,
    batch_goals: np.ndarray | None = None,
    own_goals: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Goals of the imagined pi_G rollouts (thesis Sec. 3.4.2, Algorithm 2 line 14).

    :param n: number of goals.
    :param alpha: share of task-relevant goals (alpha/2 rho_0, alpha/2 rho_g*).
    :param task_goals: ``task_goals(kind, k)``: ``k`` goals of rho_0 (``kind="initial"``) or rho_g*
        (``"evaluation"``).
    :param replay_buffer: the replay (its achieved goals are the replayed goals' pool without ``batch_goals``).
    :param rng: the generator of the draws.
    :param replay_goals: ``"batch"`` (the replayed goals come from ``batch_goals`` where given) or ``"buffer"``.
    :param own_goal_fraction: share of the replayed goals replaced by the start's own achieved goal.
    :param batch_goals: achieved goals of the training batch ``(m, goal_dim)``.
    :param own_goals: each start's own achieved goal ``(n, goal_dim)``, for ``own_goal_fraction``.
    :return: goals ``(n, goal_dim)`` and their kinds ``(n,)``: 0 rho_0 (w.p. alpha/2), 1 rho_g* (alpha/2),
        2 replayed states (1 - alpha; not HER's future states), 3 the start's own achieved goal (a share
        ``own_goal_fraction`` of the replayed ones).
    """
    kinds = rng.choice(3, size=n, p=[alpha / 2, alpha / 2, 1 - alpha])
    if own_goal_fraction > 0.0:
        if own_goals is None:
            raise ValueError("own_goal_fraction > 0 needs each start's own achieved goal (own_goals)")
        kinds[(kinds == 2) & (rng.random(n) < own_goal_fraction)] = 3
    goal_dim = replay_buffer.goal_dim
    goals = np.empty((n, goal_dim), dtype=np.float32)
    for kind, name in ((0, "initial"), (1, "evaluation")):
        mask = kinds == kind
        if mask.any():
            goals[mask] = task_goals(name, int(mask.sum())).reshape(-1, goal_dim)
    mask = kinds == 2
    if mask.any():
        if replay_goals == "batch" and batch_goals is not None:
            pool = batch_goals.reshape(-1, goal_dim)
            goals[mask] = pool[rng.choice(len(pool), int(mask.sum()), replace=int(mask.sum()) > len(pool))]
        else:
            goals[mask] = replay_buffer.sample_states(int(mask.sum()), rng)[:, -goal_dim:]
    mask = kinds == 3
    if mask.any():
        goals[mask] = np.asarray(own_goals).reshape(n, goal_dim)[mask]
    return goals, kinds


def replay_pairs(
    replay_buffer: SequenceReplayBuffer,
    n_pairs: int,
    unit: int,
    neg_fraction: float,
    rng: np.random.Generator,
    device: th.device,
) -> ReplayPairs:
    """Pairs of replayed achieved goals for the distance: ``n_pairs`` pairs of one stream up to ``unit`` steps
    apart, plus ``neg_fraction`` of them as negatives (two states drawn independently from the whole buffer,
    target ``unit + 1`` steps: beyond every positive).

    :param replay_buffer: the replay.
    :param n_pairs: positive pairs.
    :param unit: steps that make distance 1 (the longest gap of a positive pair).
    :param neg_fraction: negatives per positive pair.
    :param rng: the generator of the draws.
    :param device: the device of the tensors.
    :return: (symlog earlier goals, symlog later goals, steps between them, 0/1 validity).
    """
    first, later, steps, valid = replay_buffer.sample_pairs(n_pairs, unit, rng)
    n_neg = int(round(neg_fraction * n_pairs))
    if n_neg > 0:
        goal_dim = replay_buffer.goal_dim
        first = np.concatenate([first, replay_buffer.sample_states(n_neg, rng)[:, -goal_dim:]])
        later = np.concatenate([later, replay_buffer.sample_states(n_neg, rng)[:, -goal_dim:]])
        steps = np.concatenate([steps, np.full(n_neg, unit + 1)])
        valid = np.concatenate([valid, np.ones(n_neg, dtype=bool)])
    as_tensor = lambda x, dtype=None: th.as_tensor(x, dtype=dtype, device=device)  # noqa: E731
    return symlog(as_tensor(first)), symlog(as_tensor(later)), as_tensor(steps), as_tensor(valid, th.float32)
