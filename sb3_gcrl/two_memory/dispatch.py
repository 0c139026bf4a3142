"""Per-episode dispatch between an episodic memory (2M-EC) and a parametric one (2M-RL), thesis Algorithm 2.

Three parts, as in SB3 (the algorithm drives training and owns its schedules, the policy acts and holds what is
saved), one module each:

- :class:`~sb3_gcrl.two_memory.policy_mixin.TwoMemoryDispatchMixin` (:mod:`sb3_gcrl.two_memory.policy_mixin`) is
  mixed into the SB3 policy that holds both memories and acts with the memory that runs each env's episode.
- :class:`TwoMemoryDispatcher` (here) drives the dispatch during training and is the one owner of its settings: the
  p_ec schedule (Eq. 5.5 or another :mod:`~sb3_gcrl.two_memory.schedules` schedule), data sharing, the discount of
  the episodic returns and whether cut episodes update the episodic memory. It draws each env's memory when its
  episode starts, records the running episodes and, when one ends, scores it and updates the episodic memory
  (Eq. 5.2) -- with every episode when data is shared, only with the EC's own when it is not (ablation 2Mw/oDS).
- :class:`~sb3_gcrl.two_memory.algorithm.TwoMemoryAlgorithmMixin` (:mod:`sb3_gcrl.two_memory.algorithm`) is mixed
  into the SB3 algorithm: it builds the dispatcher from its constructor arguments and calls it from ``_setup_learn``
  and from every stored step (``_on_transition``), so ``learn`` needs no callback.

Stock SB3 DQN has no such hooks: :class:`~sb3_gcrl.two_memory.callbacks.TwoMemoryCallback` calls the same
dispatcher from a callback.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.logger import Logger

from sb3_gcrl.common.seeding import seeded_generator
from sb3_gcrl.common.validation import check_bool, check_unit_interval
from sb3_gcrl.memory.episode import EpisodeRecorder
from sb3_gcrl.two_memory.buffers import SourceTaggedReplayBuffer
from sb3_gcrl.two_memory.policy_mixin import TwoMemoryDispatchMixin
from sb3_gcrl.two_memory.schedules import EPISODIC, PARAMETRIC, PecSchedule, ScoreWindows, make_pec_schedule

__all__ = ["PecSpec", "TwoMemoryDispatcher"]

#: what ``p_ec_schedule`` accepts (see :func:`~sb3_gcrl.two_memory.schedules.make_pec_schedule`)
PecSpec = PecSchedule | float | str | dict[str, Any]


class TwoMemoryDispatcher:
    """Drives the per-episode dispatch of thesis Algorithm 2 for a
    :class:`~sb3_gcrl.two_memory.policy_mixin.TwoMemoryDispatchMixin` policy, and owns its training settings.

    Its host -- a 2M algorithm (:class:`~sb3_gcrl.two_memory.algorithm.TwoMemoryAlgorithmMixin`) or, with stock DQN,
    :class:`~sb3_gcrl.two_memory.callbacks.TwoMemoryCallback` -- calls :meth:`start` when training starts and
    :meth:`step` after every env step. Each env's memory is drawn when its episode starts (``U(0,1) < p_ec`` -> EC,
    p_ec read from the schedule then, never switched mid-episode); every finished episode is scored (Eq. 5.6
    windows) and, by the settings below, written into the episodic memory (Eq. 5.2).

    The memories are drawn with the dispatcher's own generator, :attr:`rng`, which its host seeds from the model's
    seed (:meth:`seed`; fresh entropy if it is not seeded before training starts).

    Saved with the algorithm (the schedule, its state, the p_ec of the last draw and the generator; running episodes
    are not: the envs are reset when training resumes after ``load``).

    :param p_ec_schedule: the p_ec schedule or its spec (see :func:`~sb3_gcrl.two_memory.schedules.make_pec_schedule`).
    :param data_sharing: update the episodic memory with every episode (thesis Sec. 5.4.3) instead of only with the
        EC-run ones (2Mw/oDS). The 2M algorithm applies the same switch to its replay buffer.
    :param ec_gamma: discount of the returns stored in the episodic memory; ``None``: the host algorithm's ``gamma``
        (see :meth:`use_gamma_by_default`).
    :param ec_update_truncated: also write time-limit-truncated episodes into the episodic memory (thesis: the
        Monte-Carlo update of Algorithm 1 / Algorithm 2 runs on every finished episode). ``False`` keeps cut episodes
        out of the memory (their returns still count in the score windows).
    :raises ValueError: for a bad schedule spec (naming the accepted forms) or a setting out of range.
    """

    #: the settings besides the p_ec schedule, each an attribute and a constructor argument of the same name
    settings: ClassVar[tuple[str, ...]] = ("data_sharing", "ec_gamma", "ec_update_truncated")

    def __init__(
        self,
        p_ec_schedule: PecSpec,
        data_sharing: bool = True,
        ec_gamma: float | None = None,
        ec_update_truncated: bool = True,
    ) -> None:
        self.p_ec_schedule = make_pec_schedule(p_ec_schedule)
        self.data_sharing = check_bool("data_sharing", data_sharing)
        self.ec_gamma = None if ec_gamma is None else check_unit_interval("ec_gamma", ec_gamma)
        self.ec_update_truncated = check_bool("ec_update_truncated", ec_update_truncated)
        #: p_ec of the last draw (logged as ``two_memory/p_ec``); before any, the schedule's value at step 0
        self.p_ec = self._schedule_value(0, ScoreWindows())
        #: running episodes of the training envs
        self.episodes = EpisodeRecorder()
        #: generator of the memory draws (None until :meth:`seed` or the start of training)
        self.rng: np.random.Generator | None = None

    @classmethod
    def refuse_settings(cls, policy_kwargs: dict[str, Any], policy_name: str) -> None:
        """Raise if a setting of the dispatcher is given to a 2M policy.

        :param policy_kwargs: the policy's keyword arguments.
        :param policy_name: the policy's class name, for the message.
        :raises ValueError: naming where the setting goes.
        """
        for name in ("p_ec_schedule", *cls.settings):
            if name in policy_kwargs:
                raise ValueError(
                    f"{name} is a training setting of 2M, not of {policy_name}: pass it to the 2M algorithm "
                    "(TwoMemoryDQN, TwoMemorySAC, TabularTwoMemory) or, with stock DQN, to TwoMemoryCallback "
                    "(stock DQN always shares data)"
                )

    def seed(self, seed: int | None) -> None:
        """(Re)seed the generator of the memory draws.

        :param seed: the model's seed; ``None``: fresh entropy.
        """
        self.rng = seeded_generator(seed, "two_memory dispatch")

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["episodes"] = EpisodeRecorder()  # running episodes are not saved
        return state

    def __repr__(self) -> str:
        settings = ", ".join(f"{name}={getattr(self, name)!r}" for name in self.settings)
        return f"{type(self).__name__}(p_ec_schedule={self.p_ec_schedule!r}, {settings})"

    def use_gamma_by_default(self, gamma: float) -> None:
        """Use ``gamma`` (the host algorithm's) as ``ec_gamma`` if none was given.

        :param gamma: discount in [0, 1].
        """
        if self.ec_gamma is None:
            self.ec_gamma = check_unit_interval("gamma", gamma)

    def _schedule_value(self, num_timesteps: int, scores: ScoreWindows) -> float:
        p_ec = float(self.p_ec_schedule(num_timesteps, scores))
        if not 0.0 <= p_ec <= 1.0:
            raise ValueError(f"p_ec schedule {self.p_ec_schedule!r} returned {p_ec}, outside [0, 1]")
        return p_ec

    def start(self, policy: TwoMemoryDispatchMixin, n_envs: int, num_timesteps: int, envs_reset: bool) -> None:
        """Training starts: forget the running episodes if the envs were reset (or their number changed), then give
        every env that starts an episode its memory.

        :param policy: the 2M policy.
        :param n_envs: number of training envs.
        :param num_timesteps: env steps so far.
        :param envs_reset: whether the envs were reset since the last :meth:`step`.
        """
        if envs_reset or policy.acting_memory.size != n_envs:
            policy.reset_acting_memory(n_envs)
            self.episodes.reset()
        if self.rng is None:
            self.seed(None)
        self.draw(policy, num_timesteps)

    def draw(self, policy: TwoMemoryDispatchMixin, num_timesteps: int) -> None:
        """Give every env that starts an episode its acting memory, p_ec read from the schedule now.

        :param policy: the 2M policy.
        :param num_timesteps: env steps so far.
        """
        if policy.needs_memories():
            if self.rng is None:
                raise RuntimeError("draw called before start: the dispatcher has no generator yet")
            self.p_ec = self._schedule_value(num_timesteps, policy.score_windows)
            policy.assign_memories(self.p_ec, self.rng)

    def step(
        self,
        policy: TwoMemoryDispatchMixin,
        observations: np.ndarray | dict[str, np.ndarray],
        actions: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
        num_timesteps: int,
        logger: Logger,
        replay_buffer: ReplayBuffer | None = None,
    ) -> None:
        """After an env step: record it; if episodes ended, score them, update the episodic memory, log
        ``two_memory/*`` and draw the memories of the envs that start a new episode.

        :param policy: the 2M policy.
        :param observations: observations the actions were taken in, shape (n_envs, *obs_shape).
        :param actions: executed actions as the policy outputs them (scaled to [-1, 1] for Box spaces).
        :param rewards: the env's rewards, shape (n_envs,).
        :param dones: episode ends (termination or truncation), shape (n_envs,).
        :param infos: the step's infos (``TimeLimit.truncated`` marks a cut).
        :param num_timesteps: env steps so far, this step included.
        :param logger: where to log.
        :param replay_buffer: the replay buffer (its share of EC data is logged when it is source-tagged).
        :raises RuntimeError: if the policy's envs do not match, an env has no memory, or ``ec_gamma`` is unset.
        """
        if policy.acting_memory.size != len(rewards):
            raise RuntimeError(
                f"step got {len(rewards)} envs but dispatch was set up for {policy.acting_memory.size}; call start"
            )
        if policy.needs_memories():
            raise RuntimeError("step called for an env that has no acting memory; call start first")
        if self.ec_gamma is None:
            raise RuntimeError("ec_gamma is not set: pass ec_gamma, or call use_gamma_by_default with the algorithm's")
        finished = self.episodes.record(policy._episode_features(observations), actions, rewards, dones, infos)
        for episode in finished:
            memory = policy.end_episode(episode.env_index, episode.episode_return)
            if episode.updates_memory(self.ec_update_truncated) and (self.data_sharing or memory == EPISODIC):
                policy.update_episodic_memory(episode.keys, episode.actions, episode.returns(self.ec_gamma))
        if finished:
            self.record_logs(logger, policy, replay_buffer)
            self.draw(policy, num_timesteps)

    def record_logs(
        self, logger: Logger, policy: TwoMemoryDispatchMixin, replay_buffer: ReplayBuffer | None = None
    ) -> None:
        """Log ``two_memory/*``: p_ec of the last draw, both scores (Eq. 5.6), the evaluation memory, episodes per
        memory, the fraction of envs acting with EC and the fraction of EC data in a source-tagged replay buffer.

        :param logger: where to log.
        :param policy: the 2M policy.
        :param replay_buffer: the replay buffer, if any.
        """
        windows = policy.score_windows
        logger.record("two_memory/p_ec", self.p_ec)
        for memory, name in ((EPISODIC, "ec"), (PARAMETRIC, "rl")):
            if windows.n_episodes(memory) > 0:
                logger.record(f"two_memory/score_{name}", windows.score(memory))
            logger.record(f"two_memory/episodes_{name}", int(policy.episode_counts[memory]))
        logger.record("two_memory/eval_memory_is_ec", int(policy.evaluation_memory() == EPISODIC))
        logger.record("two_memory/acting_ec_fraction", float(np.mean(policy.acting_memory == EPISODIC)))
        if isinstance(replay_buffer, SourceTaggedReplayBuffer):
            logger.record("two_memory/buffer_ec_fraction", replay_buffer.source_fraction(EPISODIC))
