"""Per-episode dispatch between an episodic memory (2M-EC) and a parametric one (2M-RL), thesis Algorithm 2.

Three parts, as in SB3 (the algorithm drives training and owns its schedules, the policy acts and holds what is
saved):

- :class:`TwoMemoryDispatchMixin` is mixed into an SB3 policy that holds both memories (tabular, DQN or SAC
  flavour). It acts with the memory that runs each env's current episode, keeps the score windows (last
  ``score_window`` returns per memory) with the evaluation memory of Eq. 5.6 used by ``predict(deterministic=True)``,
  and puts them into its ``state_dict`` (``get_extra_state``), so ``save``/``load`` bring back the tables, the
  network and the score windows together.
- :class:`TwoMemoryDispatcher` drives the dispatch during training and is the one owner of its settings: the p_ec
  schedule (Eq. 5.5 or another :mod:`~sb3_gcrl.two_memory.schedules` schedule), data sharing, the discount of the
  episodic returns and whether cut episodes update the episodic memory. It draws each env's memory when its episode
  starts, records the running episodes and, when one ends, scores it and updates the episodic memory (Eq. 5.2) --
  with every episode when data is shared, only with the EC's own when it is not (ablation 2Mw/oDS).
- :class:`TwoMemoryAlgorithmMixin` is mixed into the SB3 algorithm: it builds the dispatcher from its constructor
  arguments and calls it from ``_setup_learn`` and ``_store_transition``, so ``learn`` needs no callback. It also
  holds the set-up, the per-env exploration, the train step guard and the logging of the three 2M agents
  (:class:`~sb3_gcrl.two_memory.TwoMemoryDQN`, :class:`~sb3_gcrl.two_memory.TwoMemorySAC`,
  :class:`~sb3_gcrl.tabular.TabularTwoMemory`).

Stock SB3 DQN has no such hooks: :class:`~sb3_gcrl.two_memory.callbacks.TwoMemoryCallback` calls the same
dispatcher from a callback.
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

from sb3_gcrl.common.arguments import settings_among
from sb3_gcrl.common.runs import ClassNamedRunsMixin
from sb3_gcrl.common.saving import ModelFileMixin
from sb3_gcrl.common.seeding import SeededGeneratorMixin, seeded_generator
from sb3_gcrl.common.validation import FiniteRewardsMixin, check_bool, check_unit_interval
from sb3_gcrl.memory.episode import EpisodeRecorder, truncated_ends
from sb3_gcrl.two_memory.buffers import SourceTaggedReplayBuffer
from sb3_gcrl.two_memory.schedules import (
    DEFAULT_P_EC_SCHEDULE,
    EPISODIC,
    PARAMETRIC,
    UNASSIGNED,
    PecSchedule,
    ScoreWindows,
    make_pec_schedule,
)

__all__ = [
    "PecSpec",
    "TwoMemoryAlgorithmMixin",
    "TwoMemoryDispatchMixin",
    "TwoMemoryDispatcher",
    "truncated_ends",
]

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
    """Acting side of a 2M policy; mix in before the SB3 policy (``class P(TwoMemoryDispatchMixin, DQNPolicy)``).

    Concrete policies call :meth:`_init_dispatch` after the SB3 policy's ``__init__``, implement
    :meth:`_episodic_actions`, :meth:`_parametric_actions`, :meth:`update_episodic_memory` and, if their episodic
    memory is not a sub-module with its own state, :meth:`_episodic_state` / :meth:`_load_episodic_state`. They list
    their constructor settings in :attr:`ec_parameters` and keep each as an attribute of the same name (saved by
    ``policy.save``). The training-time settings (p_ec schedule, data sharing, ``ec_gamma``,
    ``ec_update_truncated``) are the :class:`TwoMemoryDispatcher`'s, not the policy's.
    """

    #: constructor arguments of the policy's 2M / EC settings, each kept as an attribute of the same name
    ec_parameters: ClassVar[tuple[str, ...]] = ("score_window",)

    def _init_dispatch(self, score_window: int) -> None:
        """:param score_window: n of Eq. 5.6 (50 in the thesis): the evaluation memory is the one with the higher
        mean return over its last ``score_window`` training episodes.
        """
        self.score_windows = ScoreWindows(score_window)
        self.score_window = self.score_windows.window
        #: memory running each env's current episode (EPISODIC, PARAMETRIC or UNASSIGNED)
        self.acting_memory = np.zeros(0, dtype=np.int8)
        #: episodes run by each memory since construction (saved)
        self.episode_counts = np.zeros(2, dtype=np.int64)

    @staticmethod
    def refuse_dispatcher_settings(policy_kwargs: dict[str, Any], policy_name: str) -> None:
        """Raise if a setting of the :class:`TwoMemoryDispatcher` is given to the policy.

        :param policy_kwargs: the policy's keyword arguments.
        :param policy_name: the policy's class name, for the message.
        :raises ValueError: naming where the setting goes.
        """
        for name in ("p_ec_schedule", *TwoMemoryDispatcher.settings):
            if name in policy_kwargs:
                raise ValueError(
                    f"{name} is a training setting of 2M, not of {policy_name}: pass it to the 2M algorithm "
                    "(TwoMemoryDQN, TwoMemorySAC, TabularTwoMemory) or, with stock DQN, to TwoMemoryCallback "
                    "(stock DQN always shares data)"
                )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()  # type: ignore[misc]
        data.update({name: getattr(self, name) for name in self.ec_parameters})
        return data

    def set_seed(self, seed: int | None) -> None:
        """Reseed the policy's own random generators (EC tie-breaking / sampling); the acting memories are drawn by
        the :class:`TwoMemoryDispatcher`'s generator. Policies with their own generators override this.

        :param seed: seed.
        """

    # ----------------------------------------------------------------------------------------------- episodes
    def reset_acting_memory(self, n_envs: int) -> None:
        """No env has an acting memory (the envs were reset); the next draw gives every env one.

        :param n_envs: number of training envs.
        """
        self.acting_memory = np.full(n_envs, UNASSIGNED, dtype=np.int8)

    def needs_memories(self) -> bool:
        """Whether some env starts an episode and has no acting memory yet."""
        return bool(np.any(self.acting_memory == UNASSIGNED))

    def assign_memories(self, p_ec: float, rng: np.random.Generator) -> np.ndarray:
        """Draw a memory for every env that starts an episode (Algorithm 2: ``U(0,1) < p_ec`` -> EC).

        :param p_ec: probability that an episode is run by the episodic memory (from the p_ec schedule).
        :param rng: the generator of the draws (the dispatcher's).
        :return: the acting memory of each env.
        """
        unassigned = np.flatnonzero(self.acting_memory == UNASSIGNED)
        if unassigned.size > 0:
            draws = rng.random(unassigned.size) < p_ec
            self.acting_memory[unassigned] = np.where(draws, EPISODIC, PARAMETRIC)
        return self.acting_memory

    def end_episode(self, env_index: int, episode_return: float) -> int:
        """An episode of env ``env_index`` ended: score it (Eq. 5.6 window of its memory), count it, and leave the
        env without a memory until the next draw.

        :param env_index: the env.
        :param episode_return: the episode's undiscounted return.
        :return: the memory that ran the episode.
        """
        memory = int(self.acting_memory[env_index])
        self.score_windows.push(memory, episode_return)
        self.episode_counts[memory] += 1
        self.acting_memory[env_index] = UNASSIGNED
        return memory

    def evaluation_memory(self) -> int:
        """Eq. 5.6: the memory with the higher mean return over its last ``score_window`` training episodes."""
        return self.score_windows.evaluation_memory()

    # ----------------------------------------------------------------------------------------------- acting
    def _predict(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        """Greedy action of each row's memory: the evaluation memory (Eq. 5.6) if ``deterministic``, else the
        memory running that env's episode. A batch whose size is not the number of training envs (e.g. a single
        observation given to ``predict``), and an env whose next memory is not drawn yet, use the evaluation
        memory: predicting never changes the dispatch (the :class:`TwoMemoryDispatcher` draws the memories).
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


