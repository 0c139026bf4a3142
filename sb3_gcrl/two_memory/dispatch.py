"""Per-episode dispatch between an episodic memory (2M-EC) and a parametric one (2M-RL), thesis Algorithm 2.

Two mixins, one per SB3 side, as in SB3 (the algorithm owns its schedules, the policy holds what is saved):

- :class:`TwoMemoryDispatchMixin` is mixed into an SB3 policy that holds both memories (tabular, DQN or SAC
  flavour). It holds which memory runs each env's current episode, the running episodes and, when one ends, the
  episodic-memory update (Eq. 5.2) -- with every episode when data is shared, only with the EC's own episodes when
  it is not (ablation 2Mw/oDS) -- and the score windows (last 50 returns per memory) with the evaluation memory of
  Eq. 5.6, used by ``predict(deterministic=True)``. ``get_extra_state`` puts all of it into the policy's
  ``state_dict``, so ``save``/``load`` bring back the tables, the network and the score windows together.
- :class:`TwoMemoryAlgorithmMixin` is mixed into the SB3 algorithm. It owns the p_ec schedule (Eq. 5.5 or another
  :mod:`~sb3_gcrl.two_memory.schedules` schedule), draws the acting memory of each env when its episode starts,
  hands the 2M and EC settings to the policy, and holds the set-up, the train step guard and the logging of the
  three 2M agents (:class:`~sb3_gcrl.two_memory.TwoMemoryDQN`, :class:`~sb3_gcrl.two_memory.TwoMemorySAC`,
  :class:`~sb3_gcrl.tabular.TabularTwoMemory`).

With stock SB3 DQN, :class:`~sb3_gcrl.two_memory.callbacks.TwoMemoryCallback` takes the algorithm's part, with the
same :func:`draw_memories` and :func:`record_two_memory_logs`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.policies import BasePolicy

from sb3_gcrl.common.runs import ClassNamedRunsMixin
from sb3_gcrl.common.saving import ModelFileMixin
from sb3_gcrl.memory.episode import EpisodeBuffers, discounted_returns
from sb3_gcrl.memory.validation import check_int
from sb3_gcrl.two_memory.buffers import SourceTaggedReplayBuffer
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

#: what ``p_ec_schedule`` accepts (see :func:`~sb3_gcrl.two_memory.schedules.make_pec_schedule`)
PecSpec = PecSchedule | float | str | dict[str, Any]


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
    :meth:`_episodic_state` / :meth:`_load_episodic_state`. They list their 2M / EC constructor arguments in
    :attr:`ec_parameters` and keep each as an attribute of the same name (saved by ``policy.save``).
    """

    #: constructor arguments of the 2M / EC settings, each kept as an attribute of the same name
    ec_parameters: ClassVar[tuple[str, ...]] = ("data_sharing", "score_window", "ec_gamma", "ec_update_truncated")

    def _init_dispatch(
        self, data_sharing: bool, score_window: int, ec_gamma: float | None, ec_update_truncated: bool
    ) -> None:
        """:param data_sharing: update the episodic memory with every episode (thesis default) instead of only its own.
            The algorithm applies the same switch to the replay buffer.
        :param score_window: n of Eq. 5.6 (50 in the thesis).
        :param ec_gamma: discount of the returns stored in the episodic memory; ``None``: the algorithm's
            ``gamma``, filled in by the 2M algorithm or by :class:`~sb3_gcrl.two_memory.callbacks.TwoMemoryCallback`.
        :param ec_update_truncated: also write time-limit-truncated episodes into the episodic memory (thesis: the
            Monte-Carlo update of Algorithm 1 / Algorithm 2 runs on every finished episode). ``False`` keeps cut
            episodes out of the memory (their returns still count in the score windows).
        """
        self.data_sharing = bool(data_sharing)
        self.score_window = check_int("score_window", score_window)
        self.ec_gamma: float | None = None
        if ec_gamma is not None:
            self.set_ec_gamma(ec_gamma)
        self.ec_update_truncated = bool(ec_update_truncated)
        self.score_windows = ScoreWindows(self.score_window)
        #: memory running each env's current episode (EPISODIC, PARAMETRIC or UNASSIGNED)
        self.acting_memory = np.zeros(0, dtype=np.int8)
        self.episodes: EpisodeBuffers | None = None
        #: episodes run by each memory since construction (saved)
        self.episode_counts = np.zeros(2, dtype=np.int64)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()  # type: ignore[misc]
        data.update({name: getattr(self, name) for name in self.ec_parameters})
        return data

    def set_seed(self, seed: int | None) -> None:
        """Reseed the policy's own random generators (EC tie-breaking / sampling); numpy's global generator, which
        draws the acting memories, is seeded by the algorithm. Policies with their own generators override this.

        :param seed: seed.
        """

    def set_ec_gamma(self, ec_gamma: float) -> None:
        """Set the discount of the returns stored in the episodic memory.

        :param ec_gamma: discount in [0, 1].
        """
        self.ec_gamma = check_unit_interval("ec_gamma", ec_gamma)

    # ----------------------------------------------------------------------------------------------- episodes
    def reset_episodes(self, n_envs: int) -> None:
        """Forget running episodes (the envs were reset); the next draw gives every env a memory."""
        self.acting_memory = np.full(n_envs, UNASSIGNED, dtype=np.int8)
        self.episodes = None

    def needs_memories(self) -> bool:
        """Whether some env starts an episode and has no acting memory yet."""
        return bool(np.any(self.acting_memory == UNASSIGNED))

    def assign_memories(self, p_ec: float) -> np.ndarray:
        """Draw a memory for every env that starts an episode (Algorithm 2: ``U(0,1) < p_ec`` -> EC).

        :param p_ec: probability that an episode is run by the episodic memory (from the algorithm's schedule).
        :return: the acting memory of each env.
        """
        unassigned = np.flatnonzero(self.acting_memory == UNASSIGNED)
        if unassigned.size > 0:
            draws = np.random.random(unassigned.size) < p_ec
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
        if self.needs_memories():
            raise RuntimeError("record_step called for an env that has no acting memory; call assign_memories first")
        if self.ec_gamma is None:
            raise RuntimeError(
                "ec_gamma is not set: pass ec_gamma to the policy, or train it with a 2M algorithm or with "
                "TwoMemoryCallback, which use the algorithm's gamma"
            )
        features = self._episode_features(observations)
        actions = np.asarray(actions)
        if self.episodes is None:
            self.episodes = EpisodeBuffers(
                n_envs, features.shape[1:], actions.shape[1:], actions.dtype, key_dtype=features.dtype
            )
        self.episodes.add(features, actions, rewards)
        finished = []
        for env_index in np.flatnonzero(dones):
            episode_features, episode_actions, episode_rewards = self.episodes.pop(env_index)
            memory = int(self.acting_memory[env_index])
            episode_return = float(episode_rewards.sum())
            self.score_windows.push(memory, episode_return)
            self.episode_counts[memory] += 1
            cut = truncated is not None and bool(truncated[env_index])
            if (self.data_sharing or memory == EPISODIC) and (self.ec_update_truncated or not cut):
                self.update_episodic_memory(
                    episode_features, episode_actions, discounted_returns(episode_rewards, self.ec_gamma)
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
        observation given to ``predict``), and an env whose next memory is not drawn yet, use the evaluation
        memory: predicting never changes the dispatch (the algorithm or the callback draws the memories).
        """
        n = _batch_size(observation)
        if deterministic or self.acting_memory.size != n:
            memories = np.full(n, self.evaluation_memory(), dtype=np.int8)
        else:
            memories = self.acting_memory
            if self.needs_memories():
                memories = np.where(memories == UNASSIGNED, self.evaluation_memory(), memories).astype(np.int8)
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


def current_p_ec(schedule: PecSchedule, num_timesteps: int, policy: TwoMemoryDispatchMixin) -> float:
    """p_ec of ``schedule`` at ``num_timesteps`` with the policy's current scores (Eq. 5.5 / 5.6 windows).

    :raises ValueError: if the schedule returns a value outside [0, 1].
    """
    p_ec = float(schedule(num_timesteps, policy.score_windows))
    if not 0.0 <= p_ec <= 1.0:
        raise ValueError(f"p_ec schedule {schedule!r} returned {p_ec}, outside [0, 1]")
    return p_ec


def draw_memories(
    schedule: PecSchedule, num_timesteps: int, policy: TwoMemoryDispatchMixin, p_ec: float
) -> tuple[np.ndarray, float]:
    """Give every env that starts an episode its acting memory (Algorithm 2), p_ec read from ``schedule`` then.

    :param schedule: the p_ec schedule.
    :param num_timesteps: env steps so far.
    :param policy: the 2M policy.
    :param p_ec: the p_ec of the last draw (kept when no env starts an episode).
    :return: the acting memory of each env and the p_ec of the last draw.
    """
    if policy.needs_memories():
        p_ec = current_p_ec(schedule, num_timesteps, policy)
    return policy.assign_memories(p_ec), p_ec


def record_two_memory_logs(
    logger: Logger, policy: TwoMemoryDispatchMixin, p_ec: float, replay_buffer: ReplayBuffer | None
) -> None:
    """Log ``two_memory/*``: p_ec of the last draw, both scores (Eq. 5.6), the evaluation memory, episodes per
    memory, the fraction of envs acting with EC and the fraction of EC data in a source-tagged replay buffer."""
    windows = policy.score_windows
    logger.record("two_memory/p_ec", p_ec)
    for memory, name in ((EPISODIC, "ec"), (PARAMETRIC, "rl")):
        if windows.n_episodes(memory) > 0:
            logger.record(f"two_memory/score_{name}", windows.score(memory))
        logger.record(f"two_memory/episodes_{name}", int(policy.episode_counts[memory]))
    logger.record("two_memory/eval_memory_is_ec", int(policy.evaluation_memory() == EPISODIC))
    logger.record("two_memory/acting_ec_fraction", float(np.mean(policy.acting_memory == EPISODIC)))
    if isinstance(replay_buffer, SourceTaggedReplayBuffer):
        logger.record("two_memory/buffer_ec_fraction", replay_buffer.source_fraction(EPISODIC))


def truncated_ends(dones: np.ndarray, infos: list[dict[str, Any]]) -> np.ndarray:
    """Which episode ends of a step are time-limit truncations (SB3's ``TimeLimit.truncated``)."""
    return np.array([bool(done) and info.get("TimeLimit.truncated", False) for done, info in zip(dones, infos)])


class TwoMemoryAlgorithmMixin(ModelFileMixin, ClassNamedRunsMixin):
    """Algorithm side of 2M for an SB3 ``OffPolicyAlgorithm`` whose policy is a :class:`TwoMemoryDispatchMixin`.

    Mix in first (``class TwoMemoryDQN(TwoMemoryAlgorithmMixin, DQN)``). It

    - takes the 2M switches and the EC settings as constructor arguments (a subclass passes its EC settings as
      ``ec_kwargs``; their names are kept in ``ec_settings``) and hands them to the policy; they are refused in
      ``policy_kwargs``, so each is stated once;
    - owns the p_ec schedule (``p_ec_schedule``; ``None``: :attr:`default_p_ec_schedule`) as CEC/MFEC own their
      epsilon schedule, and draws each env's acting memory when its episode starts (``p_ec`` is the last draw's);
    - acts through the policy's per-env dispatch, with epsilon-greedy applied per env on both memories for
      Discrete actions (stock DQN draws one epsilon coin for the whole batch of envs);
    - keeps SB3's random warm-up (``learning_starts``) for RL-run episodes only: EC-run episodes act with the
      episodic memory from the first step, since EC has nothing to wait for;
    - tags every stored transition with the memory that collected it and, without data sharing, trains the RL
      memory on its own transitions only (:class:`~sb3_gcrl.two_memory.buffers.SourceTaggedReplayBuffer`);
    - feeds each step to the policy, which updates the episodic memory and the score windows at episode ends;
    - logs ``two_memory/*`` (:func:`record_two_memory_logs`).
    """

    #: p_ec schedule used when none is given (the one place where each agent's default lives)
    default_p_ec_schedule: ClassVar[dict[str, Any]] = DEFAULT_P_EC_SCHEDULE
    #: 2M policy class every policy of this algorithm must subclass
    two_memory_policy_class: ClassVar[type[BasePolicy]]
    #: action space class this algorithm supports, and the 2M algorithm to use instead
    two_memory_action_space: ClassVar[tuple[type[spaces.Space], str] | None] = None

    def __init__(
        self,
        policy: Any,
        env: Any,
        p_ec_schedule: PecSpec | None = None,
        data_sharing: bool = True,
        score_window: int = 50,
        ec_gamma: float | None = None,
        ec_update_truncated: bool = True,
        ec_kwargs: dict[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        """:param policy: policy class or alias.
        :param env: env, VecEnv, env id or None (loading).
        :param p_ec_schedule: p_ec schedule (see :func:`~sb3_gcrl.two_memory.schedules.make_pec_schedule`);
            ``None``: :attr:`default_p_ec_schedule`.
        :param data_sharing: share all data between both memories (thesis Sec. 5.4.3); ``False``: 2Mw/oDS.
        :param score_window: n of Eq. 5.6 (50).
        :param ec_gamma: discount of the returns stored in the episodic memory (``None``: ``gamma``).
        :param ec_update_truncated: also write time-limit-truncated episodes into the episodic memory.
        :param ec_kwargs: the subclass's :attr:`ec_settings`, handed to the policy.
        :param kwargs: the SB3 algorithm's arguments.
        :raises ValueError: for an action space of the other 2M algorithm, a bad schedule or switch, a 2M / EC
            setting given in ``policy_kwargs``, or ``n_steps > 1`` without a ``replay_buffer_class`` of the user's.
        """
        env = self._check_two_memory_action_space(env)
        n_steps = kwargs.get("n_steps", 1)
        if n_steps != 1 and kwargs.get("replay_buffer_class") is None:
            # SB3 would build its NStepReplayBuffer; the 2M buffer replaces it and n_steps would be silently lost
            raise ValueError(
                f"{type(self).__name__} does not support n-step returns (n_steps={n_steps}): its replay buffer tags "
                "each transition with the memory that collected it (SourceTaggedReplayBuffer), which gives one-step "
                "returns, and SB3 sets n-step returns up only in its own default buffer; leave n_steps=1"
            )
        ec_kwargs = dict(ec_kwargs or {})
        for name in ("policy_kwargs", "replay_buffer_kwargs"):
            if kwargs.get(name) is not None:
                kwargs[name] = dict(kwargs[name])  # SB3 and the 2M set-up write into them: never the caller's
        own = ("p_ec_schedule", "data_sharing", "score_window", "ec_gamma", "ec_update_truncated", *ec_kwargs)
        for key in own:
            if key in (kwargs.get("policy_kwargs") or {}):
                raise ValueError(f"pass {key} to {type(self).__name__} itself, not in policy_kwargs")
        if p_ec_schedule is not None:
            make_pec_schedule(p_ec_schedule)  # a bad spec fails here, naming the accepted forms
        self.p_ec_schedule = p_ec_schedule
        self.data_sharing = bool(data_sharing)
        self.score_window = check_int("score_window", score_window)
        self.ec_gamma = None if ec_gamma is None else check_unit_interval("ec_gamma", ec_gamma)
        self.ec_update_truncated = bool(ec_update_truncated)
        for name, value in ec_kwargs.items():
            setattr(self, name, value)
        #: names of the EC settings handed to the policy (constructor arguments of both)
        self.ec_settings = tuple(ec_kwargs)
        #: p_ec of the last draw (logged as ``two_memory/p_ec``)
        self.p_ec = 0.0
        init_setup_model = kwargs.pop("_init_setup_model", True)
        super().__init__(policy, env, _init_setup_model=False, **kwargs)  # type: ignore[call-arg]
        if init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        """Build the p_ec schedule, hand the 2M switches and EC settings to the policy, pick the replay buffer."""
        if not issubclass(self.policy_class, self.two_memory_policy_class):
            raise ValueError(
                f"{type(self).__name__} needs a {self.two_memory_policy_class.__name__} (aliases "
                f"{sorted(self.policy_aliases)}), got {self.policy_class.__name__}"
            )
        self._p_ec_schedule = make_pec_schedule(
            self.default_p_ec_schedule if self.p_ec_schedule is None else self.p_ec_schedule
        )
        self.policy_kwargs = {
            **self.policy_kwargs,
            "data_sharing": self.data_sharing,
            "score_window": self.score_window,
            "ec_gamma": self.gamma if self.ec_gamma is None else self.ec_gamma,
            "ec_update_truncated": self.ec_update_truncated,
            **{name: getattr(self, name) for name in self.ec_settings},
        }
        self.replay_buffer_kwargs = dict(self.replay_buffer_kwargs)
        self._two_memory_replay_kwargs(self.data_sharing)
        super()._setup_model()  # type: ignore[misc]
        if self.num_timesteps == 0:  # (a loaded model keeps the p_ec of its last draw)
            self.p_ec = current_p_ec(self._p_ec_schedule, 0, self.policy)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_p_ec_schedule"]  # type: ignore[misc]

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
        memories, self.p_ec = draw_memories(self._p_ec_schedule, self.num_timesteps, policy, self.p_ec)
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
        finished = self.policy.record_step(observations, buffer_action, rewards, dones, truncated_ends(dones, infos))
        if finished:
            record_two_memory_logs(self.logger, self.policy, self.p_ec, replay_buffer)

    def train(self, gradient_steps: int, batch_size: int | None = None) -> None:
        """The algorithm's training step, skipped while source filtering leaves nothing to sample (no data sharing,
        no RL-run episode stored yet).

        :param gradient_steps: gradient steps (or table updates).
        :param batch_size: minibatch size (``None``: the algorithm's ``batch_size``).
        """
        buffer = self.replay_buffer
        if isinstance(buffer, SourceTaggedReplayBuffer) and buffer.filters_sources and buffer.n_sampleable() == 0:
            return
        super().train(gradient_steps, self.batch_size if batch_size is None else batch_size)  # type: ignore[misc]

    def _check_two_memory_action_space(self, env: Any) -> Any:
        """Make ``env`` (an id is built here, as SB3 would) and check its action space before SB3 asserts on it.

        :param env: env, VecEnv, env id or None (loading).
        :return: the env (built if an id was given).
        :raises ValueError: naming the other 2M algorithm if the action space is not supported.
        """
        if env is None or self.two_memory_action_space is None:
            return env
        expected, other = self.two_memory_action_space
        env = maybe_make_env(env, 0)
        if not isinstance(env.action_space, expected):
            raise ValueError(
                f"{type(self).__name__} needs a {expected.__name__} action space, got {env.action_space}; "
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
