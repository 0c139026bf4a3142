"""Forward-backward reset-free agent: two SB3 SAC learners that act, store and learn by the env's phases.

:class:`ForwardBackwardSAC` is an SB3 ``SAC`` (the forward policy: ``model.policy``, ``predict``, evaluation) that
holds a second SAC learner, :attr:`ForwardBackwardSAC.backward`, for the backward phases. The env decides the phases
(the reset-free wrappers; the algorithm only follows them): before every step
:meth:`ForwardBackwardSAC._backward_phases` reads which envs are in a backward phase (by default the ``phase`` of
:class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardWrapper`; IBC reads its curriculum's segment kind). Then:

* acting: the forward policy acts for the envs in a forward phase, the backward policy (the ``predict`` of
  :attr:`~ForwardBackwardSAC.backward`, scaled as SB3 scales the forward's) for the others; the random warm-up
  actions of ``learning_starts`` are shared;
* storing: each learner has its own replay buffer (``model.replay_buffer``, ``model.backward_buffer``); a transition
  goes to the buffer of the policy that acted;
* training: only the policy that acted is updated: its share of the ``gradient_steps`` of a ``train`` call is the
  share of the steps its phase took since the last call (one update of the acting policy per env step with
  ``train_freq=1``, as in MEDAL's and IBC's official code); the backward learner's ``train/*`` keys are logged as
  ``backward/*``;
* saving: ``save``/``load`` keep both learners (policies, optimizers, entropy coefficients), ``save_replay_buffer``/
  ``load_replay_buffer`` both buffers in one file.

Subclasses: :class:`~sb3_gcrl.reset_free_baselines.backward_reward.BackwardRewardSAC` (MEDAL, R3L: the backward policy
learns from a learned reward model) and :class:`~sb3_gcrl.reset_free_baselines.IBC` (HER buffers, IBC's curriculum).
"""

from __future__ import annotations

import io
import pathlib
from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import DictReplayBuffer, ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.save_util import load_from_pkl
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer
from stable_baselines3.sac.policies import SACPolicy

from sb3_gcrl.common.runs import ClassNamedRunsMixin
from sb3_gcrl.common.saving import ModelFileMixin, atomic_save_to_pkl
from sb3_gcrl.common.transitions import Observation, TransitionHooksMixin
from sb3_gcrl.her import check_n_sampled_goal

#: the env attribute that tells a forward-backward env (``ForwardBackwardWrapper``) apart
PHASE_ENV_ATTR = "forward_backward_steps"


def has_samples(buffer: Any) -> bool:
    """Whether ``buffer`` can be sampled (a HER buffer needs one finished episode).

    :param buffer: a replay buffer (or a view with ``size``).
    """
    if isinstance(buffer, HerReplayBuffer):
        return bool(np.any(buffer.ep_length > 0))
    return buffer.size() > 0


class _PrefixedLogger:
    """Passes ``record`` calls to a logger under another section (``train/x`` -> ``<section>/x``)."""

    def __init__(self, logger: Any, section: str) -> None:
        self.logger, self.section = logger, section

    def record(self, key: str, value: Any, exclude: Any = None) -> None:
        self.logger.record(f"{self.section}/{key.split('/', 1)[-1]}", value, exclude)


def _rows(obs: Observation, rows: np.ndarray | slice) -> Observation:
    return {k: v[rows] for k, v in obs.items()} if isinstance(obs, dict) else obs[rows]


