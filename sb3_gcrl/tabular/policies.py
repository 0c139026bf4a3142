"""Policies of the tabular algorithms (thesis Sec. 5.5.1): Q-table, episodic-control table and their 2M hybrid.

The tables are numpy arrays (so updates are cheap in-place numpy ops); ``get_extra_state`` puts them into the
policy's ``state_dict`` as tensors, so SB3's ``save``/``load`` restores them exactly.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import Schedule

from sb3_gcrl.two_memory.dispatch import TwoMemoryDispatchMixin


def check_tabular_spaces(observation_space: spaces.Space, action_space: spaces.Space, who: str) -> tuple[int, int]:
    """Return (n_states, n_actions) or raise a ValueError that names the fix."""
    if not isinstance(observation_space, spaces.Discrete):
        raise ValueError(
            f"{who} needs a Discrete observation space (one table row per state), got {observation_space}. "
            "Use MFEC / TwoMemoryDQN for image or vector observations, "
            "or wrap the env so that it returns a state index."
        )
    if not isinstance(action_space, spaces.Discrete):
        raise ValueError(f"{who} needs a Discrete action space, got {action_space}")
    if observation_space.start != 0 or action_space.start != 0:
        raise ValueError(f"{who} needs Discrete spaces that start at 0, got {observation_space}, {action_space}")
    return int(observation_space.n), int(action_space.n)


def greedy_actions(values: np.ndarray, break_ties_randomly: bool) -> np.ndarray:
    """Argmax over the last axis; with ``break_ties_randomly`` a uniformly random action among the maxima.

    Random tie-breaking matters for tabular agents that start from equal values (an all-zero table would
    otherwise always pick action 0 while exploring); deterministic prediction keeps the first maximum.
    """
    if not break_ties_randomly:
        return values.argmax(axis=-1)
    is_max = values == values.max(axis=-1, keepdims=True)
    keys = np.random.random(values.shape) * is_max
    return keys.argmax(axis=-1)


def _states(observation: th.Tensor) -> np.ndarray:
    return observation.reshape(-1).long().cpu().numpy()


class TabularBasePolicy(BasePolicy):
    """:class:`~stable_baselines3.common.policies.BasePolicy` of a table: no images to normalise, so
    ``normalize_images`` is not a constructor parameter (``policy.save`` / ``Policy.load`` round-trip)."""

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.pop("normalize_images", None)
        return data


class TabularQPolicy(TabularBasePolicy):
    """Greedy policy of a Q-table ``Q[s, a]`` (tabular 1-step Q-learning, thesis Eq. 5.1 in its tabular form).

    :param observation_space: Discrete state space.
    :param action_space: Discrete action space.
    :param lr_schedule: unused (the algorithm applies the learning rate); kept for SB3's policy signature.
    :param initial_value: initial Q-value of every entry.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule | None = None,
        initial_value: float = 0.0,
    ) -> None:
        super().__init__(observation_space, action_space)
        n_states, n_actions = check_tabular_spaces(observation_space, action_space, type(self).__name__)
        self.initial_value = float(initial_value)
        self.q_table = np.full((n_states, n_actions), self.initial_value, dtype=np.float64)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(initial_value=self.initial_value)
        return data

    def q_values(self, states: np.ndarray) -> np.ndarray:
        """Q-values of a batch of state indices, shape (n, n_actions)."""
        return self.q_table[states]

    def _predict(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        return th.as_tensor(greedy_actions(self.q_values(_states(observation)), not deterministic))

    def get_extra_state(self) -> dict[str, th.Tensor]:
        return {"q_table": th.from_numpy(self.q_table.copy())}

    def set_extra_state(self, state: dict[str, th.Tensor]) -> None:
        table = state["q_table"].numpy()
        if table.shape != self.q_table.shape:
            raise ValueError(f"saved Q-table has shape {table.shape}, this policy expects {self.q_table.shape}")
        self.q_table[...] = table


class TabularECPolicy(TabularBasePolicy):
    """Tabular episodic control: ``Q_ec[s, a]`` is the highest discounted return seen after (s, a) (Eq. 5.2).

    Unvisited entries are stored as ``-inf`` and read as ``unseen_value`` (0 in the authors' code, which is
    optimistic when rewards are negative and so drives the agent to untried actions).

    :param observation_space: Discrete state space.
    :param action_space: Discrete action space.
    :param lr_schedule: unused; kept for SB3's policy signature.
    :param unseen_value: value of a never-visited (s, a).
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule | None = None,
        unseen_value: float = 0.0,
    ) -> None:
        super().__init__(observation_space, action_space)
        n_states, n_actions = check_tabular_spaces(observation_space, action_space, type(self).__name__)
        self.unseen_value = float(unseen_value)
        self.ec_table = np.full((n_states, n_actions), -np.inf, dtype=np.float64)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(unseen_value=self.unseen_value)
        return data

    def q_values(self, states: np.ndarray) -> np.ndarray:
        """EC values of a batch of state indices (unvisited -> ``unseen_value``), shape (n, n_actions)."""
        values = self.ec_table[states]
        return np.where(np.isfinite(values), values, self.unseen_value)

    def update_episode(self, states: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> None:
        """Eq. 5.2 for every step of an episode: ``Q_ec[s, a] = max(Q_ec[s, a], G)`` (G if unvisited).

        :param states: state indices, shape (T,) or (T, 1).
        :param actions: actions, shape (T,).
        :param returns: discounted returns G_t, shape (T,).
        """
        np.maximum.at(
            self.ec_table, (np.asarray(states).reshape(-1).astype(np.int64), np.asarray(actions).reshape(-1)), returns
        )

    def _predict(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        return th.as_tensor(greedy_actions(self.q_values(_states(observation)), not deterministic))

    def get_extra_state(self) -> dict[str, th.Tensor]:
        return {"ec_table": th.from_numpy(self.ec_table.copy())}

    def set_extra_state(self, state: dict[str, th.Tensor]) -> None:
        table = state["ec_table"].numpy()
        if table.shape != self.ec_table.shape:
            raise ValueError(f"saved EC table has shape {table.shape}, this policy expects {self.ec_table.shape}")
        self.ec_table[...] = table


class TabularTwoMemoryPolicy(TwoMemoryDispatchMixin, TabularBasePolicy):
    """Tabular 2M (thesis Sec. 5.5.1): a :class:`TabularECPolicy` (2M-EC) and a :class:`TabularQPolicy` (2M-RL)
    with per-episode dispatch (Algorithm 2) and the evaluation choice of Eq. 5.6.

    :param observation_space: Discrete state space.
    :param action_space: Discrete action space.
    :param lr_schedule: unused; kept for SB3's policy signature.
    :param data_sharing: update the EC table with every episode (True, thesis) or only with its own.
    :param score_window: n of Eq. 5.6.
    :param ec_gamma: discount of the returns stored in the EC table (``None``: the algorithm's ``gamma``).
    :param ec_update_truncated: also learn from time-limit-truncated episodes (thesis: every finished episode; see
        ``TwoMemoryDispatchMixin``).
    :param unseen_value: EC value of an unvisited (s, a).
    :param initial_q: initial Q-value.
    """

    ec_parameters = (*TwoMemoryDispatchMixin.ec_parameters, "unseen_value", "initial_q")  # noqa: RUF012

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule | None = None,
        data_sharing: bool = True,
        score_window: int = 50,
        ec_gamma: float | None = None,
        ec_update_truncated: bool = True,
        unseen_value: float = 0.0,
        initial_q: float = 0.0,
    ) -> None:
        TabularBasePolicy.__init__(self, observation_space, action_space)
        self.ec_policy = TabularECPolicy(observation_space, action_space, unseen_value=unseen_value)
        self.q_policy = TabularQPolicy(observation_space, action_space, initial_value=initial_q)
        self.unseen_value = self.ec_policy.unseen_value
        self.initial_q = self.q_policy.initial_value
        self._init_dispatch(data_sharing, score_window, ec_gamma, ec_update_truncated)

    @property
    def q_table(self) -> np.ndarray:
        return self.q_policy.q_table

    @property
    def ec_table(self) -> np.ndarray:
        return self.ec_policy.ec_table

    def _episodic_actions(self, observation: th.Tensor, deterministic: bool) -> th.Tensor:
        return self.ec_policy._predict(observation, deterministic)

    def _parametric_actions(self, observation: th.Tensor, deterministic: bool) -> th.Tensor:
        return self.q_policy._predict(observation, deterministic)

    def update_episodic_memory(self, observations: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> None:
        self.ec_policy.update_episode(observations, actions, returns)
