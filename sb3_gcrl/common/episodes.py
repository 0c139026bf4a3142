"""Running episodes of each env, handed over when they end: the episode side of every Monte-Carlo memory update.

Episodic control learns once an episode is over, from the discounted return of each of its steps (thesis
Algorithm 1, UPDATE; Eq. 5.2 for the tabular memory; Algorithm 2 for the episodic half of 2M). An algorithm that
collects through SB3's ``collect_rollouts`` records every env step with :meth:`EpisodeRecorder.record` and gets back
the episodes that ended (:class:`FinishedEpisode`); :meth:`FinishedEpisode.updates_memory` says whether one may update
the memory: a time-limit cut (:func:`truncated_ends`) does only when the algorithm's ``update_truncated`` setting
allows it (the thesis's update runs on every finished episode). :class:`EpisodeRecordingMixin` keeps such a record
in an SB3 algorithm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sb3_gcrl.memory.episode import EpisodeBuffers, discounted_returns


def truncated_ends(dones: np.ndarray, infos: list[dict[str, Any]]) -> np.ndarray:
    """Which episode ends of a step are time-limit truncations (SB3's ``TimeLimit.truncated``).

    :param dones: episode ends of one step, shape (n_envs,).
    :param infos: the step's infos, one per env.
    :return: boolean array, shape (n_envs,).
    """
    return np.array([bool(done) and info.get("TimeLimit.truncated", False) for done, info in zip(dones, infos)])


@dataclass(frozen=True)
class FinishedEpisode:
    """One finished episode of one env, as recorded step by step.

    :param env_index: the env that ran it.
    :param keys: what was recorded per step (a memory key, an observation or a state index), shape (T, ...).
    :param actions: the executed actions, shape (T, ...).
    :param rewards: the rewards, shape (T,).
    :param truncated: whether a time limit cut it.
    """

    env_index: int
    keys: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    truncated: bool

    def updates_memory(self, update_truncated: bool) -> bool:
        """Whether this episode may update an episodic memory: always unless cut by a time limit, then only with
        ``update_truncated``.

        :param update_truncated: the algorithm's setting (``ec_update_truncated`` and the like).
        """
        return update_truncated or not self.truncated

    @property
    def episode_return(self) -> float:
        """Undiscounted return (what the 2M score windows of Eq. 5.6 average)."""
        return float(self.rewards.sum())

    def returns(self, gamma: float) -> np.ndarray:
        """Monte-Carlo return of every step, ``G_t = r_t + gamma * G_{t+1}``.

        :param gamma: discount factor.
        :return: shape (T,), float64.
        """
        return discounted_returns(self.rewards, gamma)


class EpisodeRecorder:
    """The running episode of every env, in preallocated per-env arrays (:class:`~sb3_gcrl.memory.EpisodeBuffers`,
    allocated on the first step with its shapes and dtypes).

    :param initial_length: initial per-env length of the arrays (doubled when exceeded).
    """

    def __init__(self, initial_length: int = 256) -> None:
        self.initial_length = initial_length
        self.buffers: EpisodeBuffers | None = None

    def reset(self) -> None:
        """Forget every running episode (the envs were reset)."""
        self.buffers = None

    def record(
        self,
        keys: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> list[FinishedEpisode]:
        """Append one step of every env and hand over the episodes that ended with it.

        :param keys: what to record per env, shape (n_envs, ...).
        :param actions: executed actions, shape (n_envs, ...).
        :param rewards: rewards, shape (n_envs,).
        :param dones: episode ends (termination or truncation), shape (n_envs,).
        :param infos: the step's infos (``TimeLimit.truncated`` marks a cut).
        :return: the finished episodes, in env order.
        """
        keys, actions = np.asarray(keys), np.asarray(actions)
        if self.buffers is None or self.buffers.n_envs != len(keys):
            self.buffers = EpisodeBuffers(
                len(keys), keys.shape[1:], actions.shape[1:], actions.dtype, keys.dtype, self.initial_length
            )
        self.buffers.add(keys, actions, rewards)
        truncated = truncated_ends(dones, infos)
        return [
            FinishedEpisode(int(env_index), *self.buffers.pop(int(env_index)), bool(truncated[env_index]))
            for env_index in np.flatnonzero(dones)
        ]


class EpisodeRecordingMixin:
    """Mix in before an SB3 algorithm that records the running episodes of its training envs in ``_episodes`` (an
    :class:`EpisodeRecorder`, made by the algorithm's constructor or set-up).

    ``learn`` forgets them when it resets the envs (their running episodes are gone), and ``save`` leaves them out (a
    loaded model starts on reset envs).
    """

    _episodes: EpisodeRecorder

    def _setup_learn(self, *args: Any, **kwargs: Any) -> Any:
        previous_obs = self._last_obs  # type: ignore[attr-defined]
        result = super()._setup_learn(*args, **kwargs)  # type: ignore[misc]
        if self._last_obs is not previous_obs:  # type: ignore[attr-defined]  (SB3 reset the envs)
            self._episodes.reset()
        return result

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_episodes"]  # type: ignore[misc]