class TwoMemoryDispatcher:
    """Drives the per-episode dispatch of thesis Algorithm 2 for a :class:`TwoMemoryDispatchMixin` policy, and owns
    its training settings.

    Its host -- a 2M algorithm (:class:`TwoMemoryAlgorithmMixin`) or, with stock DQN,
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


class TwoMemoryAlgorithmMixin(SeededGeneratorMixin, ModelFileMixin, ClassNamedRunsMixin, FiniteRewardsMixin):
    """Algorithm side of 2M for an SB3 ``OffPolicyAlgorithm`` whose policy is a :class:`TwoMemoryDispatchMixin`.

    Mix in first (``class TwoMemoryDQN(TwoMemoryAlgorithmMixin, DQN)``). It

    - takes the 2M settings as constructor arguments (each stated once: they are refused in ``policy_kwargs``) and
      gives each to its one owner: the p_ec schedule, data sharing, ``ec_gamma`` and ``ec_update_truncated`` to the
      :class:`TwoMemoryDispatcher` (:attr:`dispatcher`, which checks them), the score window and the subclass's EC
      settings (``ec_kwargs``) to the policy;
    - drives the dispatch: :attr:`dispatcher` draws each env's acting memory when its episode starts and finishes
      every episode (``p_ec`` is the last draw's), from ``_setup_learn`` and ``_store_transition``, so ``learn``
      needs no callback;
    - acts through the policy's per-env dispatch, with epsilon-greedy applied per env on both memories for
      Discrete actions (stock DQN draws one epsilon coin for the whole batch of envs), its coins drawn with the
      algorithm's own generator (:class:`~sb3_gcrl.common.seeding.SeededGeneratorMixin`);
    - keeps SB3's random warm-up (``learning_starts``) for RL-run episodes only: EC-run episodes act with the
      episodic memory from the first step, since EC has nothing to wait for;
    - tags every stored transition with the memory that collected it and, without data sharing, trains the RL
      memory on its own transitions only (:class:`~sb3_gcrl.two_memory.buffers.SourceTaggedReplayBuffer`);
    - logs ``two_memory/*`` (:meth:`TwoMemoryDispatcher.record_logs`).
    """

    #: p_ec schedule used when none is given (the one place where each agent's default lives)
    default_p_ec_schedule: ClassVar[dict[str, Any]] = DEFAULT_P_EC_SCHEDULE
    #: 2M policy class every policy of this algorithm must subclass
    two_memory_policy_class: ClassVar[type[BasePolicy]]
    #: action space class this algorithm supports, and the 2M algorithm to use instead
    two_memory_action_space: ClassVar[tuple[type[spaces.Space], str] | None] = None
    #: the dispatch of Algorithm 2 and the owner of its settings
    dispatcher: TwoMemoryDispatcher

    def __init__(
        self,
        policy: Any,
        env: Any,
        *,
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
        :param ec_kwargs: the subclass's EC settings (constructor arguments of its policy, see :meth:`policy_settings`),
            handed to the policy.
        :param kwargs: the SB3 algorithm's arguments.
        :raises ValueError: for an action space of the other 2M algorithm, a bad schedule or setting, a 2M / EC
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
        for_policy = {"score_window": score_window, **(ec_kwargs or {})}
        for name in ("policy_kwargs", "replay_buffer_kwargs"):
            if kwargs.get(name) is not None:
                kwargs[name] = dict(kwargs[name])  # SB3 and the 2M set-up write into them: never the caller's
        policy_kwargs = kwargs.get("policy_kwargs") or {}
        for key in ("p_ec_schedule", *TwoMemoryDispatcher.settings, *for_policy):
            if key in policy_kwargs:
                raise ValueError(f"pass {key} to {type(self).__name__} itself, not in policy_kwargs")
        dispatcher = TwoMemoryDispatcher(
            self.default_p_ec_schedule if p_ec_schedule is None else p_ec_schedule,
            data_sharing,
            ec_gamma,
            ec_update_truncated,
        )
        kwargs["policy_kwargs"] = {**policy_kwargs, **for_policy}
        init_setup_model = kwargs.pop("_init_setup_model", True)
        super().__init__(policy, env, _init_setup_model=False, **kwargs)  # type: ignore[call-arg]
        dispatcher.use_gamma_by_default(self.gamma)  # type: ignore[attr-defined]
        self.dispatcher = dispatcher
        if init_setup_model:
            self._setup_model()

    @classmethod
    def policy_settings(cls, arguments: dict[str, Any]) -> dict[str, Any]:
        """The policy's settings among a subclass constructor's arguments (``locals()``): those named in the 2M
        policy class's ``ec_parameters``, which the subclass takes under the same names (with the policy's defaults,
        :func:`~sb3_gcrl.common.arguments.constructor_defaults`).

        :param arguments: the constructor's arguments by name.
        :return: the settings to hand to the policy (``ec_kwargs``).
        """
        return settings_among(arguments, cls.two_memory_policy_class.ec_parameters)  # type: ignore[attr-defined]

    @property
    def p_ec(self) -> float:
        """p_ec of the last draw (logged as ``two_memory/p_ec``; saved with :attr:`dispatcher`)."""
        return self.dispatcher.p_ec

    def _setup_model(self) -> None:
        """Check the policy class, pick the replay buffer by the data-sharing setting, build the SB3 model."""
        if not issubclass(self.policy_class, self.two_memory_policy_class):
            raise ValueError(
                f"{type(self).__name__} needs a {self.two_memory_policy_class.__name__} (aliases "
                f"{sorted(self.policy_aliases)}), got {self.policy_class.__name__}"
            )
        self.replay_buffer_kwargs = dict(self.replay_buffer_kwargs)
        self._two_memory_replay_kwargs(self.dispatcher.data_sharing)
        restored = self.dispatcher.rng  # only ``load`` brings a dispatcher with a generator: continue it
        super()._setup_model()  # type: ignore[misc]
        if restored is not None:
            self.dispatcher.rng = restored

    def _seed_generators(self, seed: int | None) -> None:
        """The algorithm's generator (exploration coins) and the dispatcher's (memory draws).

        :param seed: the seed; ``None``: fresh entropy.
        """
        super()._seed_generators(seed)
        dispatcher = getattr(self, "dispatcher", None)
        if dispatcher is not None:
            dispatcher.seed(seed)

    def _setup_learn(self, *args: Any, **kwargs: Any) -> Any:
        previous_obs = self._last_obs  # type: ignore[has-type]
        result = super()._setup_learn(*args, **kwargs)  # type: ignore[misc]
        # (the envs were reset if the observation changed: their running episodes are gone)
        self.dispatcher.start(self.policy, self.n_envs, self.num_timesteps, self._last_obs is not previous_obs)
        return result

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        policy = self.policy
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
            random_rows |= policy.acting_memory == PARAMETRIC
        if isinstance(self.action_space, spaces.Discrete):
            random_rows |= self._rng.random(n_envs) < getattr(self, "exploration_rate", 0.0)
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
        self.dispatcher.step(
            self.policy,
            observations,
            buffer_action,
            rewards,
            dones,
            infos,
            self.num_timesteps,
            self.logger,
            replay_buffer,
        )

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