class _PhaseRouter:
    """``add`` of a replay buffer that sends each env's row to the buffer of the policy that acted.

    A buffer with one column per env takes a step whole (all its envs in the same phase); a one-column buffer
    (``n_envs=1``) takes its rows one by one.

    :param forward: the forward policy's buffer.
    :param backward: the backward policy's buffer.
    :param backward_acted: per env, whether the backward policy acted.
    """

    def __init__(self, forward: ReplayBuffer, backward: ReplayBuffer, backward_acted: np.ndarray) -> None:
        self.buffers = (forward, backward)
        self.backward_acted = backward_acted

    def add(
        self,
        obs: Observation,
        next_obs: Observation,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        n_envs = len(self.backward_acted)
        for buffer, rows in zip(self.buffers, (~self.backward_acted, self.backward_acted)):
            if not rows.any():
                continue
            if rows.all() and buffer.n_envs == n_envs:
                buffer.add(obs, next_obs, action, reward, done, infos)  # type: ignore[arg-type]
            elif buffer.n_envs == 1:
                for i in np.flatnonzero(rows):
                    row = slice(i, i + 1)
                    buffer.add(_rows(obs, row), _rows(next_obs, row), action[row], reward[row], done[row], [infos[i]])  # type: ignore[arg-type]
            else:
                raise RuntimeError(
                    f"the {n_envs} envs are in different phases, but the replay buffers ({type(buffer).__name__}) "
                    "keep one column per env, which a step must fill for all envs at once: train on one env (n_envs=1)"
                )


class ForwardBackwardSAC(ModelFileMixin, ClassNamedRunsMixin, TransitionHooksMixin, SAC):
    """A forward SAC (this object) and a backward SAC (:attr:`backward`) alternating by the env's phases.

    Use it on a goal env wrapped in :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` (``segment_length`` = phase length)
    and :class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardWrapper`, and pass
    :class:`~sb3_gcrl.callbacks.ResetFreeCallback` to ``learn`` (it switches the training env to reset-free mode).
    Every SAC argument is taken and applies to both learners (the backward SAC is built from this model's settings, so
    load-time overrides reach both); ``optimize_memory_usage=True``, ``n_steps > 1`` and ``use_sde=True`` are refused
    with a ``ValueError`` (why: their parameters below). The backward learner's ``train/*`` keys are logged as
    ``backward/*``, the phase shares as ``<log_prefix>/forward_step_share`` and ``<log_prefix>/backward_step_share``;
    ``learn`` names the TensorBoard run after the class.

    :param policy: SAC policy class or alias (``"MultiInputPolicy"`` for goal observations).
    :param env: the env (``None`` only when loading).
    :param learning_rate: see :class:`~stable_baselines3.SAC` (this and the other SAC arguments apply to both).
    :param buffer_size: rows of each learner's replay buffer.
    :param learning_starts: random-action warm-up steps (both phases); no update before.
    :param batch_size: minibatch size of each update.
    :param tau: soft target-update coefficient.
    :param gamma: discount.
    :param train_freq: env steps between two ``train`` calls.
    :param gradient_steps: gradient steps of a ``train`` call, shared by the phases.
    :param action_noise: extra action noise (both policies).
    :param replay_buffer_class: buffer class of both learners (SB3's default when None).
    :param replay_buffer_kwargs: its keyword arguments.
    :param optimize_memory_usage: SAC's argument; only False: each learner's buffer holds its own phases' steps
        only, so the next observation that SB3's memory optimisation reads from the following row would be one of a
        later phase (and SB3's Dict and HER buffers refuse it too).
    :param n_steps: SAC's n-step returns; only 1: SB3 builds n-step returns into its default buffer only, whereas
        both learners keep their own buffers (Dict goal observations, HER goal relabeling, MEDAL's and R3L's
        backward rewards relabeled at sampling time), whose sampled rewards are one-step rewards.
    :param ent_coef: SAC's entropy coefficient.
    :param target_update_interval: gradient steps between target-network updates.
    :param target_entropy: SAC's target entropy.
    :param use_sde: SAC's gSDE exploration; only False: SB3 resamples the exploration noise of this model's actor
        only, so the backward actor's noise would not follow ``sde_sample_freq``.
    :param sde_sample_freq: SAC's gSDE noise resampling frequency (no effect without ``use_sde``).
    :param use_sde_at_warmup: SAC's gSDE during the warm-up (no effect without ``use_sde``).
    :param stats_window_size: episodes (segments) in the rollout statistics.
    :param tensorboard_log: tensorboard folder.
    :param policy_kwargs: keyword arguments of both policies.
    :param verbose: verbosity.
    :param seed: random seed.
    :param device: torch device.
    :param _init_setup_model: build the networks at construction (SB3's load passes False).
    """

    #: section of the logger keys of this algorithm (``<prefix>/forward_step_share``, ...)
    log_prefix: ClassVar[str] = "forward_backward"
    #: one-column (``n_envs=1``) buffers that take each env's row separately, so that envs in different phases can
    #: share a step; otherwise SB3's buffers with one column per env (needed by HER), and all envs share a phase
    _single_column_buffers: ClassVar[bool] = False
    #: ``train`` updates a learner only once its buffer can be sampled (:func:`has_samples`: a HER buffer needs a
    #: finished segment), so :func:`~sb3_gcrl.her.check_her_first_update` lets any ``learning_starts`` through
    waits_for_finished_episodes: ClassVar[bool] = True
    backward: SAC
    backward_buffer: ReplayBuffer

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 3e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 100,
        batch_size: int = 256,
        tau: float = 0.005,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        action_noise: ActionNoise | None = None,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        n_steps: int = 1,
        ent_coef: str | float = "auto",
        target_update_interval: int = 1,
        target_entropy: str | float = "auto",
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        use_sde_at_warmup: bool = False,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        name = type(self).__name__
        if optimize_memory_usage:
            raise ValueError(
                f"{name} does not support optimize_memory_usage=True: each learner's replay buffer holds the steps of "
                "its own phases only, so the next observation that SB3 reads from the following row would be one of "
                "a later phase; leave it False"
            )
        if n_steps != 1:
            raise ValueError(
                f"{name} does not support n-step returns (n_steps={n_steps}): SB3 builds them into its default "
                "replay buffer only, whereas the forward and backward learners keep their own buffers (Dict goal "
                "observations, HER relabeling, rewards relabeled at sampling time) that give one-step rewards; "
                "leave n_steps=1"
            )
        if use_sde:
            raise ValueError(
                f"{name} does not support use_sde=True: SB3 resamples the gSDE noise of the forward actor only, so "
                "the backward actor's exploration noise would not follow sde_sample_freq; leave it False"
            )
        super().__init__(
            policy,
            env,  # type: ignore[arg-type]
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            action_noise=action_noise,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            optimize_memory_usage=optimize_memory_usage,
            n_steps=n_steps,
            ent_coef=ent_coef,
            target_update_interval=target_update_interval,
            target_entropy=target_entropy,
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            use_sde_at_warmup=use_sde_at_warmup,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=dict(policy_kwargs or {}),  # never the caller's dict (SB3's SAC writes use_sde into it)
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        #: env steps taken by the forward and by the backward policy (all envs), in total and since the last train
        self.phase_steps = np.zeros(2, dtype=np.int64)
        self._pending_steps = np.zeros(2, dtype=np.int64)
        self._update_credit = np.zeros(2, dtype=np.float64)
        self._backward_acted = np.zeros(1, dtype=bool)
        if self.env is not None:
            self._check_phase_env(self.env)
        if _init_setup_model:
            self._setup_model()

    # --- phases (the hooks of the subclasses) ---------------------------------------------------------------------
    def _check_phase_env(self, env: VecEnv) -> None:
        """Raise when ``env`` does not give the phases :meth:`_backward_phases` reads.

        :param env: the training env.
        """
        if not env.has_attr(PHASE_ENV_ATTR):
            raise ValueError(
                f"{type(self).__name__} follows the forward/backward phases of the env: wrap it as "
                "ForwardBackwardWrapper(ResetFreeWrapper(env, segment_length=300, ...)) "
                "(sb3_gcrl.reset_free_baselines.ForwardBackwardWrapper; RL-Zoo: env_wrapper) and pass "
                "ResetFreeCallback() to learn"
            )

    def _backward_phases(self) -> np.ndarray:
        """Per env, whether the next step is in a backward phase (the ``phase`` of ``ForwardBackwardWrapper``).

        :return: bool array of shape ``(n_envs,)``.
        """
        assert self.env is not None
        return np.array([phase == "backward" for phase in self.env.get_attr("phase")], dtype=bool)

    # --- construction -----------------------------------------------------------------------------------------
    def _make_buffer(self) -> ReplayBuffer:
        """A replay buffer of ``replay_buffer_class`` for one learner (a HER buffer gets the env)."""
        assert self.replay_buffer_class is not None
        kwargs = dict(self.replay_buffer_kwargs)
        if issubclass(self.replay_buffer_class, HerReplayBuffer):
            if "n_sampled_goal" in kwargs:  # before SB3's HerReplayBuffer divides by n_sampled_goal + 1
                check_n_sampled_goal(kwargs["n_sampled_goal"])
            if self.env is None:
                raise ValueError(f"HerReplayBuffer needs the env: pass env=... ({type(self).__name__}.load(path, env))")
            kwargs["env"] = self.env
        return self.replay_buffer_class(
            self.buffer_size,
            self.observation_space,
            self.action_space,
            device=self.device,
            n_envs=1 if self._single_column_buffers else self.n_envs,
            optimize_memory_usage=self.optimize_memory_usage,
            **kwargs,
        )

    def _backward_sampling_view(self, buffer: ReplayBuffer) -> Any:
        """What the backward SAC samples in ``train``: its buffer itself (subclasses relabel the rewards).

        :param buffer: the backward buffer.
        """
        return buffer

    def _setup_model(self) -> None:
        if self.replay_buffer_class is None:
            is_dict = isinstance(self.observation_space, spaces.Dict)
            self.replay_buffer_class = DictReplayBuffer if is_dict else ReplayBuffer
        self.replay_buffer = self._make_buffer()
        super()._setup_model()
        self.backward_buffer = self._make_buffer()
        # the backward learner: the same SAC settings, read from this model (load-time overrides reach both)
        self.backward = SAC(
            self.policy_class,
            None,  # type: ignore[arg-type]
            learning_rate=self.learning_rate,
            buffer_size=self.buffer_size,
            learning_starts=0,  # the warm-up is this model's (it draws the random actions of both phases)
            batch_size=self.batch_size,
            tau=self.tau,
            gamma=self.gamma,
            gradient_steps=self.gradient_steps,
            ent_coef=self.ent_coef,
            target_update_interval=self.target_update_interval,
            target_entropy=self.target_entropy,  # a float by now (SAC's "auto" resolved above)
            policy_kwargs=dict(self.policy_kwargs),
            device=self.device,
            _init_setup_model=False,
        )
        self.backward.observation_space, self.backward.action_space = self.observation_space, self.action_space
        self.backward.n_envs = self.n_envs
        self.backward.replay_buffer = self._backward_sampling_view(self.backward_buffer)
        self.backward._setup_model()

    # --- acting and storing -----------------------------------------------------------------------------------
    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """The forward policy's action for envs in a forward phase, the backward policy's for the others.

        :param learning_starts: warm-up steps (uniform actions for both policies).
        :param action_noise: extra action noise.
        :param n_envs: number of envs.
        """
        backward = self._backward_acted = self._backward_phases()
        if self.num_timesteps < learning_starts or not backward.any():
            return super()._sample_action(learning_starts, action_noise, n_envs)
        if backward.all():
            return self._backward_action(action_noise)
        action, buffer_action = super()._sample_action(learning_starts, action_noise, n_envs)
        backward_action, backward_buffer_action = self._backward_action(action_noise)
        action[backward], buffer_action[backward] = backward_action[backward], backward_buffer_action[backward]
        return action, buffer_action

    def _backward_action(self, action_noise: ActionNoise | None) -> tuple[np.ndarray, np.ndarray]:
        """The backward policy's action for every env, through its public ``predict``, as SB3's ``_sample_action``
        makes the forward policy's after the warm-up: sampled (not deterministic), scaled to [-1, 1] for the buffer,
        plus the action noise.

        :param action_noise: extra action noise.
        :return: the action for the env and the action for the buffer.
        """
        unscaled_action, _ = self.backward.predict(self._last_obs, deterministic=False)  # type: ignore[arg-type]
        scaled_action = self.backward.policy.scale_action(unscaled_action)
        if action_noise is not None:
            scaled_action = np.clip(scaled_action + action_noise(), -1, 1)
        return self.backward.policy.unscale_action(scaled_action), scaled_action

    def _transition_buffer(self, replay_buffer: ReplayBuffer) -> _PhaseRouter:
        """Each env's transition goes to the buffer of the policy that acted (forward or backward); the phases'
        step counts move on.

        :param replay_buffer: the forward buffer (SB3's argument; the routing uses both buffers).
        """
        backward = self._backward_acted
        counts = np.array([len(backward) - backward.sum(), backward.sum()], dtype=np.int64)
        self.phase_steps += counts
        self._pending_steps += counts
        assert self.replay_buffer is not None
        return _PhaseRouter(self.replay_buffer, self.backward_buffer, backward)

    # --- training -----------------------------------------------------------------------------------------------
    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """Update the forward and the backward SAC by the share of the steps each phase took since the last call.

        :param gradient_steps: gradient steps of this call (shared; the remainders carry over).
        :param batch_size: minibatch size.
        """
        total = int(self._pending_steps.sum())
        if total > 0:
            self._update_credit += gradient_steps * self._pending_steps / total
            self._pending_steps[:] = 0
        updates = np.floor(self._update_credit + 1e-9).astype(int)
        self._update_credit -= updates
        if updates[0] > 0 and self.replay_buffer is not None and has_samples(self.replay_buffer):
            super().train(int(updates[0]), batch_size)
        if updates[1] > 0 and has_samples(self.backward_buffer):
            self.backward._current_progress_remaining = self._current_progress_remaining
            self.backward.set_logger(_PrefixedLogger(self.logger, "backward"))  # type: ignore[arg-type]
            self.backward.train(int(updates[1]), batch_size)

    def dump_logs(self) -> None:
        """Record the phase shares (``<log_prefix>/``), then SB3's ``dump_logs``."""
        total = max(int(self.phase_steps.sum()), 1)
        self.logger.record(f"{self.log_prefix}/forward_step_share", float(self.phase_steps[0] / total))
        self.logger.record(f"{self.log_prefix}/backward_step_share", float(self.phase_steps[1] / total))
        super().dump_logs()

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        """SB3's ``set_env``, with the phase check; HER buffers without an env get this one.

        :param env: the new env.
        :param force_reset: reset it at the next ``learn``.
        """
        super().set_env(env, force_reset)
        assert self.env is not None
        self._check_phase_env(self.env)
        self.backward.n_envs = self.n_envs
        for buffer in (self.replay_buffer, self.backward_buffer):
            if isinstance(buffer, HerReplayBuffer) and buffer.env is None:
                buffer.set_env(self.env)

    # --- saving ------------------------------------------------------------------------------------------------
    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "backward", "backward_buffer", "_backward_acted"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        backward_dicts, backward_variables = self.backward._get_torch_save_params()
        return (
            [*state_dicts, *(f"backward.{name}" for name in backward_dicts)],
            [*variables, *(f"backward.{name}" for name in backward_variables)],
        )

    def save_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase) -> None:
        """Save both replay buffers (forward and backward) in one pickle file, atomically (a crash or kill during
        the save leaves the previous file intact).

        :param path: file path (``.pkl`` added when it has no suffix) or file object.
        """
        atomic_save_to_pkl(path, {"forward": self.replay_buffer, "backward": self.backward_buffer}, self.verbose)

    def load_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True) -> None:
        """Load both replay buffers saved by :meth:`save_replay_buffer` (HER buffers get the model's env).

        :param path: file path or file object.
        :param truncate_last_traj: end the last, unfinished episode of each HER buffer (see SB3's
            ``HerReplayBuffer``); other buffers have no episodes to truncate.
        """
        assert self.replay_buffer_class is not None
        buffers = load_from_pkl(path, self.verbose)
        if not (
            isinstance(buffers, dict)
            and set(buffers) == {"forward", "backward"}
            and all(isinstance(b, self.replay_buffer_class) for b in buffers.values())
        ):
            raise ValueError(
                f"{path} does not hold the forward and backward buffers ({self.replay_buffer_class.__name__}) of "
                f"{type(self).__name__}.save_replay_buffer"
            )
        for buffer in buffers.values():
            if isinstance(buffer, HerReplayBuffer):
                if self.env is None:
                    raise ValueError(f"HER replay buffers need the env: {type(self).__name__}.load(path, env=...)")
                buffer.set_env(self.env)
                if truncate_last_traj:
                    buffer.truncate_last_trajectory()
            buffer.device = self.device
        self.replay_buffer, self.backward_buffer = buffers["forward"], buffers["backward"]
        self.backward.replay_buffer = self._backward_sampling_view(self.backward_buffer)
