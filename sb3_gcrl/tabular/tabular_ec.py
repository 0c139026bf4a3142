"""Tabular episodic control (thesis Eq. 5.2, the "EC" agent of Fig. 5.5)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import BasePolicy

from sb3_gcrl.common.transitions import Transition
from sb3_gcrl.common.validation import check_bool, check_unit_interval
from sb3_gcrl.memory.episode import EpisodeRecorder, EpisodeRecordingMixin
from sb3_gcrl.tabular.policies import TabularECPolicy
from sb3_gcrl.tabular.tabular_algorithm import TabularAlgorithm


class TabularEpisodicControl(EpisodeRecordingMixin, TabularAlgorithm):
    """Tabular episodic control: after each episode, ``Q_ec[s, a] = max(Q_ec[s, a], G_t)`` for every step (Eq. 5.2);
    act epsilon-greedily on ``Q_ec``. No replay buffer and no gradient steps: the only learning is the update at
    the end of each episode (per env with ``n_envs > 1``).

    :param policy: policy class or alias.
    :param env: env with Discrete observation and action spaces.
    :param ec_gamma: discount of the stored returns (None: ``gamma``).
    :param ec_update_truncated: also learn from time-limit-truncated episodes (thesis Eq. 5.2 / Algorithm 2: the
        update runs on every finished episode). With ``False`` a cut episode writes nothing; then an agent that
        has not reached a terminal state yet never learns at all (its optimistic unvisited entries stay
        untouched). With ``True`` the partial returns of cut episodes enter the max; with negative step rewards
        they can exceed the returns of complete episodes (see the two-memory docs).
    :param kwargs: the other :class:`~sb3_gcrl.tabular.tabular_algorithm.TabularAlgorithm` arguments
        (``learning_rate``, ``buffer_size``, ``batch_size``, ``train_freq`` have no effect here).
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"TabularECPolicy": TabularECPolicy}
    policy: TabularECPolicy

    def __init__(
        self,
        policy: str | type[BasePolicy] = "TabularECPolicy",
        env: Any = None,
        ec_gamma: float | None = None,
        ec_update_truncated: bool = True,
        **kwargs: Any,
    ) -> None:
        kwargs.setdefault("buffer_size", 1)
        self.ec_gamma = None if ec_gamma is None else check_unit_interval("ec_gamma", ec_gamma)
        self.ec_update_truncated = check_bool("ec_update_truncated", ec_update_truncated)
        super().__init__(policy, env, **kwargs)
        self._episodes = EpisodeRecorder()

    @property
    def ec_table(self) -> np.ndarray:
        return self.policy.ec_table

    def _transition_buffer(self, replay_buffer: ReplayBuffer) -> None:
        """No replay: the steps are stored nowhere (the table learns at episode ends, :meth:`_on_transition`).

        :param replay_buffer: SB3's replay buffer (unused).
        """
        return None

    def _on_transition(self, transition: Transition) -> None:
        """Record the step into the running episodes; a finished episode's returns update the table (Eq. 5.2).

        :param transition: the step of every training env.
        """
        states = np.asarray(transition.observations).reshape(-1)
        actions = np.asarray(transition.actions).reshape(-1)
        gamma = self.gamma if self.ec_gamma is None else self.ec_gamma
        for episode in self._episodes.record(states, actions, transition.rewards, transition.dones, transition.infos):
            if episode.updates_memory(self.ec_update_truncated):
                self.policy.update_episode(episode.keys, episode.actions, episode.returns(gamma))

    def train(self, gradient_steps: int, batch_size: int = 32) -> None:
        """Nothing to do between episodes (the table is updated in :meth:`_on_transition`)."""
        self.logger.record("train/ec_visited_fraction", float(np.isfinite(self.ec_table).mean()))
