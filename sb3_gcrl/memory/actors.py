"""The episodic-control actors: how a CEC or MFEC memory picks actions, for CEC/MFEC and for the 2M agents.

One meaning of epsilon in both (see ``docs/glossary.md``): the probability of exploring at a step.

- CEC (thesis Algorithm 1, SELECT ACTION): sample a stored action by Eq. 4.5, then with probability epsilon add
  ``N(0, sigma^2)`` noise; a query with no stored row within ``n * d`` takes a uniformly random action.
- MFEC (Sec. 5.2.3): greedy on the Eq. 5.2 estimate, ties broken at random, and with probability epsilon a
  uniformly random action (epsilon-greedy).

Evaluation (``deterministic=True``) never draws random numbers: CEC takes the nearest row's action (the middle of
the action space while the memory is empty), MFEC the greedy action with ties broken by lowest index.
"""

from __future__ import annotations

import numpy as np

from sb3_gcrl.memory.cec_memory import CECMemory
from sb3_gcrl.memory.mfec_memory import MFECMemory, argmax_random_ties


def cec_actions(
    memory: CECMemory,
    keys: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    rng: np.random.Generator,
    deterministic: bool,
    epsilon: float,
    noise_std: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Actions of a CEC memory for a batch of keys (thesis Algorithm 1 and Sec. 4.4).

    :param memory: the CEC memory.
    :param keys: ``(n, key_dim)`` keys.
    :param low: flat lower bound of the action space the memory stores actions in.
    :param high: flat upper bound.
    :param rng: generator of the Eq. 4.5 sampling, the noise and the random actions.
    :param deterministic: nearest row's action (evaluation) instead of the exploring action.
    :param epsilon: probability of adding Gaussian noise to the sampled action (Algorithm 1).
    :param noise_std: sigma of the noise, in action units.
    :return: ``(actions, found)``: flat ``(n, action_dim)`` float32 actions clipped to ``[low, high]``, and the
        mask of queries the memory could answer.
    """
    n = len(keys)
    if deterministic:
        actions, found = memory.greedy_actions(keys)
        if not found.all():
            actions[~found] = (low + high) / 2
        return actions, found
    actions, found = memory.select_actions(keys, rng)
    noisy = found & (rng.random(n) < epsilon)
    if noisy.any():
        actions[noisy] += rng.normal(0.0, noise_std, size=(int(noisy.sum()), actions.shape[1]))
    if not found.all():
        actions[~found] = rng.uniform(low, high, size=(int((~found).sum()), len(low)))
    np.clip(actions, low, high, out=actions)
    return actions, found


def mfec_actions(
    memory: MFECMemory, keys: np.ndarray, rng: np.random.Generator, deterministic: bool, epsilon: float
) -> tuple[np.ndarray, np.ndarray]:
    """Actions of an MFEC memory for a batch of keys (thesis Sec. 5.2.3).

    :param memory: the MFEC memory.
    :param keys: ``(n, key_dim)`` keys.
    :param rng: generator of the tie-breaking and the random actions.
    :param deterministic: greedy with ties broken by lowest index, no exploration.
    :param epsilon: probability of a uniformly random action (epsilon-greedy); 0 when the caller explores itself.
    :return: ``(actions, known)``: ``(n,)`` table indices ``0 .. n_actions - 1`` and the mask of queries whose
        chosen action had a finite estimate.
    """
    q = memory.estimate(keys)
    n, n_actions = q.shape
    actions = argmax_random_ties(q, None if deterministic else rng)
    if not deterministic and epsilon > 0:
        explore = rng.random(n) < epsilon
        if explore.any():
            actions[explore] = rng.integers(n_actions, size=int(explore.sum()))
    known = np.isfinite(q[np.arange(n), actions])
    return actions, known
