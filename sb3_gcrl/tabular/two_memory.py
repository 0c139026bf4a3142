"""Tabular 2M (thesis Sec. 5.5.1, Algorithm 2 with tabular EC and tabular Q-learning; Fig. 5.5)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from stable_baselines3.common.policies import BasePolicy

from sb3_gcrl.tabular.policies import TabularTwoMemoryPolicy
from sb3_gcrl.tabular.q_learning import q_learning_update, sample_tabular_batch
from sb3_gcrl.tabular.tabular_algorithm import TabularAlgorithm
from sb3_gcrl.two_memory.dispatch import TwoMemoryAlgorithmMixin
from sb3_gcrl.two_memory.schedules import PecSchedule


class TabularTwoMemory(TwoMemoryAlgorithmMixin, TabularAlgorithm):
    """Tabular two-memory agent: per episode and per env, the EC table acts with probability p_ec, else the Q-table
    (epsilon-greedy on both); every transition goes to the replay buffer that trains the Q-table, every finished
    episode updates the EC table (data sharing, Sec. 5.4.3; ``data_sharing=False`` gives ablation 2Mw/oDS);
    ``predict(deterministic=True)`` uses the memory with the higher mean return over its last ``score_window``
    training episodes (Eq. 5.6).

    :param policy: policy class or alias.
    :param env: env with Discrete observation and action spaces.
    :param p_ec_schedule: p_ec schedule, see :func:`~sb3_gcrl.two_memory.schedules.make_pec_schedule`. ``None``:
        the policy's ``default_p_ec_schedule``, the authors' tabular 0.9 -> 0.01 over tau = 2e4 steps (Eq. 5.5).
    :param data_sharing: share every episode between both memories (thesis) or not (2Mw/oDS).
    :param score_window: n of Eq. 5.6.
    :param ec_gamma: discount of the returns stored in the EC table (None: ``gamma``).
    :param kwargs: the other :class:`~sb3_gcrl.tabular.tabular_algorithm.TabularAlgorithm` arguments.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"TabularTwoMemoryPolicy": TabularTwoMemoryPolicy}
    policy: TabularTwoMemoryPolicy

    def __init__(
        self,
        policy: str | type[BasePolicy] = "TabularTwoMemoryPolicy",
        env: Any = None,
        p_ec_schedule: PecSchedule | float | str | dict[str, Any] | None = None,
        data_sharing: bool = True,
        score_window: int = 50,
        ec_gamma: float | None = None,
        **kwargs: Any,
    ) -> None:
        self._own_two_memory_kwargs(kwargs)
        self.p_ec_schedule = p_ec_schedule
        self.data_sharing = data_sharing
        self.score_window = score_window
        self.ec_gamma = ec_gamma
        init_setup_model = kwargs.pop("_init_setup_model", True)
        super().__init__(policy, env, _init_setup_model=False, **kwargs)
        if init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        self._configure_two_memory()
        super()._setup_model()

    @property
    def q_table(self) -> np.ndarray:
        return self.policy.q_table

    @property
    def ec_table(self) -> np.ndarray:
        return self.policy.ec_table

    def train(self, gradient_steps: int, batch_size: int = 32) -> None:
        if not self._replay_ready():
            return
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
