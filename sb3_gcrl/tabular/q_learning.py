"""Tabular 1-step Q-learning from a replay buffer (thesis Sec. 5.2.2 / 5.5.1, the "RL" agent of Fig. 5.5)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from stable_baselines3.common.policies import BasePolicy

from sb3_gcrl.tabular.policies import TabularQPolicy
from sb3_gcrl.tabular.tabular_algorithm import TabularAlgorithm


def q_learning_update(
    q_table: np.ndarray,
    states: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    next_states: np.ndarray,
    dones: np.ndarray,
    learning_rate: float,
    gamma: float,
) -> np.ndarray:
    """One batched tabular Q-learning step, in place:
    ``Q[s, a] += lr * (r + gamma * (1 - done) * max_a' Q[s', a'] - Q[s, a])``.

    All TD errors are computed from the table before the step; duplicates of an (s, a) pair in the batch add
    up (``np.add.at``), as the summed gradient of a batch would.

    :return: the TD errors, shape (batch,).
    """
    targets = rewards + gamma * (1.0 - dones) * q_table[next_states].max(axis=1)
    td_errors = targets - q_table[states, actions]
    np.add.at(q_table, (states, actions), learning_rate * td_errors)
    return td_errors


def sample_tabular_batch(algorithm: TabularAlgorithm) -> tuple[np.ndarray, ...]:
    """(states, actions, rewards, next_states, dones) of one replay batch as flat numpy arrays."""
    batch = algorithm.replay_buffer.sample(algorithm.batch_size)
    return (
        batch.observations.reshape(-1).long().numpy(),
        batch.actions.reshape(-1).long().numpy(),
        batch.rewards.reshape(-1).double().numpy(),
        batch.next_observations.reshape(-1).long().numpy(),
        batch.dones.reshape(-1).double().numpy(),
    )


class TabularQLearning(TabularAlgorithm):
    """Tabular Q-learning trained on minibatches from a replay buffer (the authors' tabular RL agent).

    Takes every :class:`~sb3_gcrl.tabular.tabular_algorithm.TabularAlgorithm` argument. Logs
    ``train/q_sum`` (the summed Q-values of Fig. 5.5 right) and ``train/td_error``.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"TabularQPolicy": TabularQPolicy}
    policy: TabularQPolicy

    def __init__(self, policy: str | type[BasePolicy] = "TabularQPolicy", env: Any = None, **kwargs: Any) -> None:
        super().__init__(policy, env, **kwargs)

    @property
    def q_table(self) -> np.ndarray:
        return self.policy.q_table

    def train(self, gradient_steps: int, batch_size: int = 32) -> None:
        learning_rate = self.lr_schedule(self._current_progress_remaining)
        td_errors = []
        for _ in range(gradient_steps):
            batch = sample_tabular_batch(self)
            td_errors.append(q_learning_update(self.q_table, *batch, learning_rate=learning_rate, gamma=self.gamma))
        self._n_updates += gradient_steps
        self.logger.record("train/learning_rate", learning_rate)
        self.logger.record("train/n_updates", self._n_updates)
        self.logger.record("train/td_error", float(np.abs(np.concatenate(td_errors)).mean()))
        self.logger.record("train/q_sum", float(self.q_table.sum()))
