"""Per-episode dispatch between an episodic memory (2M-EC) and a parametric one (2M-RL), thesis Algorithm 2.

:class:`TwoMemoryDispatchMixin` is mixed into an SB3 policy that holds both memories (tabular, DQN or SAC
flavour). It owns everything the 2M agent decides:

- which memory runs each env's next episode, drawn once per episode with probability p_ec (Eq. 5.5 or another
  :mod:`~sb3_gcrl.two_memory.schedules` schedule) and never changed until that env's episode ends;
- the running episodes and, when one ends, the episodic-memory update (Eq. 5.2) -- with every episode when data
  is shared, only with the EC's own episodes when it is not (ablation 2Mw/oDS);
- the score windows (last 50 returns per memory) and the evaluation memory of Eq. 5.6, used by
  ``predict(deterministic=True)``.

Keeping this state in the policy means ``save``/``load`` bring back the tables, the network and the score windows
together (``get_extra_state`` puts them into the policy's ``state_dict``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import MaybeCallback

from sb3_gcrl.two_memory.buffers import SourceTaggedReplayBuffer
from sb3_gcrl.two_memory.episodes import EpisodeRecorder, discounted_returns
from sb3_gcrl.two_memory.schedules import (
    DEFAULT_P_EC_SCHEDULE,
    EPISODIC,
    PARAMETRIC,
    UNASSIGNED,
    PecSchedule,
    ScoreWindows,
    check_unit_interval,
    make_pec_schedule,
)


def _batch_size(observation: th.Tensor | dict[str, th.Tensor]) -> int:
    if isinstance(observation, dict):
        return int(next(iter(observation.values())).shape[0])
    return int(observation.shape[0])


def _device(observation: th.Tensor | dict[str, th.Tensor]) -> th.device:
    if isinstance(observation, dict):
        return next(iter(observation.values())).device
    return observation.device


def _select_rows(observation: th.Tensor | dict[str, th.Tensor], index: th.Tensor) -> Any:
    if isinstance(observation, dict):
        return {key: value[index] for key, value in observation.items()}
    return observation[index]


class TwoMemoryDispatchMixin:
    """Dispatch logic of a 2M policy; mix in before the SB3 policy (``class P(TwoMemoryDispatchMixin, DQNPolicy)``).

    Concrete policies implement :meth:`_episodic_actions`, :meth:`_parametric_actions`,
    :meth:`update_episodic_memory` and, if their episodic memory is not a sub-module with its own state,
    :meth:`_episodic_state` / :meth:`_load_episodic_state`.
    """

    #: p_ec schedule used when none is given (the one place where each policy's default lives)
    default_p_ec_schedule: dict[str, Any] = DEFAULT_P_EC_SCHEDULE

    def _init_dispatch(
        self,
        p_ec_schedule: PecSchedule | float | str | dict[str, Any],
        data_sharing: bool,
        score_window: int,
        ec_gamma: float | None,
        ec_update_truncated: bool,
    ) -> None:
        """:param p_ec_schedule: schedule of p_ec (see :func:`~sb3_gcrl.two_memory.schedules.make_pec_schedule`);
            ``None``: the policy class's :attr:`default_p_ec_schedule`.
        :param data_sharing: update the episodic memory with every episode (thesis default) instead of only its own.
            The algorithm applies the same switch to the replay buffer.
        :param score_window: n of Eq. 5.6 (50 in the thesis).
        :param ec_gamma: discount of the returns stored in the episodic memory; ``None``: the algorithm's
            ``gamma``, filled in by the 2M algorithm or by :class:`~sb3_gcrl.two_memory.callbacks.TwoMemoryCallback`.
        :param ec_update_truncated: also write time-limit-truncated episodes into the episodic memory (thesis: the
            Monte-Carlo update of Algorithm 1 / Algorithm 2 runs on every finished episode). ``False`` keeps cut
            episodes out of the memory (their returns still count in the score windows).
        """
        self.p_ec_schedule = make_pec_schedule(self.default_p_ec_schedule if p_ec_schedule is None else p_ec_schedule)
        self.data_sharing = bool(data_sharing)
        self.ec_gamma = None
        if ec_gamma is not None:
            self.set_ec_gamma(ec_gamma)
        self.ec_update_truncated = bool(ec_update_truncated)
        self.score_windows = ScoreWindows(score_window)
        #: memory running each env's current episode (EPISODIC, PARAMETRIC or UNASSIGNED)
        self.acting_memory = np.zeros(0, dtype=np.int8)
        self.recorder: EpisodeRecorder | None = None
        #: env steps so far, kept up to date by the algorithm (or :class:`TwoMemoryCallback`)
        self.num_timesteps = 0
        #: p_ec used at the last draw
        self.last_p_ec = float(self.p_ec_schedule(0, self.score_windows))
        #: episodes run by each memory since construction (saved)
        self.episode_counts = np.zeros(2, dtype=np.int64)

    def set_seed(self, seed: int | None) -> None:
        """Reseed the policy's own random generators (EC tie-breaking / sampling); numpy's global generator, which
        draws the acting memories, is seeded by the algorithm. Policies with their own generators override this.

        :param seed: seed.
        """

    def set_ec_gamma(self, ec_gamma: float) -> None:
        """Set the discount of the returns stored in the episodic memory.

        :param ec_gamma: discount in [0, 1].
        """
        check_unit_interval("ec_gamma", ec_gamma)
        self.ec_gamma = float(ec_gamma)

    # ----------------------------------------------------------------------------------------------- episodes
    def reset_episodes(self, n_envs: int) -> None:
        """Forget running episodes (the envs were reset); the next step draws a memory for each env."""
        self.acting_memory = np.full(n_envs, UNASSIGNED, dtype=np.int8)
        self.recorder = None

    def current_p_ec(self) -> float:
        """p_ec of the schedule now (at :attr:`num_timesteps`, with the current scores)."""
        p_ec = float(self.p_ec_schedule(self.num_timesteps, self.score_windows))
        if not 0.0 <= p_ec <= 1.0:
            raise ValueError(f"p_ec schedule {self.p_ec_schedule!r} returned {p_ec}, outside [0, 1]")
        return p_ec

    def assign_memories(self) -> np.ndarray:
        """Draw a memory for every env that starts an episode (Algorithm 2: ``U(0,1) < p_ec`` -> EC).

        :return: the acting memory of each env.
        """
        unassigned = np.flatnonzero(self.acting_memory == UNASSIGNED)
        if unassigned.size > 0:
            self.last_p_ec = self.current_p_ec()
            draws = np.random.random(unassigned.size) < self.last_p_ec
            self.acting_memory[unassigned] = np.where(draws, EPISODIC, PARAMETRIC)
        return self.acting_memory

    def record_step(
        self,
        observations: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
        truncated: np.ndarray | None = None,
    ) -> list[tuple[int, int, float]]:
        """Record one step of every env; finish the episodes that ended.

        :param observations: observations the actions were taken in, shape (n_envs, *obs_shape).
        :param actions: executed actions (env space), shape (n_envs, *action_shape).
        :param rewards: rewards, shape (n_envs,).
        :param dones: episode ends (termination or truncation), shape (n_envs,).
        :param truncated: which of those ends are time-limit truncations (None: none).
        :return: ``(env_index, memory, undiscounted return)`` for each finished episode.
        """
        n_envs = len(rewards)
        if self.acting_memory.size != n_envs:
            raise RuntimeError(f"record_step got {n_envs} envs but dispatch was set up for {self.acting_memory.size}")
        if np.any(self.acting_memory == UNASSIGNED):
            raise RuntimeError("record_step called for an env that has no acting memory; call assign_memories first")
        if self.ec_gamma is None:
            raise RuntimeError(
                "ec_gamma is not set: pass ec_gamma to the policy, or train it with a 2M algorithm or with "
                "TwoMemoryCallback, which use the algorithm's gamma"
            )
        observations = self._episode_features(observations)
        actions = np.asarray(actions)
        if self.recorder is None:
            self.recorder = EpisodeRecorder(
                n_envs, observations.shape[1:], observations.dtype, actions.shape[1:], actions.dtype
            )
        self.recorder.add(observations, actions, rewards)
        finished = []
        for env_index in np.flatnonzero(dones):
            episode_obs, episode_actions, episode_rewards = self.recorder.pop(env_index)
            memory = int(self.acting_memory[env_index])
            episode_return = float(episode_rewards.sum())
            self.score_windows.push(memory, episode_return)
            self.episode_counts[memory] += 1
            cut = truncated is not None and bool(truncated[env_index])
            if (self.data_sharing or memory == EPISODIC) and (self.ec_update_truncated or not cut):
                self.update_episodic_memory(
                    episode_obs, episode_actions, discounted_returns(episode_rewards, self.ec_gamma)
                )
            self.acting_memory[env_index] = UNASSIGNED
            finished.append((int(env_index), memory, episode_return))
        return finished

    def evaluation_memory(self) -> int:
        """Eq. 5.6: the memory with the higher mean return over its last ``score_window`` training episodes."""
        return self.score_windows.evaluation_memory()

    # ----------------------------------------------------------------------------------------------- acting
    def _predict(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        """Greedy action of each row's memory: the evaluation memory (Eq. 5.6) if ``deterministic``, else the
        memory running that env's episode. A batch whose size is not the number of training envs (e.g. a single
        observation given to ``predict``) uses the evaluation memory.
        """
        n = _batch_size(observation)
        if deterministic or self.acting_memory.size != n:
            memories = np.full(n, self.evaluation_memory(), dtype=np.int8)
        else:
            memories = self.assign_memories()
        # (the tensor's device: ``self.device`` walks all parameters, a measurable cost per env step)
        device = _device(observation)
        if n == 1 or (memories == memories[0]).all():
            # one memory acts for the whole batch (always with one env): no row split and scatter
            act = self._episodic_actions if memories[0] == EPISODIC else self._parametric_actions
            return act(observation, deterministic).to(device)
        actions: th.Tensor | None = None
        for memory, act in ((EPISODIC, self._episodic_actions), (PARAMETRIC, self._parametric_actions)):
            rows = np.flatnonzero(memories == memory)
            if rows.size == 0:
                continue
            index = th.as_tensor(rows, device=device)
            memory_actions = act(_select_rows(observation, index), deterministic)
            if actions is None:
                actions = th.zeros((n, *memory_actions.shape[1:]), dtype=memory_actions.dtype, device=device)
            actions[index] = memory_actions.to(device)
        assert actions is not None
        return actions

    def _episodic_actions(self, observation: th.Tensor, deterministic: bool) -> th.Tensor:
        """Actions of the episodic memory for a batch of (preprocessed-by-``obs_to_tensor``) observations."""
        raise NotImplementedError

    def _parametric_actions(self, observation: th.Tensor, deterministic: bool) -> th.Tensor:
        """Actions of the parametric (RL) memory."""
        raise NotImplementedError

    def _episode_features(self, observations: Any) -> np.ndarray:
        """What is recorded per step for the episodic update (default: the observation; neural 2M policies record
        the memory key, which is smaller and also works for Dict observations)."""
        return np.asarray(observations)

    def update_episodic_memory(self, features: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> None:
        """Write one finished episode into the episodic memory: per step the :meth:`_episode_features`, the
        action and the discounted return."""
        raise NotImplementedError

    # ----------------------------------------------------------------------------------------------- saving
    def _episodic_state(self) -> dict[str, th.Tensor]:
        """Tensors of the episodic memory to save (empty if it is a sub-module that saves itself)."""
        return {}

    def _load_episodic_state(self, state: dict[str, th.Tensor]) -> None:
        """Inverse of :meth:`_episodic_state`."""

    def get_extra_state(self) -> dict[str, th.Tensor]:
        """Score windows and episode counts (plus the episodic memory's tensors) for the ``state_dict``."""
        state = {
            "score_returns": th.from_numpy(self.score_windows.returns.copy()),
            "score_counts": th.from_numpy(self.score_windows.counts.copy()),
            "episode_counts": th.from_numpy(self.episode_counts.copy()),
        }
        state.update(self._episodic_state())
        return state

    def set_extra_state(self, state: dict[str, th.Tensor]) -> None:
        state = dict(state)
        self.score_windows.load_state_dict(
            {"returns": state.pop("score_returns").numpy(), "counts": state.pop("score_counts").numpy()}
        )
        self.episode_counts[...] = state.pop("episode_counts").numpy()
        self._load_episodic_state(state)


class TwoMemoryAlgorithmMixin:
    """Algorithm side of 2M for an SB3 ``OffPolicyAlgorithm`` whose policy is a :class:`TwoMemoryDispatchMixin`.

    Mix in first (``class TwoMemoryDQN(TwoMemoryAlgorithmMixin, DQN)``). It

    - acts through the policy's per-env dispatch, with epsilon-greedy applied per env on both memories for
      Discrete actions (stock DQN draws one epsilon coin for the whole batch of envs);
    - keeps SB3's random warm-up (``learning_starts``) for RL-run episodes only: EC-run episodes act with the
      episodic memory from the first step, since EC has nothing to wait for;
    - tags every stored transition with the memory that collected it and, without data sharing, trains the RL
      memory on its own transitions only (:class:`~sb3_gcrl.two_memory.buffers.SourceTaggedReplayBuffer`);
    - feeds each step to the policy, which updates the episodic memory and the score windows at episode ends;
    - logs ``two_memory/*``: p_ec, both scores (Eq. 5.6), the evaluation memory, episodes per memory, the fraction
      of envs acting with EC and the fraction of EC data in the buffer.
    """

    def _setup_learn(self, *args: Any, **kwargs: Any) -> Any:
        previous_obs = self._last_obs  # type: ignore[has-type]
        result = super()._setup_learn(*args, **kwargs)  # type: ignore[misc]
        if self._last_obs is not previous_obs or self.policy.acting_memory.size != self.n_envs:
            # the envs were reset: running episodes (if any) are gone
            self.policy.reset_episodes(self.n_envs)
        return result

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        policy = self.policy
        policy.num_timesteps = self.num_timesteps
        memories = policy.assign_memories()
        # policy.predict() without its per-call set_training_mode (it walks every sub-module on each env step)
        if policy.training:
            policy.set_training_mode(False)
        obs_tensor, _ = policy.obs_to_tensor(self._last_obs)
        with th.no_grad():
            action = policy._predict(obs_tensor, deterministic=False).cpu().numpy()
        action = action.reshape((n_envs, *self.action_space.shape))
        if isinstance(self.action_space, spaces.Box):
            # as BasePolicy.predict: squashed policies output [-1, 1], others are clipped to the bounds
            low, high = self.action_space.low, self.action_space.high
            unscaled_action = policy.unscale_action(action) if policy.squash_output else np.clip(action, low, high)
        else:
            unscaled_action = action
        random_rows = np.zeros(n_envs, dtype=bool)
        if self.num_timesteps < learning_starts:
            random_rows |= memories == PARAMETRIC
        if isinstance(self.action_space, spaces.Discrete):
            random_rows |= np.random.random(n_envs) < getattr(self, "exploration_rate", 0.0)
        if random_rows.any():
            unscaled_action = unscaled_action.copy()
            for row in np.flatnonzero(random_rows):
                unscaled_action[row] = self.action_space.sample()
        if isinstance(self.action_space, spaces.Box):
            scaled_action = policy.scale_action(unscaled_action)
            if action_noise is not None:
                scaled_action = np.clip(scaled_action + action_noise(), -1, 1)
            return policy.unscale_action(scaled_action), scaled_action
        return unscaled_action, unscaled_action

    def _store_transition(
        self,
        replay_buffer: ReplayBuffer,
        buffer_action: np.ndarray,
        new_obs: np.ndarray | dict[str, np.ndarray],
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        # the episodic memory is keyed on what the policy sees (normalised if VecNormalize is used); the scores and
        # stored returns use the env's own rewards
        observations = self._last_obs
        rewards = reward if self._vec_normalize_env is None else self._vec_normalize_env.get_original_reward()
        if isinstance(replay_buffer, SourceTaggedReplayBuffer):
            replay_buffer.next_sources[:] = self.policy.acting_memory
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)  # type: ignore[misc]
        # the episodic memory stores actions as the policy outputs them (scaled to [-1, 1] for Box spaces)
        truncated = np.array([done and info.get("TimeLimit.truncated", False) for done, info in zip(dones, infos)])
        finished = self.policy.record_step(observations, buffer_action, rewards, dones, truncated)
        if finished:
            self._log_two_memory(replay_buffer)

    def _log_two_memory(self, replay_buffer: ReplayBuffer | None) -> None:
        policy = self.policy
        windows = policy.score_windows
        self.logger.record("two_memory/p_ec", policy.last_p_ec)
        for memory, name in ((EPISODIC, "ec"), (PARAMETRIC, "rl")):
            if windows.n_episodes(memory) > 0:
                self.logger.record(f"two_memory/score_{name}", windows.score(memory))
            self.logger.record(f"two_memory/episodes_{name}", int(policy.episode_counts[memory]))
        self.logger.record("two_memory/eval_memory_is_ec", int(policy.evaluation_memory() == EPISODIC))
        self.logger.record("two_memory/acting_ec_fraction", float(np.mean(policy.acting_memory == EPISODIC)))
        if isinstance(replay_buffer, SourceTaggedReplayBuffer):
            self.logger.record("two_memory/buffer_ec_fraction", replay_buffer.source_fraction(EPISODIC))

    def _replay_ready(self) -> bool:
        """False while source filtering leaves nothing to sample (no data sharing, no RL episode stored yet)."""
        buffer = self.replay_buffer
        filtered = isinstance(buffer, SourceTaggedReplayBuffer) and buffer.filters_sources
        return not (filtered and buffer.n_sampleable() == 0)

    def _configure_two_memory(self) -> None:
        """Before ``_setup_model``: hand the 2M switches to the policy and pick the replay buffer.

        Reads the algorithm's ``p_ec_schedule`` (``None``: the policy's default), ``data_sharing``, ``score_window``
        and ``ec_gamma`` (``None``: the algorithm's ``gamma``). The caller's ``policy_kwargs`` and
        ``replay_buffer_kwargs`` dicts are copied, never modified.
        """
        switches: dict[str, Any] = dict(
            data_sharing=self.data_sharing,
            score_window=self.score_window,
            ec_gamma=self.gamma if self.ec_gamma is None else self.ec_gamma,
        )
        if self.p_ec_schedule is not None:
            switches["p_ec_schedule"] = self.p_ec_schedule
        self.policy_kwargs = {**self.policy_kwargs, **switches}
        self.replay_buffer_kwargs = dict(self.replay_buffer_kwargs)
        self._two_memory_replay_kwargs(self.data_sharing)

    #: arguments of the 2M algorithms that the algorithm hands to its policy
    TWO_MEMORY_SWITCHES = ("p_ec_schedule", "data_sharing", "score_window", "ec_gamma")

    @classmethod
    def _own_two_memory_kwargs(cls, kwargs: dict[str, Any]) -> None:
        """At construction: replace the caller's ``policy_kwargs`` / ``replay_buffer_kwargs`` in ``kwargs`` by copies
        (SB3 and the 2M setup write into them) and refuse 2M switches in ``policy_kwargs``.

        :param kwargs: the algorithm's keyword arguments, changed in place.
        :raises ValueError: naming the switch and where to pass it.
        """
        for name in ("policy_kwargs", "replay_buffer_kwargs"):
            if kwargs.get(name) is not None:
                kwargs[name] = dict(kwargs[name])
        for key in cls.TWO_MEMORY_SWITCHES:
            if key in (kwargs.get("policy_kwargs") or {}):
                raise ValueError(f"pass {key} to {cls.__name__} itself, not in policy_kwargs")

    @staticmethod
    def _check_two_memory_action_space(env: Any, expected: type[spaces.Space], algorithm: str, other: str) -> Any:
        """Make ``env`` (an id is built here, as SB3 would) and check its action space before SB3 asserts on it.

        :param env: env, VecEnv, env id or None (loading).
        :param expected: the action space class this algorithm supports.
        :param algorithm: name of this algorithm, for the message.
        :param other: the 2M algorithm to use instead, for the message.
        :return: the env (built if an id was given).
        :raises ValueError: naming ``other`` if the action space is not an ``expected``.
        """
        if env is None:
            return env
        env = maybe_make_env(env, 0)
        if not isinstance(env.action_space, expected):
            raise ValueError(
                f"{algorithm} needs a {expected.__name__} action space, got {env.action_space}; "
                f"use {other} for this env"
            )
        return env

    def set_random_seed(self, seed: int | None = None) -> None:
        """SB3's seeding (python, numpy, torch, action space, env) plus the policy's own generators.

        :param seed: seed; ``None`` does nothing, as in SB3.
        """
        super().set_random_seed(seed)  # type: ignore[misc]
        policy = getattr(self, "policy", None)
        if seed is not None and policy is not None:
            policy.set_seed(seed)

    def learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> Any:
        """SB3's ``learn``; the TensorBoard run is named after the class (``TwoMemoryDQN_1``) unless
        ``tb_log_name`` is given.
        """
        return super().learn(  # type: ignore[misc]
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=type(self).__name__ if tb_log_name is None else tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def _two_memory_replay_kwargs(self, data_sharing: bool) -> None:
        """Use a :class:`SourceTaggedReplayBuffer` (unless the user gave a buffer class) that, without data sharing,
        samples RL-collected transitions only."""
        if self.replay_buffer_class is None:
            if isinstance(self.observation_space, spaces.Dict):
                if not data_sharing:
                    raise ValueError(
                        "data_sharing=False is not supported with Dict observations yet (the source-tagged buffer is "
                        "a ReplayBuffer); flatten the observation (gymnasium.wrappers.FlattenObservation) or share data"
                    )
                return  # SB3 picks its DictReplayBuffer; every transition is sampled, as data sharing wants
            self.replay_buffer_class = SourceTaggedReplayBuffer
        if issubclass(self.replay_buffer_class, SourceTaggedReplayBuffer):
            self.replay_buffer_kwargs.setdefault(
                "sampled_sources", (EPISODIC, PARAMETRIC) if data_sharing else (PARAMETRIC,)
            )
        elif not data_sharing:
            raise ValueError(
                "data_sharing=False needs a SourceTaggedReplayBuffer (or a subclass) as replay_buffer_class, "
                f"got {self.replay_buffer_class.__name__}"
            )
