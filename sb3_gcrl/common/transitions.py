"""The one override of SB3's ``_store_transition`` in the package, with two hooks for what an algorithm does with a
stored step.

SB3's off-policy algorithms hand every step of the training envs to ``_store_transition``, which puts it into the
replay buffer. The package's algorithms do more with a step: check its rewards (all), send each env's row to the
buffer of the policy that acted (the forward-backward agents), tag it with the memory that acted (2M), record it
into the running episodes of an episodic memory (EMAC, tabular EC, 2M). :class:`TransitionHooksMixin` overrides
``_store_transition`` once for all of them; an algorithm says where the step goes (:meth:`_transition_buffer`) and
what it learns from it (:meth:`_on_transition`, with the step as a :class:`Transition`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from sb3_gcrl.common.validation import check_finite_rewards

#: an observation of SB3's VecEnv: an array, or a dict of arrays (goal envs), one row per env
Observation = np.ndarray | dict[str, np.ndarray]


class Transition(NamedTuple):
    """One step of every training env, as SB3 hands it to ``_store_transition``.

    :param observations: the observations the actions were taken in (SB3's ``_last_obs`` before the step).
    :param actions: the actions as the replay buffer stores them (for Box actions scaled to [-1, 1]).
    :param rewards: the rewards, one per env (as SB3 stores them: normalised under ``VecNormalize``).
    :param dones: the episode ends, one per env.
    :param infos: the envs' infos.
    :param replay_buffer: SB3's replay buffer (its ``_store_transition`` argument).
    """

    observations: Observation
    actions: np.ndarray
    rewards: np.ndarray
    dones: np.ndarray
    infos: list[dict[str, Any]]
    replay_buffer: Any


class TransitionHooksMixin:
    """Mix in before an SB3 off-policy algorithm: every stored step has finite rewards, goes where the algorithm
    says and is handed to the algorithm.

    ``_store_transition`` rejects a NaN or infinite reward at the step that returned it (tables, episodic memories
    and critics average rewards into their values, and one NaN spreads to every value it meets, so that the run
    would fail much later with an error about something else), stores the step in :meth:`_transition_buffer`
    (SB3's own storing), then calls :meth:`_on_transition`. Subclasses override the two hooks, never
    ``_store_transition``.
    """

    num_timesteps: int
    _last_obs: Observation | None

    def _check_rewards(self, rewards: np.ndarray) -> None:
        """:func:`~sb3_gcrl.common.validation.check_finite_rewards` of one step's rewards (one per env).

        :param rewards: the rewards SB3 is about to store.
        :raises ValueError: if a reward is NaN or infinite.
        """
        check_finite_rewards(
            rewards,
            f"at timestep {self.num_timesteps}",
            f"{type(self).__name__} learns its values from the rewards (a NaN would spread to every value it meets)",
        )

    def _transition_buffer(self, replay_buffer: Any) -> Any:
        """Where SB3 stores this step: by default its replay buffer; ``None`` stores it nowhere (only ``_last_obs``
        moves on, as SB3's storing would move it).

        :param replay_buffer: SB3's replay buffer.
        :return: an object with the replay buffer's ``add``, or ``None``.
        """
        return replay_buffer

    def _on_transition(self, transition: Transition) -> None:
        """What the algorithm learns from a step, once it is stored (nothing by default).

        :param transition: the step of every training env.
        """

    def _store_transition(
        self,
        replay_buffer: Any,
        buffer_action: np.ndarray,
        new_obs: Observation,
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        self._check_rewards(reward)
        observations = self._last_obs
        buffer = self._transition_buffer(replay_buffer)
        if buffer is None:
            self._last_obs = new_obs
        else:
            super()._store_transition(buffer, buffer_action, new_obs, reward, dones, infos)  # type: ignore[misc]
        self._on_transition(Transition(observations, buffer_action, reward, dones, infos, replay_buffer))  # type: ignore[arg-type]
