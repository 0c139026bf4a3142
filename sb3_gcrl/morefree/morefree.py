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
"""

from __future__ import annotations

import sys
import time
import warnings
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback
from stable_baselines3.common.utils import safe_mean
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper
from torch.profiler import record_function

from sb3_gcrl.common.hardware import describe_cpu, native_bfloat16
from sb3_gcrl.common.runs import warn_if_learning_never_starts
from sb3_gcrl.common.saving import ModelFileMixin, atomic_save_to_pkl
from sb3_gcrl.common.seeding import SeededGeneratorMixin
from sb3_gcrl.common.validation import (
    check_bool,
    check_choice,
    check_float,
    check_int,
    check_optional_int,
    check_unit_interval,
)
from sb3_gcrl.goals.task_goals import TaskRelevantGoals
from sb3_gcrl.morefree.buffer import SequenceReplayBuffer
from sb3_gcrl.morefree.networks import LatentState, frozen, lambda_returns, symlog
from sb3_gcrl.morefree.policies import MoReFreePolicy, state_vector
from sb3_gcrl.wrappers.go_explore import ACTING_GOAL, GOAL_REQUEST_KEY

SelfMoReFree = TypeVar("SelfMoReFree", bound="MoReFree")

#: thesis Sec. 3.7.3: alpha = 0.2 for all tasks
DEFAULT_ALPHA = 0.2


class MoReFree(SeededGeneratorMixin, ModelFileMixin, BaseAlgorithm):
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
        self._latent: LatentState | None = None
        self._prev_action: th.Tensor | None = None
        self._stream_obs: Any = None
        self._task_goals: TaskRelevantGoals | None = None
        #: envs whose goal requests the agent answers (set during learn), whether the envs report acting_policy
        self._planned_envs: list[int] = []
        self._reads_acting_policy = False
        self._go_steps: int | None = None
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

    def save_replay_buffer(self, path: str) -> None:
        """Pickle the sequence replay buffer, atomically (a trusted file only can be loaded back)."""
        atomic_save_to_pkl(path, self.replay_buffer, self.verbose)

    def load_replay_buffer(self, path: str, truncate_last_traj: bool = True) -> None:
        """Load a buffer saved by :meth:`save_replay_buffer` (pickle: load trusted files only).

        :param path: the pickled buffer.
        :param truncate_last_traj: SB3's signature (RL-Zoo passes it); nothing to truncate here: the next ``learn``
            starts a new stream (``is_first``), so the trajectory cut off by the save is never continued.
        """
        from stable_baselines3.common.save_util import load_from_pkl

        buffer = load_from_pkl(path, self.verbose)
        if not isinstance(buffer, SequenceReplayBuffer) or buffer.n_envs != self.n_envs:
            raise ValueError(f"{path} does not hold a SequenceReplayBuffer for {self.n_envs} env(s)")
        self.replay_buffer = buffer

    # --- the Go/Explore wrapper's public interface --------------------------------------------------------------
    def _base_vec_env(self) -> VecEnv:
        """The training VecEnv under its VecEnv wrappers (it holds the reset infos)."""
        env = self.env
        assert env is not None
        return env.unwrapped if isinstance(env, VecEnvWrapper) else env  # type: ignore[return-value]

    def _attach(self) -> None:
        """Declare the agent as the goal planner of the envs that take planned goals; read alpha and H_G; set up
        task goals."""
        env = self.env
        assert env is not None
        self._reads_acting_policy = env.has_attr("acting_policy")
        self._planned_envs = []
        if env.has_attr("takes_planned_goals"):
            self._planned_envs = [i for i, takes in enumerate(env.get_attr("takes_planned_goals")) if takes]
        if self._planned_envs:
            env.env_method("set_goal_planning", True, indices=self._planned_envs)
        if self.imagination_alpha is None:
            alpha = env.get_attr("task_goal_alpha")[0] if env.has_attr("task_goal_alpha") else None
            self._alpha = DEFAULT_ALPHA if alpha is None else float(alpha)
        self._go_steps = int(env.get_attr("go_steps")[0]) if env.has_attr("go_steps") else None
        if not env.has_attr("sample_task_goals") and self._task_goals is None:
            base = self._base_vec_env()
            source = base.envs[0] if isinstance(base, DummyVecEnv) else env
            self._task_goals = TaskRelevantGoals(source, self.policy.goal_dim)  # type: ignore[arg-type]

    def _detach(self) -> None:
        """Stop answering goal requests (the envs take their fallback goals until the next ``learn``)."""
        if self._planned_envs and self.env is not None:
            self.env.env_method("set_goal_planning", False, indices=self._planned_envs)

    def _phases(self) -> list[str]:
        """Per env, ``"explore"`` where the next step is an Explore-phase step (pi_E acts), else ``"go"``."""
        assert self.env is not None
        if not self._reads_acting_policy:
            return ["go"] * self.n_envs
        return ["go" if acting == ACTING_GOAL else "explore" for acting in self.env.get_attr("acting_policy")]

    def _answer_goal_requests(self, new_obs: dict[str, np.ndarray], dones: np.ndarray) -> None:
        """Plan the goals the envs asked for at the resets of this step and write them into ``new_obs``.

        Each request carries the observation and the env's generator; the plan draws from that generator (and the
        env continues from it), so the run is the same in a ``DummyVecEnv`` and a ``SubprocVecEnv``.
        """
        env = self.env
        assert env is not None
        reset_infos = self._base_vec_env().reset_infos
        for i in np.flatnonzero(dones):
            if not reset_infos[i].get(GOAL_REQUEST_KEY, False):
                continue
            obs, rng = env.env_method("goal_request", indices=[i])[0]
            goal = self.plan_exploratory_goal(obs, rng)
            commanded = env.env_method("answer_goal_request", goal, rng, indices=[i])[0]
            new_obs["desired_goal"][i] = commanded["desired_goal"]

    # --- task-relevant and imagination goals ---------------------------------------------------------------------
    def _task_goal_samples(self, kind: str, n: int) -> np.ndarray:
        assert self.env is not None
        if self._task_goals is None:
            return np.asarray(self.env.env_method("sample_task_goals", kind, n, indices=[0])[0], dtype=np.float32)
        return self._task_goals.sample(kind, self._rng, n).astype(np.float32)  # type: ignore[arg-type]

    def sample_imagination_goals(
        self, n: int, batch_goals: np.ndarray | None = None, own_goals: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Goals of the imagined pi_G rollouts (thesis Sec. 3.4.2, Algorithm 2 line 14).

        :param n: number of goals.
        :param batch_goals: achieved goals of the training batch ``(m, goal_dim)``, the replayed goals' pool with
            ``replay_goals="batch"`` (``None``: drawn from the whole buffer).
        :param own_goals: each start's own achieved goal ``(n, goal_dim)``, for ``own_goal_fraction``.
        :return: goals ``(n, goal_dim)`` and their kinds ``(n,)``: 0 rho_0 (w.p. alpha/2), 1 rho_g* (alpha/2),
            2 replayed states (1 - alpha; not HER's future states), 3 the start's own achieved goal (a share
            ``own_goal_fraction`` of the replayed ones).
        """
        alpha = self._alpha
        kinds = self._rng.choice(3, size=n, p=[alpha / 2, alpha / 2, 1 - alpha])
        if self.own_goal_fraction > 0.0:
            if own_goals is None:
                raise ValueError("own_goal_fraction > 0 needs each start's own achieved goal (own_goals)")
            kinds[(kinds == 2) & (self._rng.random(n) < self.own_goal_fraction)] = 3
        goal_dim = self.policy.goal_dim
        goals = np.empty((n, goal_dim), dtype=np.float32)
        for kind, name in ((0, "initial"), (1, "evaluation")):
            mask = kinds == kind
            if mask.any():
                goals[mask] = self._task_goal_samples(name, int(mask.sum())).reshape(-1, goal_dim)
        mask = kinds == 2
        if mask.any():
            if self.replay_goals == "batch" and batch_goals is not None:
                pool = batch_goals.reshape(-1, goal_dim)
                goals[mask] = pool[self._rng.choice(len(pool), int(mask.sum()), replace=int(mask.sum()) > len(pool))]
            else:
                goals[mask] = self.replay_buffer.sample_states(int(mask.sum()), self._rng)[:, -goal_dim:]
        mask = kinds == 3
        if mask.any():
            goals[mask] = np.asarray(own_goals).reshape(n, goal_dim)[mask]
        return goals, kinds

    def _goal_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The box PEG's planner searches: the ``desired_goal`` space, or the span of the replayed achieved goals
        (padded by 10% each side) where that space is unbounded."""
        space = self.observation_space["desired_goal"]  # type: ignore[index]
        low, high = space.low.reshape(-1).astype(np.float64), space.high.reshape(-1).astype(np.float64)
        if np.isfinite(low).all() and np.isfinite(high).all():
            return low, high
        visited = self.replay_buffer.achieved_goals().astype(np.float64)
        lo, hi = visited.min(0), visited.max(0)
        pad = 0.1 * np.maximum(hi - lo, 1e-3)
        return np.where(np.isfinite(low), low, lo - pad), np.where(np.isfinite(high), high, hi + pad)

    def _peg_fitness(self, start: LatentState, candidates: np.ndarray, horizon: int) -> th.Tensor:
        """PEG's score of candidate goals: pi_G is imagined from ``start`` toward each for ``horizon`` steps; the
        score sums, over the imagined path, the lambda-returns of pi_E's intrinsic reward (the ensemble's
        disagreement) bootstrapped from V_E (PEG's ``cost_use_p2e_value``)."""
        policy = self.policy
        rssm = policy.world_model.rssm
        goals = symlog(th.as_tensor(candidates, dtype=th.float32, device=self.device))
        latent = start.expand(len(candidates))
        feats, actions = [latent.feat], []
        for _ in range(horizon):
            action, _ = policy.actor_g.act(latent.feat, goals)
            latent = rssm.img_step(latent, action)
            feats.append(latent.feat)
            actions.append(action)
        feat, action = th.stack(feats), th.stack(actions)
        rewards = self.expl_reward_scale * policy.ensemble.disagreement(feat[:-1], action)
        returns = lambda_returns(rewards, policy.critic_e_target(feat), self.gamma, self.lambda_)
        return returns.sum(0)

    def plan_exploratory_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray | None:
        """PEG's exploratory goal (Hu et al., 2023): cross-entropy search over goal space for the goal whose imagined
        pi_G path is worth most to the explorer.

        A diagonal Gaussian starts at the env's achieved goal with half the goal box as std; each of
        ``peg_iterations`` rounds scores ``peg_samples`` goals drawn from it (clipped to the box, see
        :meth:`_peg_fitness`, imagined from the env's current latent) and refits it to the best
        ``peg_elite_fraction``. The goal is a draw from the final Gaussian, as in PEG.

        :param obs: the env's current observation (one env).
        :param rng: the scheduler's generator (candidate draws).
        :return: the goal, or None before training starts.
        """
        if self.num_timesteps < self.learning_starts or self.replay_buffer.size() == 0:
            return None
        policy = self.policy
        low, high = self._goal_box()
        mean = np.asarray(obs["achieved_goal"], dtype=np.float64).reshape(-1)
        std = 0.5 * (high - low)
        n_elite = max(2, int(round(self.peg_elite_fraction * self.peg_samples)))
        horizon = self.peg_horizon or self._go_steps or self.imagination_horizon
        with th.no_grad():
            state = th.as_tensor(state_vector(obs), device=self.device).reshape(1, -1)
            start = policy.hold_latent(state)
            for _ in range(self.peg_iterations):
                candidates = np.clip(mean + std * rng.standard_normal((self.peg_samples, mean.size)), low, high)
                fitness = self._peg_fitness(start, candidates, horizon)
                elite = candidates[th.topk(fitness, n_elite).indices.cpu().numpy()]
                mean, std = elite.mean(0), np.sqrt(elite.var(0) + 1e-6)
        return np.clip(mean + std * rng.standard_normal(mean.size), low, high)

    # --- acting ------------------------------------------------------------------------------------------------
    def _start_streams(self) -> None:
        """Begin every env's replay stream and latent state at the current observations (a physical start)."""
        assert self._last_obs is not None and isinstance(self._last_obs, dict)
        states = state_vector(self._last_obs)
        for i in range(self.n_envs):
            self.replay_buffer.add(i, states[i], None)
            self._record_reset(self._last_obs, i)
        action_dim = int(np.prod(self.action_space.shape))
        self._latent = self.policy.world_model.rssm.initial(self.n_envs, self.device)
        self._prev_action = th.zeros(self.n_envs, action_dim, device=self.device)
        self._stream_obs = self._last_obs

    def _record_reset(self, obs: dict[str, np.ndarray], i: int) -> None:
        if self._task_goals is not None and not self._task_goals.declared:
            self._task_goals.record_reset({k: obs[k][i] for k in ("achieved_goal", "desired_goal")})

    def _act(self, obs: dict[str, np.ndarray], phases: list[str]) -> np.ndarray:
        """Actions in [-1, 1]: filter the latent with the new observation, then pi_G (Go) or pi_E (Explore)."""
        assert self._latent is not None and self._prev_action is not None
        policy = self.policy
        with th.no_grad():
            states, goals = policy.states_to_tensor(obs)
            self._latent = policy.filter(self._latent, self._prev_action, states)
            if self.num_timesteps < self.learning_starts:
                actions = self._rng.uniform(-1, 1, (self.n_envs, *self.action_space.shape)).astype(np.float32)
                return actions
            feat = self._latent.feat
            if all(p == "explore" for p in phases):
                return policy.actor_e.act(feat)[0].cpu().numpy()
            actions = policy.actor_g.act(feat, goals)[0]
            if "explore" in phases:
                explore = th.as_tensor([p == "explore" for p in phases], device=self.device).unsqueeze(-1)
                actions = th.where(explore, policy.actor_e.act(feat)[0], actions)
        return actions.cpu().numpy()

    def _store(
        self, new_obs: dict[str, np.ndarray], scaled: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
    ) -> None:
        """Append the step to the replay streams (executed actions) and restart streams at physical resets."""
        assert self._prev_action is not None and self._latent is not None and self.env is not None
        states = state_vector(new_obs)
        executed = scaled.copy()
        for i, info in enumerate(infos):
            if "executed_action" in info:
                executed[i] = self.policy.scale_action(np.asarray(info["executed_action"], dtype=np.float32))
        self._prev_action = th.as_tensor(executed, device=self.device)
        for i in range(self.n_envs):
            if not dones[i]:
                self.replay_buffer.add(i, states[i], executed[i])
                continue
            terminal = infos[i].get("terminal_observation")
            if terminal is not None:
                self.replay_buffer.add(i, state_vector(terminal), executed[i])
            physical = self._base_vec_env().reset_infos[i].get("physical_reset", True)
            if physical:
                self.replay_buffer.add(i, states[i], None)
                self._record_reset(new_obs, i)
                self._prev_action[i] = 0.0
                self._latent.deter[i] = 0.0
                self._latent.stoch[i] = 0.0

    def collect_rollouts(self, callback: BaseCallback, n_steps: int, log_interval: int | None) -> bool:
        """Step the envs ``n_steps`` times (one training interval); False when a callback stops training.

        :param callback: the learn callback.
        :param n_steps: vectorised env steps.
        :param log_interval: dump the logs every ``log_interval`` finished episodes.
        :return: whether to continue.
        """
        env = self.env
        assert env is not None and self._last_obs is not None
        callback.on_rollout_start()
        for _ in range(n_steps):
            obs = self._last_obs
            assert isinstance(obs, dict)
            scaled = self._act(obs, self._phases())
            actions = self.policy.unscale_action(scaled)
            new_obs, rewards, dones, infos = env.step(actions)
            if self._planned_envs and dones.any():
                self._answer_goal_requests(new_obs, dones)  # type: ignore[arg-type]
            self.num_timesteps += env.num_envs
            callback.update_locals(locals())
            if not callback.on_step():
                self._last_obs = new_obs  # type: ignore[assignment]
                self._store(new_obs, scaled, dones, infos)  # type: ignore[arg-type]
                self._stream_obs = new_obs
                callback.on_rollout_end()
                return False
            self._update_info_buffer(infos, dones)
            self._store(new_obs, scaled, dones, infos)  # type: ignore[arg-type]
            self._last_obs = self._stream_obs = new_obs  # type: ignore[assignment]
            self._update_current_progress_remaining(self.num_timesteps, self._total_timesteps)
            for done in dones:
                if done:
                    self._episode_num += 1
                    if log_interval is not None and self._episode_num % log_interval == 0:
                        self.dump_logs()
        callback.on_rollout_end()
        return True

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

    def _imagine(self, start: LatentState, goals: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """Roll pi_G (toward ``goals``) and pi_E from the same starts through the world model, in one batch.

        Rows ``[:N]`` of the outputs follow pi_G, rows ``[N:]`` pi_E; each step is one RSSM prior step for both.

        :param start: flat imagination start states ``(N, ...)`` (detached).
        :param goals: symlog goals ``(N, G)`` of pi_G.
        :return: features ``(H + 1, 2N, F)``, actions ``(H, 2N, A)`` (``actions[t]`` is taken in state ``t``),
            entropies ``(H, 2N)``.
        """
        policy = self.policy
        rssm = policy.world_model.rssm
        n = goals.shape[0]
        latent = LatentState(*(th.cat([x, x]) for x in start))
        feats, actions, entropies = [latent.feat], [], []
        for _ in range(self.imagination_horizon):
            feat = latent.feat.detach()
            action_g, entropy_g = policy.actor_g.act(feat[:n], goals)
            action_e, entropy_e = policy.actor_e.act(feat[n:])
            action = th.cat([action_g, action_e])
            latent = rssm.img_step(latent, action)
            feats.append(latent.feat)
            actions.append(action)
            entropies.append(th.cat([entropy_g, entropy_e]))
        return th.stack(feats), th.stack(actions), th.stack(entropies)

    def _returns(
        self, feats: th.Tensor, rewards: th.Tensor, target: th.nn.Module, goals: th.Tensor | None
    ) -> th.Tensor:
        """Lambda-returns ``(H, N)`` of imagined states ``feats (H + 1, N, F)``, bootstrapped from a slow critic."""
        expand = None if goals is None else goals.unsqueeze(0).expand(feats.shape[0], *goals.shape)
        return lambda_returns(rewards, target(feats, expand), self.gamma, self.lambda_)

    def _actor_loss(self, returns: th.Tensor, entropies: th.Tensor) -> th.Tensor:
        """DreamerV2's dynamics-backpropagation objective: discounted lambda-returns plus the entropy bonus."""
        discount = self._discounts(returns)
        return -(discount * (returns + self.entropy_coef * entropies)).mean()

    def _critic_loss(
        self, critic: th.nn.Module, feats: th.Tensor, returns: th.Tensor, goals: th.Tensor | None
    ) -> th.Tensor:
        """Discounted regression of the critic on the (detached) lambda-returns of the imagined states."""
        expand = None if goals is None else goals.unsqueeze(0).expand(returns.shape[0], *goals.shape)
        prediction = critic(feats[:-1].detach(), expand)
        return (self._discounts(returns) * (prediction - returns.detach()).pow(2)).mean()

    def _discounts(self, returns: th.Tensor) -> th.Tensor:
        steps = returns.shape[0]
        return self.gamma ** th.arange(steps, device=returns.device, dtype=returns.dtype).unsqueeze(-1)

    def _goal_rewards(self, achieved: th.Tensor, goals: th.Tensor) -> th.Tensor:
        """pi_G's reward ``-D(achieved goal of s_{t+1}, g)`` from the decoded achieved goals ``(H + 1, N, G)`` of an
        imagined path: ``(H, N)``."""
        return -self.policy.distance(achieved[1:], goals.unsqueeze(0).expand(achieved.shape[0] - 1, *goals.shape))

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
        """World-model loss plus the Plan2Explore ensemble's on the same (detached) posteriors.

        The ensemble predicts the next stochastic state from (features, action), never across a stream start.

        :return: (summed loss, detached posteriors ``(T, B, ...)``, detached metrics).
        """
        policy = self.policy
        wm_loss, post, metrics = policy.world_model.loss(states, actions, is_first)
        feat = post.feat.detach()
        valid = (~is_first[1:]).to(feat.dtype)
        ensemble_loss = policy.ensemble.loss(feat[:-1], actions[1:], post.stoch[1:].detach(), valid)
        metrics = {**metrics, "world_model_loss": wm_loss.detach(), "ensemble_loss": ensemble_loss.detach()}
        return wm_loss + ensemble_loss, post.detach(), metrics

    def _imagination_losses(
        self, start: LatentState, goals: th.Tensor
    ) -> tuple[th.Tensor, tuple[th.Tensor, ...], dict[str, th.Tensor]]:
        """Actor losses of pi_G and pi_E from one batch of imagination starts (Sec. 3.3.2); runs with the world
        model, the distance and the ensemble frozen.

        pi_G is imagined from ``start`` toward ``goals`` with the reward ``-D``; pi_E from the same starts with the
        ensemble's disagreement; both learn by backpropagating lambda-returns through the model.

        :param start: imagination start states (flat batch, detached).
        :param goals: symlog goals of pi_G, one per start.
        :return: (summed actor loss, detached (pi_G features, pi_E features, pi_G returns, pi_E returns, pi_G's
            decoded achieved goals), metrics).
        """
        policy = self.policy
        n = goals.shape[0]
        feats, actions, entropies = self._imagine(start, goals)
        feats_g, feats_e = feats[:, :n], feats[:, n:]
        achieved = policy.world_model.decode_goal(feats_g)
        rewards_g = self._goal_rewards(achieved, goals)
        rewards_e = self.expl_reward_scale * policy.ensemble.disagreement(feats_e[:-1], actions[:, n:])
        returns_g = self._returns(feats_g, rewards_g, policy.critic_g_target, goals)
        returns_e = self._returns(feats_e, rewards_e, policy.critic_e_target, None)
        actor_g_loss = self._actor_loss(returns_g, entropies[:, :n])
        actor_e_loss = self._actor_loss(returns_e, entropies[:, n:])
        metrics = {
            "actor_g_loss": actor_g_loss,
            "actor_e_loss": actor_e_loss,
            "imagined_return_g": returns_g.mean(),
            "imagined_return_e": returns_e.mean(),
            "imagined_reward_e": rewards_e.mean(),
            "action_g_abs": actions[:, :n].abs().mean(),
            "entropy_g": entropies[:, :n].mean(),
        }
        imagined = tuple(x.detach() for x in (feats_g, feats_e, returns_g, returns_e, achieved))
        return actor_g_loss + actor_e_loss, imagined, {k: v.detach() for k, v in metrics.items()}

    def _learner_losses(
        self,
        imagined: tuple[th.Tensor, ...],
        goals: th.Tensor,
        groups: th.Tensor,
        replay_pairs: tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor] | None,
    ) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """Critic losses of V_G and V_E and the distance's, from the imagined trajectories of
        :meth:`_imagination_losses`.

        D is trained on pairs of the imagined pi_G trajectories' decoded achieved goals (LEXA / PEG) and, with
        ``replay_pairs``, on pairs of achieved goals of the replayed streams, in one unit (:attr:`distance_unit`).

        :param imagined: detached (pi_G features, pi_E features, pi_G returns, pi_E returns, pi_G's decoded achieved
            goals).
        :param goals: symlog goals of pi_G.
        :param groups: replayed sequence of each start (negatives of the distance come from other sequences).
        :param replay_pairs: (symlog earlier goals, symlog later goals, steps between them, 0/1 validity) of
            replayed pairs, or None.
        :return: (summed loss, detached metrics).
        """
        policy = self.policy
        feats_g, feats_e, returns_g, returns_e, imagined_goals = imagined
        critic_g_loss = self._critic_loss(policy.critic_g, feats_g, returns_g, goals)
        critic_e_loss = self._critic_loss(policy.critic_e, feats_e, returns_e, None)
        unit = self.distance_unit
        distance_loss = policy.distance.trajectory_loss(
            imagined_goals, self.distance_pairs, unit, self.distance_neg_fraction, groups=groups
        )
        if replay_pairs is not None:
            distance_loss = distance_loss + policy.distance.loss(*replay_pairs[:3], unit, replay_pairs[3])
        metrics = {"critic_g_loss": critic_g_loss, "critic_e_loss": critic_e_loss, "distance_loss": distance_loss}
        return critic_g_loss + critic_e_loss + distance_loss, {k: v.detach() for k, v in metrics.items()}

    def _replay_pairs(self) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        """Pairs of replayed achieved goals for the distance: ``distance_pairs`` pairs of one stream up to
        :attr:`distance_unit` steps apart, plus ``distance_neg_fraction`` of them as negatives (two states drawn
        independently from the whole buffer, target ``distance_unit + 1`` steps: beyond every positive).

        :return: (symlog earlier goals, symlog later goals, steps between them, 0/1 validity).
        """
        unit = self.distance_unit
        first, later, steps, valid = self.replay_buffer.sample_pairs(self.distance_pairs, unit, self._rng)
        n_neg = int(round(self.distance_neg_fraction * self.distance_pairs))
        if n_neg > 0:
            goal_dim = self.policy.goal_dim
            first = np.concatenate([first, self.replay_buffer.sample_states(n_neg, self._rng)[:, -goal_dim:]])
            later = np.concatenate([later, self.replay_buffer.sample_states(n_neg, self._rng)[:, -goal_dim:]])
            steps = np.concatenate([steps, np.full(n_neg, unit + 1)])
            valid = np.concatenate([valid, np.ones(n_neg, dtype=bool)])
        as_tensor = lambda x, dtype=None: th.as_tensor(x, dtype=dtype, device=self.device)  # noqa: E731
        return symlog(as_tensor(first)), symlog(as_tensor(later)), as_tensor(steps), as_tensor(valid, th.float32)

    def _autocast(self, world_model: bool = False) -> AbstractContextManager[Any]:
        """bfloat16 matrix products (``torch.autocast``) with ``mixed_precision``, as PEG's ``precision: 16``; the
        distributions, losses and the GRU's normalisation stay in float32.

        :param world_model: for the world model's step (filtering the replayed sequences), which stays in float32 on
            a CPU: its products are small (one per sequence step), and bfloat16's casts cost more there than they
            save (``scripts/bench_morefree.py --profile``).
        """
        if not self._uses_bfloat16() or (world_model and self.device.type == "cpu"):
            return nullcontext()
        return th.autocast(self.device.type, dtype=th.bfloat16)

    def _uses_bfloat16(self) -> bool:
        """``mixed_precision`` where the device computes bfloat16 natively; decided once per process (and per load),
        with one warning where ``mixed_precision`` asks for bfloat16 on a device that would emulate it."""
        if getattr(self, "_bfloat16", None) is None:
            self._bfloat16 = self.mixed_precision and native_bfloat16(self.device)
            if self.mixed_precision and not self._bfloat16:
                where = describe_cpu() if self.device.type == "cpu" else str(self.device)
                warnings.warn(
                    f"MoReFree: mixed_precision=True, but {where} has no native bfloat16 (a CPU needs AVX512-BF16 or "
                    "AMX): training in float32, which is faster there; set mixed_precision=False to silence this",
                    stacklevel=2,
                )
        return bool(self._bfloat16)

    def _loss_functions(self) -> dict[str, Callable[..., Any]]:
        """The three loss computations of a training step, compiled with ``torch.compile`` when
        ``compile_train_step`` (compiled once, on the first training step of the process)."""
        names = ("_model_losses", "_imagination_losses", "_learner_losses")
        if not self.compile_train_step:
            return {name: getattr(self, name) for name in names}
        if self._compiled is None:
            if self.verbose >= 1:
                print(
                    "MoReFree: compiling the training step with torch.compile (compile_train_step=True). The first "
                    "training step waits for it, once per model in this process: minutes on a CPU (about 2-3 for the "
                    "CPU presets, up to 20 on one core at the thesis sizes; torch's cache shortens later compiles of "
                    "the same sizes), then a step takes about half the time; compile_train_step=False skips it"
                )
            # fallback_random: random numbers come from PyTorch's own generator (as in the plain step) instead of
            # inductor's in-kernel ones, which cost about 60 ns a sample on a CPU core
            options = {"fallback_random": True}
            self._compiled = {name: th.compile(getattr(self, name), options=options) for name in names}
        return self._compiled

    def train(self) -> None:
        """One training step (Algorithm 2, lines 10-14): world model and ensemble, then pi_G, pi_E and D.

        Two backward passes per step: the world model with the ensemble, then every learner trained in imagination
        (their parameters are disjoint; the world model, D and the ensemble are frozen while imagining).
        """
        policy = self.policy
        policy.set_training_mode(True)
        losses = self._loss_functions()
        states_np, actions_np, first_np = self.replay_buffer.sample(self.batch_size, self.batch_length, self._rng)
        states = th.as_tensor(states_np, device=self.device)
        actions = th.as_tensor(actions_np, device=self.device)
        is_first = th.as_tensor(first_np, device=self.device)

        with record_function("morefree.world_model"), self._autocast(world_model=True):
            model_loss, post, metrics = losses["_model_losses"](states, actions, is_first)
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
        replay_pairs = self._replay_pairs() if self.distance_on_replay else None
        frozen_models = frozen(policy.world_model, policy.distance, policy.ensemble)
        with record_function("morefree.imagination"), frozen_models, self._autocast():
            actor_loss, imagined, actor_metrics = losses["_imagination_losses"](start, goals)
        with record_function("morefree.learners"), self._autocast():
            learner_loss, learner_metrics = losses["_learner_losses"](imagined, goals, groups, replay_pairs)
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

    # --- learn ----------------------------------------------------------------------------------------------------
    def dump_logs(self) -> None:
        """Write the log data (SB3's public hook): episodes, returns, success, speed, the counters of the goal hooks."""
        time_elapsed = max((time.time_ns() - self.start_time) / 1e9, sys.float_info.epsilon)
        fps = int((self.num_timesteps - self._num_timesteps_at_start) / time_elapsed)
        self.logger.record("time/episodes", self._episode_num, exclude="tensorboard")
        if len(self.ep_info_buffer) > 0 and len(self.ep_info_buffer[0]) > 0:
            self.logger.record("rollout/ep_rew_mean", safe_mean([ep["r"] for ep in self.ep_info_buffer]))
            self.logger.record("rollout/ep_len_mean", safe_mean([ep["l"] for ep in self.ep_info_buffer]))
        if len(self.ep_success_buffer) > 0:
            self.logger.record("rollout/success_rate", safe_mean(self.ep_success_buffer))
        self.logger.record("time/fps", fps)
        self.logger.record("time/time_elapsed", int(time_elapsed), exclude="tensorboard")
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        if self._planned_envs and self.env is not None:
            counts = self.env.get_attr("planned_goal_counts", indices=self._planned_envs)
            self.logger.record("morefree/peg_goals_planned", sum(c["planned"] for c in counts))
            self.logger.record("morefree/peg_goals_fallback", sum(c["fallback"] for c in counts))
        self.logger.dump(step=self.num_timesteps)

    def learn(
        self: SelfMoReFree,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "MoReFree",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfMoReFree:
        warn_if_learning_never_starts(self, total_timesteps, reset_num_timesteps)
        total_timesteps, callback = self._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        callback.on_training_start(locals(), globals())
        threads = th.get_num_threads()
        if self.n_threads is not None:
            th.set_num_threads(self.n_threads)
        self._attach()
        if self._last_obs is not self._stream_obs or self._latent is None:
            self._start_streams()
        try:
            while self.num_timesteps < total_timesteps:
                remaining = -(-(total_timesteps - self.num_timesteps) // self.n_envs)
                if not self.collect_rollouts(callback, min(self.train_ratio, remaining), log_interval):
                    break
                if self.num_timesteps > self.learning_starts and self.replay_buffer.can_sample(self.batch_length):
                    self.train()
        finally:
            self._detach()
            th.set_num_threads(threads)
        self.dump_logs()
        callback.on_training_end()
        return self
