"""Algorithm side of the 2M agents (thesis Algorithm 2): the mixin that gives an SB3 off-policy algorithm its
dispatcher, per-env exploration, source-tagged replay and ``two_memory/*`` logs.

:class:`TwoMemoryAlgorithmMixin` is the base of the three 2M agents (:class:`~sb3_gcrl.two_memory.TwoMemoryDQN`,
:class:`~sb3_gcrl.two_memory.TwoMemorySAC`, :class:`~sb3_gcrl.tabular.TabularTwoMemory`): it builds the
:class:`~sb3_gcrl.two_memory.dispatch.TwoMemoryDispatcher` from its constructor arguments and calls it from
``_setup_learn`` and from every stored step (``_on_transition``), so ``learn`` needs no callback. It also holds the
set-up, the per-env exploration, the train step guard and the logging of the three agents.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import BasePolicy

from sb3_gcrl.common.runs import ClassNamedRunsMixin
from sb3_gcrl.common.saving import ModelFileMixin
from sb3_gcrl.common.seeding import SeededGeneratorMixin
from sb3_gcrl.common.transitions import Transition, TransitionHooksMixin
from sb3_gcrl.two_memory.buffers import SourceTaggedReplayBuffer
from sb3_gcrl.two_memory.dispatch import PecSpec, TwoMemoryDispatcher
from sb3_gcrl.two_memory.schedules import DEFAULT_P_EC_SCHEDULE, EPISODIC, PARAMETRIC


class TwoMemoryAlgorithmMixin(SeededGeneratorMixin, ModelFileMixin, ClassNamedRunsMixin, TransitionHooksMixin):
    """Algorithm side of 2M for an SB3 ``OffPolicyAlgorithm`` whose policy is a
    :class:`~sb3_gcrl.two_memory.policy_mixin.TwoMemoryDispatchMixin`.

    Mix in first (``class TwoMemoryDQN(TwoMemoryAlgorithmMixin, DQN)``). It

    - takes the 2M settings as constructor arguments (each stated once: they are refused in ``policy_kwargs``) and
      gives each to its one owner: the p_ec schedule, data sharing, ``ec_gamma`` and ``ec_update_truncated`` to the
      :class:`~sb3_gcrl.two_memory.dispatch.TwoMemoryDispatcher` (:attr:`dispatcher`, which checks them), the score
      window and the subclass's EC settings (``ec_kwargs``) to the policy;
    - drives the dispatch: :attr:`dispatcher` draws each env's acting memory when its episode starts and finishes
      every episode (``p_ec`` is the last draw's), from ``_setup_learn`` and ``_on_transition``, so ``learn``
      needs no callback;
    - acts through the policy's per-env dispatch, with epsilon-greedy applied per env on both memories for
      Discrete actions (stock DQN draws one epsilon coin for the whole batch of envs), its coins drawn with the
      algorithm's own generator (:class:`~sb3_gcrl.common.seeding.SeededGeneratorMixin`);
    - keeps SB3's random warm-up (``learning_starts``) for RL-run episodes only: EC-run episodes act with the
      episodic memory from the first step, since EC has nothing to wait for;
    - tags every stored transition with the memory that collected it and, without data sharing, trains the RL
      memory on its own transitions only (:class:`~sb3_gcrl.two_memory.buffers.SourceTaggedReplayBuffer`);
    - logs ``two_memory/*`` (:meth:`~sb3_gcrl.two_memory.dispatch.TwoMemoryDispatcher.record_logs`).
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
        :param ec_kwargs: the subclass's EC settings, handed to the policy: constructor arguments of its policy, which
            the subclass takes under the same names, with the policy's defaults
            (:func:`~sb3_gcrl.common.arguments.constructor_defaults`).
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

    def _transition_buffer(self, replay_buffer: ReplayBuffer) -> ReplayBuffer:
        """SB3's replay buffer, told which memory acted in each env (a source-tagged one).

        :param replay_buffer: SB3's replay buffer.
        """
        if isinstance(replay_buffer, SourceTaggedReplayBuffer):
            replay_buffer.next_sources[:] = self.policy.acting_memory
        return replay_buffer

    def _on_transition(self, transition: Transition) -> None:
        """Hand the step to the dispatcher (episodes, memory updates, the next draws).

        :param transition: the step of every training env.
        """
        # the episodic memory is keyed on what the policy sees (normalised if VecNormalize is used); the scores and
        # stored returns use the env's own rewards
        normalize = self._vec_normalize_env
        rewards = transition.rewards if normalize is None else normalize.get_original_reward()
        self.dispatcher.step(
            self.policy,
            transition.observations,
            transition.actions,
            rewards,
            transition.dones,
            transition.infos,
            self.num_timesteps,
            self.logger,
            transition.replay_buffer,
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
