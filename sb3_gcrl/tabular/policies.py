"""Policies of the tabular algorithms (thesis Sec. 5.5.1): Q-table, episodic-control table and their 2M hybrid.

The tables are numpy arrays (so updates are cheap in-place numpy ops); ``get_extra_state`` puts them into the
policy's ``state_dict`` as tensors, together with the state of the generator that breaks ties, so SB3's
``save``/``load`` restores them exactly and a loaded policy continues its draws.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import Schedule

from sb3_gcrl.common.seeding import draw_seed, generator_state, restore_generator, seeded_generator
from sb3_gcrl.common.validation import check_float
from sb3_gcrl.memory.mfec_memory import argmax_random_ties
from sb3_gcrl.two_memory.policy_mixin import TwoMemoryDispatchMixin


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


def _states(observation: th.Tensor) -> np.ndarray:
    return observation.reshape(-1).long().cpu().numpy()


class TabularBasePolicy(BasePolicy):
    """:class:`~stable_baselines3.common.policies.BasePolicy` of a table: no images to normalise, so
    ``normalize_images`` is not a constructor parameter (``policy.save`` / ``Policy.load`` round-trip)."""

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.pop("normalize_images", None)
        return data


class TabularTablePolicy(TabularBasePolicy):
    """Greedy policy of one ``(n_states, n_actions)`` table: a numpy array named :attr:`table_name`, saved in the
    ``state_dict`` under that name, whose start is set by one float constructor argument, :attr:`value_parameter`.

    Ties are broken uniformly at random while exploring (``deterministic=False``), which matters for tables that
    start from equal values (an all-zero table would otherwise always pick action 0), and by the first maximum for
    deterministic predictions. The tie-breaking generator is seeded from the action space's generator (which SB3
    seeds with the model's seed before it builds the policy), reseeded by :meth:`set_seed` and saved with the table.

    :param observation_space: Discrete state space.
    :param action_space: Discrete action space.
    :param value: the value of :attr:`value_parameter` (kept as an attribute of that name).
    :param initial_entry: what every entry of the table stores at construction.
    """

    #: attribute (and ``state_dict`` key) of the table
    table_name: ClassVar[str]
    #: the constructor argument that sets the table's start
    value_parameter: ClassVar[str]
    #: the table's name in error messages
    table_label: ClassVar[str]

    def __init__(
        self, observation_space: spaces.Space, action_space: spaces.Space, value: float, initial_entry: float
    ) -> None:
        super().__init__(observation_space, action_space)
        n_states, n_actions = check_tabular_spaces(observation_space, action_space, type(self).__name__)
        setattr(self, self.value_parameter, check_float(self.value_parameter, value))
        setattr(self, self.table_name, np.full((n_states, n_actions), initial_entry, dtype=np.float64))
        #: generator of the random tie-breaking
        self.rng = np.random.default_rng(draw_seed(action_space))

    @property
    def table(self) -> np.ndarray:
        """The table (``q_table`` / ``ec_table``)."""
        return getattr(self, self.table_name)

    def set_seed(self, seed: int | None) -> None:
        """Reseed the tie-breaking generator (the algorithm's ``set_random_seed`` calls this).

        :param seed: the seed; ``None``: fresh entropy.
        """
        self.rng = seeded_generator(seed, self.table_name)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data[self.value_parameter] = getattr(self, self.value_parameter)
        return data

    def q_values(self, states: np.ndarray) -> np.ndarray:
        """Values of a batch of state indices, shape (n, n_actions)."""
        return self.table[states]

    def _predict(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        values = self.q_values(_states(observation))
        return th.as_tensor(argmax_random_ties(values, None if deterministic else self.rng))

    def get_extra_state(self) -> dict[str, th.Tensor]:
        return {self.table_name: th.from_numpy(self.table.copy()), "rng": generator_state(self.rng)}

    def set_extra_state(self, state: dict[str, th.Tensor]) -> None:
        table = state[self.table_name].numpy()
        if table.shape != self.table.shape:
            raise ValueError(
                f"saved {self.table_label} has shape {table.shape}, this policy expects {self.table.shape}"
            )
        self.table[...] = table
        self.rng = restore_generator(state["rng"])


class TabularQPolicy(TabularTablePolicy):
    """Greedy policy of a Q-table ``Q[s, a]`` (tabular 1-step Q-learning, thesis Eq. 5.1 in its tabular form).

    :param observation_space: Discrete state space.
    :param action_space: Discrete action space.
    :param lr_schedule: unused (the algorithm applies the learning rate); kept for SB3's policy signature.
    :param initial_value: initial Q-value of every entry.
    """

    table_name = "q_table"
    value_parameter = "initial_value"
    table_label = "Q-table"
    q_table: np.ndarray
    initial_value: float

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule | None = None,
        initial_value: float = 0.0,
    ) -> None:
        super().__init__(observation_space, action_space, initial_value, check_float("initial_value", initial_value))


class TabularECPolicy(TabularTablePolicy):
    """Tabular episodic control: ``Q_ec[s, a]`` is the highest discounted return seen after (s, a) (Eq. 5.2).

    Unvisited entries are stored as ``-inf`` and read as ``unseen_value`` (0 in the authors' code, which is
    optimistic when rewards are negative and so drives the agent to untried actions).

    :param observation_space: Discrete state space.
    :param action_space: Discrete action space.
    :param lr_schedule: unused; kept for SB3's policy signature.
    :param unseen_value: value of a never-visited (s, a).
    """

    table_name = "ec_table"
    value_parameter = "unseen_value"
    table_label = "EC table"
    ec_table: np.ndarray
    unseen_value: float

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule | None = None,
        unseen_value: float = 0.0,
    ) -> None:
        super().__init__(observation_space, action_space, unseen_value, -np.inf)

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


class TabularTwoMemoryPolicy(TwoMemoryDispatchMixin, TabularBasePolicy):
    """Tabular 2M (thesis Sec. 5.5.1): a :class:`TabularECPolicy` (2M-EC) and a :class:`TabularQPolicy` (2M-RL)
    with per-episode dispatch (Algorithm 2) and the evaluation choice of Eq. 5.6.

    :param observation_space: Discrete state space.
    :param action_space: Discrete action space.
    :param lr_schedule: unused; kept for SB3's policy signature.
    :param score_window: n of Eq. 5.6.
    :param unseen_value: EC value of an unvisited (s, a).
    :param initial_q: initial Q-value.
    """

    ec_parameters = (*TwoMemoryDispatchMixin.ec_parameters, "unseen_value", "initial_q")  # noqa: RUF012

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule | None = None,
        score_window: int = 50,
        unseen_value: float = 0.0,
        initial_q: float = 0.0,
    ) -> None:
        TabularBasePolicy.__init__(self, observation_space, action_space)
        self.ec_policy = TabularECPolicy(observation_space, action_space, unseen_value=unseen_value)
        self.q_policy = TabularQPolicy(observation_space, action_space, initial_value=initial_q)
        self.unseen_value = self.ec_policy.unseen_value
        self.initial_q = self.q_policy.initial_value
        self._init_dispatch(score_window)

    def set_seed(self, seed: int | None) -> None:
        """Reseed the tie-breaking generators of both tables.

        :param seed: the seed; ``None``: fresh entropy.
        """
        self.ec_policy.set_seed(seed)
        self.q_policy.set_seed(seed)

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
