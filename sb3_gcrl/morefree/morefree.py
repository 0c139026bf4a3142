"""MoReFree on a world model (thesis Ch. 3, Algorithms 1-3, Sec. 3.3.2 and 3.4): an SB3 ``BaseAlgorithm``.

Built as PEG's state-input agent (LEXA / DreamerV2 underneath). Every ``train_ratio`` env steps (thesis Table 3.2)
one training step runs (Algorithm 2, lines 10-14):

1. the world model (:class:`~sb3_gcrl.morefree.networks.WorldModel`) on ``batch_size`` chunks of
   ``batch_length`` replayed steps, and the Plan2Explore ensemble on the same posteriors;
2. pi_G and pi_E in imagination from the posterior states, in one batch: pi_G toward goals drawn w.p. alpha/2
   from rho_0, alpha/2 from rho_g* and 1 - alpha uniformly from replayed states (Sec. 3.4.2), rewarded with
   ``-D(achieved goal, g)`` of the dynamical distance; pi_E with the ensemble's disagreement; then both critics and
   D (on pairs of the imagined pi_G paths and of the replayed streams). pi_G's actor waits ``distance_warmup``
   training steps.

Actors learn by backpropagating lambda-returns through the model (DreamerV2's ``dynamics`` gradient for
continuous actions) with an entropy bonus; critics regress the lambda-returns, bootstrapped from slow target
critics. The environment's reward and ``compute_reward`` are never read for training.

Data collection: in the Go phase of a :class:`~sb3_gcrl.wrappers.GoExploreWrapper` (or with no such wrapper) the
agent acts with pi_G toward the observation's ``desired_goal`` (the commanded goal); in the Explore phase with
pi_E (the wrapper, built with ``explore_policy="agent"``, executes it). Exploratory goals come from
:class:`~sb3_gcrl.morefree.goals.PEGScheduler`: the wrapper asks for them at the resets that draw one and the agent
answers with :meth:`MoReFree.plan_exploratory_goal` (PEG's cross-entropy planner). The agent reads and answers the
wrappers only through ``VecEnv.get_attr`` / ``env_method``, so any VecEnv works (``SubprocVecEnv`` included).
docs/morefree.md lists where this departs from PEG and why.

This module holds the agent's settings and its training step; the learn loop and data collection are its base class
(:mod:`~sb3_gcrl.morefree.collection`), the losses pure functions (:mod:`~sb3_gcrl.morefree.losses`), PEG's planner
:mod:`~sb3_gcrl.morefree.peg`, the goal and pair draws :mod:`~sb3_gcrl.morefree.sampling`, and bfloat16 and
``torch.compile`` :mod:`~sb3_gcrl.morefree.acceleration`.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.type_aliases import GymEnv
from torch.profiler import record_function

import sb3_gcrl.morefree.losses as losses
from sb3_gcrl.common.saving import ModelFileMixin
from sb3_gcrl.common.seeding import SeededGeneratorMixin
from sb3_gcrl.common.validation import (
    check_bool,
    check_choice,
    check_float,
    check_int,
    check_optional_int,
    check_unit_interval,
)
from sb3_gcrl.morefree.acceleration import autocast, compile_functions, native_bfloat16_or_warn
from sb3_gcrl.morefree.buffer import SequenceReplayBuffer
from sb3_gcrl.morefree.collection import DEFAULT_ALPHA, MoReFreeCollector
from sb3_gcrl.morefree.functional import frozen, symlog
from sb3_gcrl.morefree.networks import LatentState
from sb3_gcrl.morefree.policies import MoReFreePolicy
from sb3_gcrl.morefree.sampling import imagination_goals, replay_pairs


class MoReFree(SeededGeneratorMixin, ModelFileMixin, MoReFreeCollector):
    """Model-based reset-free goal-conditioned agent (MoReFree, thesis Ch. 3), PEG's state-input agent.

    Defaults are PEG's point-maze settings (the thesis preset); the CPU presets are the sections
    of ``zoo_configs/morefree.yml`` (the thesis preset: ``zoo_configs/morefree_thesis.yml``).

    :param policy: ``"MultiInputPolicy"`` / ``"MoReFreePolicy"`` or the class.
    :param env: goal env (Dict observation, Box actions); for reset-free training wrap it with
        :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` and :func:`~sb3_gcrl.morefree.morefree_go_explore` and pass
        :class:`~sb3_gcrl.callbacks.ResetFreeCallback` to ``learn``.
    :param learning_rate: world-model learning rate (PEG: 3e-4).
    :param buffer_size: replay rows (all envs together).
    :param learning_starts: env steps of uniform random actions before training (PEG's prefill: 2500 steps).
    :param batch_size: sequences per world-model batch (PEG: 45).
    :param batch_length: steps per sequence (PEG: 50).
    :param train_ratio: env steps per training step, thesis Table 3.2 (PointUMaze 2, Sawyer Door 5, Tabletop 1,
        Fetch tasks and Ant 2; PEG: 5).
    :param imagination_horizon: imagined steps per start state (PEG: 15).
    :param imagination_starts: posterior states used as imagination starts per training step (``None``: all
        ``batch_size * batch_length``, as PEG); fewer is faster on CPU.
    :param gamma: discount in imagination (PEG: 0.99).
    :param lambda_: TD(lambda) parameter (PEG: 0.95).
    :param imagination_alpha: share alpha of task-relevant imagination goals (alpha/2 rho_0, alpha/2 rho_g*);
        ``None`` reads alpha from the env's Back-and-Forth scheduler (stated once, there), or 0.2 (thesis) when the
        env has none. Set it to 0 for "MF w/o Imag." and to 0.2 with an ``alpha=0`` env for "MF w/o BF-GE".
    :param replay_goals: where the 1 - alpha replayed imagination goals come from: ``"batch"``, the achieved goals
        of the training batch's states in random order (PEG's ``training_goals: batch``, so about one goal in
        ``batch_size`` lies on the start's own replayed sequence), or ``"buffer"``, states drawn uniformly from the
        whole replay buffer.
    :param own_goal_fraction: share of the replayed imagination goals replaced by the start's own achieved goal
        ("stay here" goals). Not in the thesis or PEG: the ``own_goal`` variant of the presets (0 is the thesis's
        agent; docs/morefree.md, "Goal holding").
    :param entropy_coef: actor entropy bonus (PEG's point maze: 1e-4; DreamerV2: 2e-3).
    :param target_update_interval: training steps between copies into the slow critics (PEG: 100).
    :param expl_reward_scale: scale of the disagreement reward of pi_E (PEG: 1).
    :param distance_pairs: pairs of each source (imagined paths, replayed streams) per distance update (PEG's
        ``dd_num_positives``: 256).
    :param distance_neg_fraction: negatives per positive pair of the distance loss, target one step beyond the
        longest positive (PEG's ``dd_neg_sampling_factor``: 0 in its point maze, 0.1 elsewhere).
    :param distance_on_replay: also train the distance on pairs of the replayed streams up to
        :attr:`distance_unit` steps apart (behaviour data that spans the task, where PEG's imagined pairs span 15
        steps; see docs/morefree.md).
    :param distance_window: steps that make distance 1, and the longest gap of the replayed pairs (``None``: the
        Go-phase length H_G with ``distance_on_replay``, else ``imagination_horizon``, PEG's unit).
    :param distance_warmup: training steps in which the distance, world model and critics learn but pi_G does
        not, so that pi_G does not follow an untrained distance's slopes into a saturated action.
    :param peg_samples: goals scored per round of PEG's cross-entropy planner (PEG: 500).
    :param peg_iterations: rounds of the planner (PEG: 5).
    :param peg_elite_fraction: share of the best goals the planner refits to (PEG: 0.2).
    :param peg_horizon: imagined steps of pi_G toward each candidate goal (``None``: the Go-phase length H_G of the
        env's Go/Explore wrapper, as PEG, else ``imagination_horizon``).
    :param compile_train_step: compile the step's loss computations with ``torch.compile`` (once per process, on the
        first training step; minutes on a CPU, then about 2x faster there). Random numbers come from PyTorch's
        generator, as in the plain step, which the compiled step reproduces on fixed seeds.
    :param mixed_precision: bfloat16 matrix products (PEG's ``precision: 16``); distributions and losses in float32,
        and on a CPU the world model's filtering too (bfloat16 is slower there at its small products). Only where
        the device computes bfloat16 natively (a CPU with AVX512-BF16 or AMX, a CUDA GPU that supports it):
        elsewhere bfloat16 is emulated and slower than float32, so the agent trains in float32 and warns once.
    :param n_threads: torch intra-op threads while learning (``None``: leave torch's setting, e.g. RL-Zoo's
        ``--num-threads``).
    :param policy_kwargs: keyword arguments of :class:`~sb3_gcrl.morefree.policies.MoReFreePolicy` (network sizes,
        learning rates of the other learners).
    :param stats_window_size: episodes in the rollout statistics.
    :param tensorboard_log: tensorboard log folder.
    :param verbose: verbosity.
    :param seed: seed.
    :param device: ``"cpu"``, ``"cuda"`` or ``"auto"``.
    :param _init_setup_model: build the networks at construction.
    """

    #: its replay streams keep ``info["executed_action"]`` (:func:`~sb3_gcrl.her.check_stores_executed_actions`)
    stores_executed_actions: ClassVar[bool] = True
    policy_aliases: ClassVar[dict[str, type[MoReFreePolicy]]] = {
        "MultiInputPolicy": MoReFreePolicy,
        "MoReFreePolicy": MoReFreePolicy,
    }
    policy: MoReFreePolicy

    def __init__(
        self,
        policy: str | type[MoReFreePolicy],
        env: GymEnv | str | None,
        learning_rate: float = 3e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 2500,
        batch_size: int = 45,
        batch_length: int = 50,
        train_ratio: int = 2,
        imagination_horizon: int = 15,
        imagination_starts: int | None = None,
        gamma: float = 0.99,
        lambda_: float = 0.95,
        imagination_alpha: float | None = None,
        replay_goals: str = "batch",
        own_goal_fraction: float = 0.0,
        entropy_coef: float = 1e-4,
        target_update_interval: int = 100,
        expl_reward_scale: float = 1.0,
        distance_pairs: int = 256,
        distance_neg_fraction: float = 0.0,
        distance_on_replay: bool = True,
        distance_window: int | None = None,
        distance_warmup: int = 0,
        peg_samples: int = 500,
        peg_iterations: int = 5,
        peg_elite_fraction: float = 0.2,
        peg_horizon: int | None = None,
        compile_train_step: bool = False,
        mixed_precision: bool = False,
        n_threads: int | None = 1,
        policy_kwargs: dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        if callable(learning_rate):
            raise TypeError("MoReFree takes a constant learning_rate (a float)")
        super().__init__(
            policy,
            env,
            learning_rate,
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            support_multi_env=True,
            seed=seed,
            supported_action_spaces=(spaces.Box,),
        )
        check_float("learning_rate", learning_rate, minimum=0.0, exclusive_minimum=True)
        self.buffer_size = check_int("buffer_size", buffer_size, minimum=2)
        self.learning_starts = check_int("learning_starts", learning_starts, minimum=0)
        self.batch_size = check_int("batch_size", batch_size)
        self.batch_length = check_int("batch_length", batch_length, minimum=2)
        n_envs = self.n_envs if self.env is not None else 1
        if self.buffer_size // n_envs < self.batch_length:
            raise ValueError(
                f"buffer_size={self.buffer_size} keeps {self.buffer_size // n_envs} steps per env ({n_envs} envs), "
                f"fewer than batch_length={self.batch_length}: no sequence could ever be sampled and nothing would be "
                f"trained; raise buffer_size to at least {self.batch_length * n_envs} or lower batch_length"
            )
        self.train_ratio = check_int("train_ratio", train_ratio)
        self.imagination_horizon = check_int("imagination_horizon", imagination_horizon)
        self.imagination_starts = check_optional_int("imagination_starts", imagination_starts)
        self.gamma = check_unit_interval("gamma", gamma)
        self.lambda_ = check_unit_interval("lambda_", lambda_)
        self.imagination_alpha = (
            None if imagination_alpha is None else check_unit_interval("imagination_alpha", imagination_alpha)
        )
        self.replay_goals = check_choice("replay_goals", replay_goals, ("batch", "buffer"))
        self.own_goal_fraction = check_unit_interval("own_goal_fraction", own_goal_fraction)
        self.entropy_coef = check_float("entropy_coef", entropy_coef, minimum=0.0)
        self.target_update_interval = check_int("target_update_interval", target_update_interval)
        self.expl_reward_scale = check_float("expl_reward_scale", expl_reward_scale, minimum=0.0)
        self.distance_pairs = check_int("distance_pairs", distance_pairs)
        self.distance_neg_fraction = check_unit_interval("distance_neg_fraction", distance_neg_fraction)
        self.distance_on_replay = check_bool("distance_on_replay", distance_on_replay)
        self.distance_window = check_optional_int("distance_window", distance_window)
        self.distance_warmup = check_int("distance_warmup", distance_warmup, minimum=0)
        self.peg_samples = check_int("peg_samples", peg_samples, minimum=2)
        self.peg_iterations = check_int("peg_iterations", peg_iterations)
        self.peg_elite_fraction = check_unit_interval("peg_elite_fraction", peg_elite_fraction, exclude_zero=True)
        self.peg_horizon = check_optional_int("peg_horizon", peg_horizon)
        self.compile_train_step = check_bool("compile_train_step", compile_train_step)
        self.mixed_precision = check_bool("mixed_precision", mixed_precision)
        self.n_threads = check_optional_int("n_threads", n_threads)
        self._n_updates = 0
        if _init_setup_model:
            self._setup_model()

    # --- setup ------------------------------------------------------------------------------------------------
    def _setup_model(self) -> None:
        self._setup_lr_schedule()
        with self._continuing_saved_generator():
            self.set_random_seed(self.seed)
        self.policy = self.policy_class(  # type: ignore[assignment]
            self.observation_space, self.action_space, self.lr_schedule, **self.policy_kwargs
        )
        self.policy = self.policy.to(self.device)
        action_dim = int(np.prod(self.action_space.shape))
        self.replay_buffer = SequenceReplayBuffer(
            self.buffer_size, self.n_envs, self.policy.state_dim, action_dim, goal_dim=self.policy.goal_dim
        )
        self._latent = None
        self._prev_action = None
        self._stream_obs = None
        self._task_goals = None
        self._planned_envs = []
        self._reads_acting_policy = False
        self._go_steps = None
        self._compiled: dict[str, Callable[..., Any]] | None = None
        self._bfloat16: bool | None = None  # mixed_precision on this device: decided on the first training step
        self._alpha = DEFAULT_ALPHA if self.imagination_alpha is None else float(self.imagination_alpha)

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),
            "replay_buffer",
            "_latent",
            "_prev_action",
            "_stream_obs",
            "_task_goals",
            "_planned_envs",
            "_compiled",
            "_bfloat16",
        ]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", *(f"policy.{name}_optimizer" for name in MoReFreePolicy.OPTIMIZERS)], []

    # --- task-relevant and imagination goals ---------------------------------------------------------------------
    def sample_imagination_goals(
        self,
        n: int,
        batch_goals: np.ndarray | None = None,
        own_goals: np.ndarray | None = None,
        rng: np.random.Generator | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Goals of the imagined pi_G rollouts (thesis Sec. 3.4.2, Algorithm 2 line 14).

        :param n: number of goals.
        :param batch_goals: achieved goals of the training batch ``(m, goal_dim)``, the replayed goals' pool with
            ``replay_goals="batch"`` (``None``: drawn from the whole buffer).
        :param own_goals: each start's own achieved goal ``(n, goal_dim)``, for ``own_goal_fraction``.
        :param rng: the generator of the draws (``None``: the agent's own, as in training).
        :return: goals ``(n, goal_dim)`` and their kinds ``(n,)``: 0 rho_0 (w.p. alpha/2), 1 rho_g* (alpha/2),
            2 replayed states (1 - alpha; not HER's future states), 3 the start's own achieved goal (a share
            ``own_goal_fraction`` of the replayed ones).
        """
        rng = self._rng if rng is None else rng
        return imagination_goals(
            n,
            self._alpha,
            lambda kind, k: self.task_goal_samples(kind, k, rng),
            self.replay_buffer,
            rng,
            self.replay_goals,
            self.own_goal_fraction,
            batch_goals,
            own_goals,
        )

    # --- imagination (public, for probes) ---------------------------------------------------------------------
    def imagine(self, start: LatentState, goals: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """pi_G (toward ``goals``) and pi_E imagined from the same starts for ``imagination_horizon`` steps, as in
        training (:func:`~sb3_gcrl.morefree.losses.imagine`: rows ``[:N]`` follow pi_G, rows ``[N:]`` pi_E).

        :param start: flat imagination start states ``(N, ...)``.
        :param goals: symlog goals ``(N, G)`` of pi_G.
        :return: features ``(H + 1, 2N, F)``, actions ``(H, 2N, A)``, entropies ``(H, 2N)``.
        """
        policy = self.policy
        return losses.imagine(
            policy.world_model.rssm, policy.actor_g, policy.actor_e, start, goals, self.imagination_horizon
        )

    def goal_rewards(self, achieved: th.Tensor, goals: th.Tensor) -> th.Tensor:
        """pi_G's rewards ``-D(achieved goal of s_{t+1}, g)`` ``(H, N)`` along imagined paths, from their decoded
        achieved goals ``(H + 1, N, G)`` (:func:`~sb3_gcrl.morefree.losses.goal_rewards`).

        :param achieved: symlog achieved goals along the paths.
        :param goals: symlog goals ``(N, G)``.
        """
        return losses.goal_rewards(self.policy.distance, achieved, goals)

    def lambda_returns(
        self, feats: th.Tensor, rewards: th.Tensor, target: th.nn.Module, goals: th.Tensor | None
    ) -> th.Tensor:
        """Lambda-returns ``(H, N)`` of imagined states ``feats (H + 1, N, F)`` with the agent's ``gamma`` and
        ``lambda_``, bootstrapped from a slow critic (:func:`~sb3_gcrl.morefree.losses.bootstrapped_returns`).

        :param feats: latent features along the paths.
        :param rewards: ``(H, N)`` rewards.
        :param target: the slow critic (``policy.critic_g_target`` or ``policy.critic_e_target``).
        :param goals: symlog goals ``(N, G)`` of V_G, None for V_E.
        """
        return losses.bootstrapped_returns(feats, rewards, target, goals, self.gamma, self.lambda_)

    # --- training ----------------------------------------------------------------------------------------------
    def _apply(self, loss: th.Tensor, learners: tuple[str, ...], skip: tuple[str, ...] = ()) -> None:
        """One backward pass of ``loss`` (a sum over learners with disjoint parameters), then each learner's clipped
        optimizer step (``skip``: learners whose gradients are dropped, e.g. pi_G during the distance warm-up)."""
        policy = self.policy
        for name in learners:
            getattr(policy, f"{name}_optimizer").zero_grad(set_to_none=True)
        loss.backward()
        for name in learners:
            if name in skip:
                continue
            optimizer = getattr(policy, f"{name}_optimizer")
            params = [p for group in optimizer.param_groups for p in group["params"] if p.grad is not None]
            th.nn.utils.clip_grad_norm_(params, policy.grad_clip, foreach=True)
            optimizer.step()

    @property
    def distance_unit(self) -> int:
        """Steps that make distance 1: ``distance_window``, else the env's Go-phase length H_G when the distance
        also learns from replayed pairs (which then span up to this many steps), else the imagination horizon
        (LEXA / PEG's unit)."""
        if self.distance_window is not None:
            return int(self.distance_window)
        if self.distance_on_replay and self._go_steps is not None:
            return int(self._go_steps)
        return self.imagination_horizon

    def _model_losses(
        self, states: th.Tensor, actions: th.Tensor, is_first: th.Tensor
    ) -> tuple[th.Tensor, LatentState, dict[str, th.Tensor]]:
        """:func:`~sb3_gcrl.morefree.losses.model_losses` of the agent's world model and ensemble."""
        return losses.model_losses(self.policy.world_model, self.policy.ensemble, states, actions, is_first)

    def _imagination_losses(
        self, start: LatentState, goals: th.Tensor
    ) -> tuple[th.Tensor, tuple[th.Tensor, ...], dict[str, th.Tensor]]:
        """:func:`~sb3_gcrl.morefree.losses.imagination_losses` with the agent's settings."""
        return losses.imagination_losses(
            self.policy,
            start,
            goals,
            self.imagination_horizon,
            self.gamma,
            self.lambda_,
            self.entropy_coef,
            self.expl_reward_scale,
        )

    def _learner_losses(
        self,
        imagined: tuple[th.Tensor, ...],
        goals: th.Tensor,
        groups: th.Tensor,
        replay_pairs: losses.ReplayPairs | None,
    ) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """:func:`~sb3_gcrl.morefree.losses.learner_losses` with the agent's settings (:attr:`distance_unit`)."""
        return losses.learner_losses(
            self.policy,
            imagined,
            goals,
            groups,
            replay_pairs,
            self.gamma,
            self.distance_unit,
            self.distance_pairs,
            self.distance_neg_fraction,
        )

    def _replay_pairs(self) -> losses.ReplayPairs:
        """:func:`~sb3_gcrl.morefree.sampling.replay_pairs` of ``distance_pairs`` pairs up to :attr:`distance_unit`
        steps apart, ``distance_neg_fraction`` negatives."""
        unit, n_pairs, neg_fraction = self.distance_unit, self.distance_pairs, self.distance_neg_fraction
        return replay_pairs(self.replay_buffer, n_pairs, unit, neg_fraction, self._rng, self.device)

    def _autocast(self, world_model: bool = False) -> AbstractContextManager[Any]:
        """bfloat16 matrix products with ``mixed_precision`` where the device computes them natively
        (:func:`~sb3_gcrl.morefree.acceleration.autocast`; ``world_model``: the world model's step)."""
        return autocast(self._uses_bfloat16(), self.device, world_model)

    def _uses_bfloat16(self) -> bool:
        """``mixed_precision`` where the device computes bfloat16 natively; decided once per process (and per load),
        with one warning where ``mixed_precision`` asks for bfloat16 on a device that would emulate it."""
        if getattr(self, "_bfloat16", None) is None:
            self._bfloat16 = native_bfloat16_or_warn(self.mixed_precision, self.device)
        return bool(self._bfloat16)

    def _loss_functions(self) -> dict[str, Callable[..., Any]]:
        """The three loss computations of a training step, compiled with ``torch.compile`` when
        ``compile_train_step`` (compiled once, on the first training step of the process)."""
        functions = {name: getattr(self, name) for name in ("_model_losses", "_imagination_losses", "_learner_losses")}
        if not self.compile_train_step:
            return functions
        if self._compiled is None:
            self._compiled = compile_functions(functions, self.verbose)
        return self._compiled

    def train(self) -> None:
        """One training step (Algorithm 2, lines 10-14): world model and ensemble, then pi_G, pi_E and D.

        Two backward passes per step: the world model with the ensemble, then every learner trained in imagination
        (their parameters are disjoint; the world model, D and the ensemble are frozen while imagining).
        """
        policy = self.policy
        policy.set_training_mode(True)
        functions = self._loss_functions()
        states_np, actions_np, first_np = self.replay_buffer.sample(self.batch_size, self.batch_length, self._rng)
        states = th.as_tensor(states_np, device=self.device)
        actions = th.as_tensor(actions_np, device=self.device)
        is_first = th.as_tensor(first_np, device=self.device)

        with record_function("morefree.world_model"), self._autocast(world_model=True):
            model_loss, post, metrics = functions["_model_losses"](states, actions, is_first)
        with record_function("morefree.world_model_backward"):
            self._apply(model_loss, ("wm", "ensemble"))

        start = post.flatten()
        groups = th.arange(self.batch_size, device=self.device).repeat(self.batch_length)
        # the batch's achieved goals, in the order of the flat starts (time-major)
        batch_goals = states_np.reshape(-1, states_np.shape[-1])[:, -self.policy.goal_dim :]
        own_goals = batch_goals
        n_starts = start.deter.shape[0]
        if self.imagination_starts is not None and self.imagination_starts < n_starts:
            rows_np = self._rng.choice(n_starts, self.imagination_starts, replace=False)
            rows = th.as_tensor(rows_np, device=self.device)
            start, groups, own_goals = start.rows(rows), groups[rows], own_goals[rows_np]
            n_starts = self.imagination_starts
        goals_np, _ = self.sample_imagination_goals(n_starts, batch_goals, own_goals)
        goals = symlog(th.as_tensor(goals_np, device=self.device))
        pairs = self._replay_pairs() if self.distance_on_replay else None
        frozen_models = frozen(policy.world_model, policy.distance, policy.ensemble)
        with record_function("morefree.imagination"), frozen_models, self._autocast():
            actor_loss, imagined, actor_metrics = functions["_imagination_losses"](start, goals)
        with record_function("morefree.learners"), self._autocast():
            learner_loss, learner_metrics = functions["_learner_losses"](imagined, goals, groups, pairs)
        learners = ("actor_g", "critic_g", "actor_e", "critic_e", "distance")
        with record_function("morefree.imagination_backward"):
            warming_up = self._n_updates < self.distance_warmup
            self._apply(actor_loss + learner_loss, learners, skip=("actor_g",) if warming_up else ())

        self._n_updates += 1
        if self._n_updates % self.target_update_interval == 0:
            policy.critic_g_target.load_state_dict(policy.critic_g.state_dict())
            policy.critic_e_target.load_state_dict(policy.critic_e.state_dict())
        if self._n_updates % 10 == 1:  # .item() syncs a GPU: record every 10 updates
            log = self.logger.record
            log("train/n_updates", self._n_updates, exclude="tensorboard")
            for name, value in {**metrics, **actor_metrics, **learner_metrics}.items():
                log(f"train/{name}", value.item())
            log("train/imagination_alpha", self._alpha)
