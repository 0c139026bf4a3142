"""Model-Free Episodic Control (MFEC; Blundell et al., 2016) as used in thesis Section 5.2.3."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv

from sb3_gcrl.common.arguments import constructor_defaults
from sb3_gcrl.episodic_control.algorithm import EpisodicControlAlgorithm
from sb3_gcrl.mfec.policies import MFECPolicy

#: the memory settings' defaults, stated by the policy
_MEMORY = constructor_defaults(MFECPolicy)


class MFEC(EpisodicControlAlgorithm):
    """Model-free episodic control: one non-parametric value table per discrete action.

    After each finished episode, ``Q_ec(s_t, a_t) <- max(G_t, Q_ec(s_t, a_t))`` on an exact key match,
    else ``G_t`` is added (Eq. 5.2), evicting the least recently updated row of the action's table
    when it is full. Acting: ``argmax_a`` of the stored value (exact match) or of the mean of the
    ``k`` nearest rows' values; actions whose table holds ``<= k`` rows count as ``+inf`` (tried
    first); epsilon-greedy on top. Keys are the observation randomly projected to
    ``projection_dim`` dims (8 in the 2M code). This is the EC half of 2M (thesis Ch. 5).

    :param policy: ``"MFECPolicy"`` (aliases ``"MlpPolicy"``, ``"MultiInputPolicy"``). There is no
        ``"CnnPolicy"`` (no network): image observations work with ``"MFECPolicy"``, transposed
        channel-first as in SB3 and keyed by the random projection.
    :param env: env with a ``Discrete`` action space (any number of envs), or its registered id.
    :param capacity_per_action: rows per action table (2M code: ``1e5 / (2 * n_actions)``; MFEC paper: 1e6).
    :param n_neighbors: ``k`` of the kNN estimate (2M code: 3).
    :param exploration_initial_eps: initial epsilon.
    :param exploration_final_eps: final epsilon.
    :param exploration_fraction: fraction of the budget over which epsilon decays linearly.
    :param projection_dim: Gaussian random projection dimension, ``None`` for raw observations
        (fine for small tabular/discrete observations such as WindyGrid).
    :param kwargs: the other :class:`~sb3_gcrl.episodic_control.EpisodicControlAlgorithm` arguments (``gamma``:
        discount of the Monte-Carlo returns, ``observation_keys``, ``knn_backend``, ``rebuild_threshold``,
        ``policy_kwargs``, ``seed``, ``verbose``, ...).
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MFECPolicy": MFECPolicy,
        "MlpPolicy": MFECPolicy,
        "MultiInputPolicy": MFECPolicy,
    }
    policy: MFECPolicy

    def __init__(
        self,
        policy: str | type[MFECPolicy],
        env: GymEnv | str,
        capacity_per_action: int = _MEMORY["capacity_per_action"],
        n_neighbors: int = _MEMORY["n_neighbors"],
        exploration_initial_eps: float = 0.1,
        exploration_final_eps: float = 0.005,
        exploration_fraction: float = 0.1,
        projection_dim: int | None = 8,
        **kwargs: Any,
    ) -> None:
        self.capacity_per_action = capacity_per_action
        self.n_neighbors = n_neighbors
        super().__init__(
            policy, env, exploration_initial_eps, exploration_final_eps, exploration_fraction, projection_dim, **kwargs
        )

    def _check_spaces(self, observation_space: spaces.Space, action_space: spaces.Space) -> None:
        if not isinstance(action_space, spaces.Discrete):
            raise ValueError(
                f"MFEC needs a Discrete action space, got {action_space}; use sb3_gcrl.CEC for continuous (Box) actions"
            )

    def _memory_kwargs(self) -> dict[str, Any]:
        return {"capacity_per_action": self.capacity_per_action, "n_neighbors": self.n_neighbors}

    def _update_memory(self, keys: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> dict[str, int]:
        added = self.policy.memory.update_episode(keys, actions - self.policy.action_start, returns)
        return {"added": added, "updated": len(keys) - added}
