"""Goal-conditioned tabular policy of the IMGEP agent (thesis Sec. 6.4.1, Eq. 6.2).

The value table ``Q[s, g, a]`` is a torch buffer of the policy, so ``model.save`` stores it in ``policy.pth``
and ``model.load`` restores it exactly. The algorithm updates it in place through :attr:`TabularGoalPolicy.q`,
a numpy view sharing the buffer's memory (CPU only, which is where a table belongs).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs


class TabularGoalPolicy(BasePolicy):
    """Greedy policy over a goal-conditioned Q-table ``Q[s, g, a]``.

    The observation is a Dict with Discrete ``observation`` (the state ``s``) and ``desired_goal`` (the goal
    ``g``); other keys (``achieved_goal``) are ignored. Ties are broken towards the lowest action index, so
    the greedy policy is deterministic (needed for loop detection in the all-goals evaluation).

    :param observation_space: Dict space with Discrete ``observation`` and ``desired_goal``.
    :param action_space: Discrete action space.
    :param lr_schedule: unused (tabular updates use the algorithm's learning rate); kept for SB3's signature.
    :param initial_value: initial value of every table entry (0: pessimistic for the one-hot reward of
        Eq. 6.6, as in the thesis's Q-learning).
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Discrete,
        lr_schedule: Any = None,
        initial_value: float = 0.0,
        **kwargs: Any,
    ) -> None:
        if kwargs:
            raise ValueError(f"TabularGoalPolicy takes no network arguments, got {sorted(kwargs)}")
        if not isinstance(observation_space, spaces.Dict) or not all(
            isinstance(observation_space.spaces.get(key), spaces.Discrete) for key in ("observation", "desired_goal")
        ):
            raise TypeError(
                "TabularGoalPolicy needs a Dict observation space with Discrete 'observation' and 'desired_goal' "
                f"(wrap a tabular env in sb3_gcrl.imgep.TabularGoalEnv), got {observation_space}"
            )
        if not isinstance(action_space, spaces.Discrete):
            raise TypeError(f"TabularGoalPolicy needs a Discrete action space, got {action_space}")
        super().__init__(observation_space, action_space)
        self.n_states = int(observation_space["observation"].n)
        self.n_goals = int(observation_space["desired_goal"].n)
        self.n_actions = int(action_space.n)
        self.initial_value = float(initial_value)
        self.register_buffer(
            "q_table", th.full((self.n_states, self.n_goals, self.n_actions), self.initial_value, dtype=th.float32)
        )

    @property
    def q(self) -> np.ndarray:
        """Numpy view of the table (writes go to the saved buffer)."""
        return self.q_table.numpy()

    def obs_to_tensor(self, observation: np.ndarray | dict[str, np.ndarray]) -> tuple[PyTorchObs, bool]:
        """SB3's conversion of ``predict``'s observation, for goal-conditioned (Dict) observations only.

        :param observation: a Dict observation (``observation`` and ``desired_goal``) or a batch of them.
        :return: the tensors and whether the observation was a batch.
        :raises ValueError: for an observation that is not a Dict (a bare state of the plain env has no goal: the
            model's ``predict`` commands the env's task goal for it).
        """
        if not isinstance(observation, dict):
            raise ValueError(
                "TabularGoalPolicy is goal-conditioned: it takes Dict observations {'observation': s, "
                f"'desired_goal': g}}, got {type(observation).__name__} {observation!r}. For a bare state of the "
                "plain tabular env, use the model's predict (TabularIMGEP.predict commands the env's own task goal)"
            )
        return super().obs_to_tensor(observation)

    def _predict(self, observation: dict[str, th.Tensor], deterministic: bool = False) -> th.Tensor:  # type: ignore[override]
        states = observation["observation"].long().reshape(-1)
        goals = observation["desired_goal"].long().reshape(-1)
        return self.q_table[states, goals].argmax(dim=1)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.pop("normalize_images", None)  # a table has no image preprocessing
        data.update(initial_value=self.initial_value)
        return data
