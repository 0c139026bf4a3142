"""Continuous Episodic Control (CEC), thesis Chapter 4 (Yang et al., IEEE CoG 2023)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv

from sb3_gcrl.cec.policies import CECPolicy
from sb3_gcrl.common.arguments import constructor_defaults
from sb3_gcrl.episodic_control.algorithm import EpisodicControlAlgorithm

#: the memory settings' defaults, stated by the policy
_MEMORY = constructor_defaults(CECPolicy)


class CEC(EpisodicControlAlgorithm):
    """Continuous Episodic Control: a non-parametric memory of (state, action, return) rows acts directly.

    After each finished episode every step's discounted return updates the memory (Eq. 4.3/4.4:
    replace the nearest row within ``d`` if the new return is higher, add a row if the nearest is
    farther than ``d``, evict the least recently updated row when full). Actions are sampled from
    the ``k`` nearest rows within ``n * d`` by ``softmax(v / tau)`` (Eq. 4.5), with Gaussian noise
    ``sigma`` with probability epsilon, or uniformly at random when no row qualifies. Evaluation
    (``deterministic=True``) takes the action of the nearest row. Details and departures from the
    authors' code: :mod:`sb3_gcrl.memory.cec_memory` and ``docs/episodic_control.md``.

    Table 4.4 symbols -> arguments: ``k`` = ``n_neighbors``, ``tau`` = ``temperature``,
    ``sigma`` = ``noise_std``, ``n`` = ``filter_factor``, ``d`` = ``distance_threshold``. Defaults are
    the PointUMaze row of Table 4.4 (k=5, tau=0.1, sigma=0.3, n=1, d=0.1).

    Dict observations (goal envs) are keyed by ``observation_keys`` concatenated in order, default
    ``("observation", "desired_goal")``.

    :param policy: ``"CECPolicy"`` (aliases ``"MlpPolicy"``, ``"MultiInputPolicy"``) or a subclass.
    :param env: env with a bounded ``Box`` action space (any number of envs), or its registered id.
    :param capacity: maximum memory rows (authors: 1e6).
    :param distance_threshold: ``d``: update radius of Eq. 4.3/4.4 (Euclidean, in key units).
    :param filter_factor: ``n``: only rows within ``n * d`` vote in Eq. 4.5.
    :param n_neighbors: ``k``: neighbours considered for action selection.
    :param temperature: ``tau`` of the softmax in Eq. 4.5 (> 0).
    :param noise_std: ``sigma``: std of the Gaussian exploration noise, in action units.
    :param exploration_initial_eps: initial probability epsilon of adding noise (authors: 0.9).
    :param exploration_final_eps: final epsilon (authors: 0.05).
    :param exploration_fraction: fraction of the budget over which epsilon decays linearly. The thesis
        keeps epsilon fixed and does not give it; the authors' code decays it linearly 0.9 -> 0.05.
    :param projection_dim: Gaussian random projection of the key to this many dims (thesis: 8 for
        FetchReach), ``None`` for the raw (concatenated) observation.
    :param kwargs: the other :class:`~sb3_gcrl.episodic_control.EpisodicControlAlgorithm` arguments (``gamma``:
        discount of the Monte-Carlo returns of Algorithm 1, ``observation_keys``, ``knn_backend``,
        ``rebuild_threshold``, ``policy_kwargs``, ``seed``, ``verbose``, ...).
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "CECPolicy": CECPolicy,
        "MlpPolicy": CECPolicy,
        "MultiInputPolicy": CECPolicy,
    }
    policy: CECPolicy

    def __init__(
        self,
        policy: str | type[CECPolicy],
        env: GymEnv | str,
        capacity: int = _MEMORY["capacity"],
        distance_threshold: float = _MEMORY["distance_threshold"],
        filter_factor: float = _MEMORY["filter_factor"],
        n_neighbors: int = _MEMORY["n_neighbors"],
        temperature: float = _MEMORY["temperature"],
        noise_std: float = _MEMORY["noise_std"],
        exploration_initial_eps: float = 0.9,
        exploration_final_eps: float = 0.05,
        exploration_fraction: float = 0.5,
        projection_dim: int | None = None,
        **kwargs: Any,
    ) -> None:
        self.capacity = capacity
        self.distance_threshold = distance_threshold
        self.filter_factor = filter_factor
        self.n_neighbors = n_neighbors
        self.temperature = temperature
        self.noise_std = noise_std
        super().__init__(
            policy, env, exploration_initial_eps, exploration_final_eps, exploration_fraction, projection_dim, **kwargs
        )

    def _check_spaces(self, observation_space: spaces.Space, action_space: spaces.Space) -> None:
        if not isinstance(action_space, spaces.Box):
            raise ValueError(
                f"CEC needs a continuous (Box) action space, got {action_space}; use sb3_gcrl.MFEC for discrete actions"
            )
        if not (np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))):
            raise ValueError(
                "CEC needs a bounded Box action space (random actions are drawn uniformly from it); "
                "rescale the env's actions, e.g. with gymnasium.wrappers.RescaleAction"
            )

    def _memory_kwargs(self) -> dict[str, Any]:
        return {
            "capacity": self.capacity,
            "distance_threshold": self.distance_threshold,
            "filter_factor": self.filter_factor,
            "n_neighbors": self.n_neighbors,
            "temperature": self.temperature,
            "noise_std": self.noise_std,
        }

    def _update_memory(self, keys: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> dict[str, int]:
        return self.policy.memory.update_episode(keys, actions.reshape(len(actions), -1), returns)
