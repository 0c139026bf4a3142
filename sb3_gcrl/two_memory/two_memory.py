"""2M agents (thesis Ch. 5, Algorithm 2): TwoMemoryDQN (MFEC + DQN) and TwoMemorySAC (CEC + SAC, ours)."""

from __future__ import annotations

from typing import Any, ClassVar

from gymnasium import spaces
from stable_baselines3 import DQN, SAC
from stable_baselines3.common.policies import BasePolicy

from sb3_gcrl.common.arguments import constructor_defaults
from sb3_gcrl.two_memory.algorithm import TwoMemoryAlgorithmMixin
from sb3_gcrl.two_memory.policies import (
    TwoMemoryDQNPolicy,
    TwoMemoryMinAtarPolicy,
    TwoMemoryMultiInputDQNPolicy,
    TwoMemoryMultiInputSACPolicy,
    TwoMemorySACPolicy,
)

#: the EC settings' defaults, stated by the policies (stock DQN and SAC build them alone)
_MFEC = constructor_defaults(TwoMemoryDQNPolicy)
_CEC = constructor_defaults(TwoMemorySACPolicy)


class TwoMemoryDQN(TwoMemoryAlgorithmMixin, DQN):
    """Two-memory agent with an MFEC table (2M-EC) and a DQN (2M-RL), thesis Ch. 5 / Algorithm 2.

    Per episode and per env, MFEC acts with probability p_ec, else the Q-network; epsilon-greedy (drawn per env)
    on both. Every transition goes to the replay buffer that trains the DQN on its usual schedule, every finished
    episode updates MFEC (data sharing; ``data_sharing=False`` is ablation 2Mw/oDS: each memory learns only from its
    own episodes). ``predict(deterministic=True)`` uses the memory with the higher mean return over its last
    ``score_window`` training episodes (Eq. 5.6). Logs ``two_memory/*`` (see
    :class:`~sb3_gcrl.two_memory.algorithm.TwoMemoryAlgorithmMixin`).

    Policies: ``"MlpPolicy"`` (SB3 MLP Q-network), ``"MinAtarPolicy"`` (the authors' CNN), ``"MultiInputPolicy"``
    (Dict observations, e.g. goal envs).

    :param policy: policy class or alias.
    :param env: env with a Discrete action space.
    :param ec_projection_dim: random-projection dimension of the MFEC keys (authors: 8; None: raw observations).
    :param ec_capacity_per_action: rows per MFEC action table (None: authors' ``1e5 / (2 * n_actions)``).
    :param ec_n_neighbors: k of the MFEC estimate (Table 5.1: 3).
    :param knn_backend: kNN backend of the MFEC tables (see :class:`~sb3_gcrl.memory.KNNIndex`).
    :param kwargs: the 2M settings (see :class:`~sb3_gcrl.two_memory.algorithm.TwoMemoryAlgorithmMixin`):
        ``p_ec_schedule`` (``None``: :attr:`default_p_ec_schedule`, Eq. 5.5 with the thesis's decayed schedule
        0.9 -> 0.1 of Table 5.1 / Sec. 5.5.3 and decay 5e5 env steps), ``data_sharing`` (thesis Sec. 5.4.3),
        ``score_window`` (n of Eq. 5.6, 50), ``ec_gamma`` (discount of the MFEC returns, ``None``: ``gamma``),
        ``ec_update_truncated`` (also write cut episodes into MFEC); and every :class:`~stable_baselines3.DQN`
        argument, ``n_steps`` only 1 (the replay buffer that tags each transition's source gives one-step returns).
    :raises ValueError: for a non-Discrete action space (use :class:`TwoMemorySAC`), a 2M or EC setting given in
        ``policy_kwargs``, or ``n_steps > 1``.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": TwoMemoryDQNPolicy,
        "MinAtarPolicy": TwoMemoryMinAtarPolicy,
        "MultiInputPolicy": TwoMemoryMultiInputDQNPolicy,
    }
    policy: TwoMemoryDQNPolicy
    two_memory_policy_class = TwoMemoryDQNPolicy
    two_memory_action_space = (spaces.Discrete, "TwoMemorySAC")

    def __init__(
        self,
        policy: str | type[TwoMemoryDQNPolicy],
        env: Any,
        *,
        ec_projection_dim: int | None = _MFEC["ec_projection_dim"],
        ec_capacity_per_action: int | None = _MFEC["ec_capacity_per_action"],
        ec_n_neighbors: int = _MFEC["ec_n_neighbors"],
        knn_backend: str = _MFEC["knn_backend"],
        **kwargs: Any,
    ) -> None:
        ec_kwargs = {
            "ec_projection_dim": ec_projection_dim,
            "ec_capacity_per_action": ec_capacity_per_action,
            "ec_n_neighbors": ec_n_neighbors,
            "knn_backend": knn_backend,
        }
        super().__init__(policy, env, ec_kwargs=ec_kwargs, **kwargs)


class TwoMemorySAC(TwoMemoryAlgorithmMixin, SAC):
    """Two-memory agent for continuous actions: a CEC memory (2M-EC, thesis Ch. 4) and SAC (2M-RL).

    Not in the thesis (it combines MFEC with DQN only): the same Algorithm 2 with CEC as the episodic half. Same
    switches (p_ec schedule, data sharing, score window) and logging as :class:`TwoMemoryDQN`. SAC explores with its
    own stochastic policy; EC-run episodes explore as standalone CEC does (thesis Algorithm 1; see
    :class:`~sb3_gcrl.two_memory.policies.TwoMemorySACPolicy`).

    :param policy: policy class or alias (``"MlpPolicy"``, ``"MultiInputPolicy"``).
    :param env: env with a Box action space.
    :param ec_projection_dim: random-projection dimension of the CEC keys (None: raw observations).
    :param ec_capacity: CEC rows.
    :param ec_distance_threshold: d of Table 4.4.
    :param ec_filter_factor: n of Table 4.4.
    :param ec_n_neighbors: k of Table 4.4.
    :param ec_temperature: tau of Eq. 4.5 (the softmax temperature).
    :param ec_epsilon: epsilon of Algorithm 1: probability of Gaussian noise on an EC action while training.
    :param ec_noise_std: sigma of Algorithm 1: std of that noise, in [-1, 1] action units.
    :param knn_backend: kNN backend of the CEC memory.
    :param kwargs: the 2M settings, as for :class:`TwoMemoryDQN` (``p_ec_schedule`` ``None``:
        :attr:`default_p_ec_schedule`, Eq. 5.5 with 0.9 -> 0.1 and decay 5e4 steps, ours: scaled to the 1e5-step
        budgets of Ch. 4's tasks); and every :class:`~stable_baselines3.SAC` argument, ``n_steps`` only 1.
    :raises ValueError: for a non-Box action space (use :class:`TwoMemoryDQN`), ``use_sde=True``, ``n_steps > 1``,
        or a 2M or EC setting given in ``policy_kwargs``.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": TwoMemorySACPolicy,
        "MultiInputPolicy": TwoMemoryMultiInputSACPolicy,
    }
    policy: TwoMemorySACPolicy
    default_p_ec_schedule = {"type": "decayed", "start": 0.9, "end": 0.1, "decay": 50_000}  # noqa: RUF012
    two_memory_policy_class = TwoMemorySACPolicy
    two_memory_action_space = (spaces.Box, "TwoMemoryDQN")

    def __init__(
        self,
        policy: str | type[TwoMemorySACPolicy],
        env: Any,
        *,
        ec_projection_dim: int | None = _CEC["ec_projection_dim"],
        ec_capacity: int = _CEC["ec_capacity"],
        ec_distance_threshold: float = _CEC["ec_distance_threshold"],
        ec_filter_factor: float = _CEC["ec_filter_factor"],
        ec_n_neighbors: int = _CEC["ec_n_neighbors"],
        ec_temperature: float = _CEC["ec_temperature"],
        ec_epsilon: float = _CEC["ec_epsilon"],
        ec_noise_std: float = _CEC["ec_noise_std"],
        knn_backend: str = _CEC["knn_backend"],
        **kwargs: Any,
    ) -> None:
        ec_kwargs = {
            "ec_projection_dim": ec_projection_dim,
            "ec_capacity": ec_capacity,
            "ec_distance_threshold": ec_distance_threshold,
            "ec_filter_factor": ec_filter_factor,
            "ec_n_neighbors": ec_n_neighbors,
            "ec_temperature": ec_temperature,
            "ec_epsilon": ec_epsilon,
            "ec_noise_std": ec_noise_std,
            "knn_backend": knn_backend,
        }
        super().__init__(policy, env, ec_kwargs=ec_kwargs, **kwargs)

    def _setup_model(self) -> None:
        if self.use_sde:
            raise ValueError(
                "TwoMemorySAC does not support use_sde=True (EC-run steps have no SDE noise); set it False"
            )
        super()._setup_model()
