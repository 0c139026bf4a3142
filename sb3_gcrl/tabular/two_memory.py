"""Tabular 2M (thesis Sec. 5.5.1, Algorithm 2 with tabular EC and tabular Q-learning; Fig. 5.5)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from stable_baselines3.common.policies import BasePolicy

from sb3_gcrl.common.arguments import constructor_defaults
from sb3_gcrl.tabular.policies import TabularTwoMemoryPolicy
from sb3_gcrl.tabular.q_learning import TabularQLearning
from sb3_gcrl.two_memory.algorithm import TwoMemoryAlgorithmMixin

#: the EC settings' defaults, stated by the policy
_POLICY = constructor_defaults(TabularTwoMemoryPolicy)


class TabularTwoMemory(TwoMemoryAlgorithmMixin, TabularQLearning):
    """Tabular two-memory agent: per episode and per env, the EC table acts with probability p_ec, else the Q-table
    (epsilon-greedy on both); every transition goes to the replay buffer that trains the Q-table (the Q-learning
    step of :class:`~sb3_gcrl.tabular.TabularQLearning`), every finished episode updates the EC table (data sharing,
    Sec. 5.4.3; ``data_sharing=False`` gives ablation 2Mw/oDS); ``predict(deterministic=True)`` uses the memory with
    the higher mean return over its last ``score_window`` training episodes (Eq. 5.6).

    :param policy: policy class or alias.
    :param env: env with Discrete observation and action spaces.
    :param unseen_value: EC value of an unvisited (s, a) (authors: 0).
    :param initial_q: initial Q-value.
    :param kwargs: the 2M settings of :class:`~sb3_gcrl.two_memory.algorithm.TwoMemoryAlgorithmMixin`
        (``p_ec_schedule``, ``None``: :attr:`default_p_ec_schedule`, the authors' tabular 0.9 -> 0.01 with decay
        2e4 steps (Eq. 5.5); ``data_sharing``, ``False``: 2Mw/oDS; ``score_window``; ``ec_gamma``, ``None``:
        ``gamma``; ``ec_update_truncated``) and the other
        :class:`~sb3_gcrl.tabular.tabular_algorithm.TabularAlgorithm` arguments.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"TabularTwoMemoryPolicy": TabularTwoMemoryPolicy}
    policy: TabularTwoMemoryPolicy
    default_p_ec_schedule = {"type": "decayed", "start": 0.9, "end": 0.01, "decay": 20_000}  # noqa: RUF012
    two_memory_policy_class = TabularTwoMemoryPolicy

    def __init__(
        self,
        policy: str | type[BasePolicy] = "TabularTwoMemoryPolicy",
        env: Any = None,
        *,
        unseen_value: float = _POLICY["unseen_value"],
        initial_q: float = _POLICY["initial_q"],
        **kwargs: Any,
    ) -> None:
        super().__init__(policy, env, ec_kwargs={"unseen_value": unseen_value, "initial_q": initial_q}, **kwargs)

    @property
    def ec_table(self) -> np.ndarray:
        return self.policy.ec_table
