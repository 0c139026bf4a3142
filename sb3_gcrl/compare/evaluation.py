"""Evaluation schedule of a comparison run: deterministic episodes on a separate env every ``eval_freq`` steps."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv, sync_envs_normalization

#: columns of ``evaluations.csv``, one row per evaluation
EVALUATION_COLUMNS: tuple[str, ...] = (
    "timesteps",
    "num_timesteps",
    "mean_return",
    "std_return",
    "mean_length",
    "success_rate",
    "wall_time_s",
    "eval_memory_is_ec",
)


class EvaluationRecorder(BaseCallback):
    """Evaluate the agent before training and every ``eval_freq`` env steps (see :meth:`evaluate_final`).

    Unlike SB3's ``EvalCallback`` (which counts callback calls, i.e. ``eval_freq * n_envs`` env steps), the
    schedule here is in env steps, so runs with different ``n_envs`` are evaluated at the same points and
    their curves can be averaged. Each row is keyed by the scheduled step (``timesteps`` = k * ``eval_freq``);
    ``num_timesteps`` is the step count at which the evaluation actually ran (larger by < ``n_envs``).

    Success is the mean of ``info["is_success"]`` at the end of each episode when the env reports it
    (gymnasium-robotics convention), else NaN; returns are the Monitor episode returns. For two-memory (2M)
    agents, ``eval_memory_is_ec`` records which memory the evaluation used (1 = episodic control; Eq. 5.6),
    the data of Fig. 5.6's top row; NaN for other agents.

    :param eval_env: evaluation env, built like the training env (same wrappers) but separate.
    :param eval_freq: env steps between evaluations.
    :param n_eval_episodes: episodes per evaluation.
    :param deterministic: deterministic actions (``predict(..., deterministic=True)``).
    :param report_progress: called with the number of env steps done since its previous call (progress bars).
    :param progress_every: env steps between two ``report_progress`` calls.
    :param verbose: 1 prints one line per evaluation.
    """

    def __init__(
        self,
        eval_env: VecEnv,
        eval_freq: int,
        n_eval_episodes: int = 5,
        deterministic: bool = True,
        report_progress: Callable[[int], None] | None = None,
        progress_every: int = 100,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if eval_freq < 1:
            raise ValueError(f"eval_freq must be >= 1 env step, got {eval_freq}")
        if n_eval_episodes < 1:
            raise ValueError(f"n_eval_episodes must be >= 1, got {n_eval_episodes}")
        self.eval_env = eval_env
        self.eval_freq = eval_freq
        self.n_eval_episodes = n_eval_episodes
        self.deterministic = deterministic
        self.report_progress = report_progress
        self.progress_every = max(1, progress_every)
        self.records: list[dict[str, float]] = []
        self._next_eval = 0
        self._reported_steps = 0
        self._start_time = 0.0
        self._success_buffer: list[float] = []

    def resume(self, records: list[dict[str, float]]) -> None:
        """Continue a run from a checkpoint: ``records`` are its evaluations up to the checkpoint, and the schedule
        goes on after the checkpoint's step (no evaluation at the start; ``wall_time_s`` goes on from the last).

        :param records: the evaluation rows the run had when the checkpoint was saved (the evaluation at the
            checkpoint's step included, if one was due).
        """
        self.records = [dict(record) for record in records]

    def _on_training_start(self) -> None:
        self._start_time = time.perf_counter()
        if self.records:  # resumed (:meth:`resume`)
            self._start_time -= self.records[-1]["wall_time_s"]
            self._next_eval = (self.num_timesteps // self.eval_freq + 1) * self.eval_freq
            return
        self._next_eval = 0
        self._evaluate(scheduled=0)
        self._next_eval = self.eval_freq

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next_eval:
            # with n_envs > 1 a step can cross the schedule; evaluate once, at the latest scheduled point
            scheduled = (self.num_timesteps // self.eval_freq) * self.eval_freq
            self._evaluate(scheduled)
            self._next_eval = scheduled + self.eval_freq
        self._maybe_report_progress()
        return True

    def _on_training_end(self) -> None:
        self._maybe_report_progress(force=True)

    def evaluate_final(self) -> None:
        """Evaluate at the last step if the schedule did not land on it (budget not a multiple of ``eval_freq``).

        Called by :func:`~sb3_gcrl.compare.run.execute_run` after a *completed* ``learn`` (not from
        ``on_training_end``, which RL-Zoo also calls after a crash, and twice).
        """
        if self.records and self.records[-1]["num_timesteps"] < self.num_timesteps:
            self._evaluate(scheduled=self.num_timesteps)

    def _maybe_report_progress(self, force: bool = False) -> None:
        if self.report_progress is None:
            return
        delta = self.num_timesteps - self._reported_steps
        if delta > 0 and (force or delta >= self.progress_every):
            self.report_progress(delta)
            self._reported_steps = self.num_timesteps

    def _log_success(self, locals_: dict[str, Any], globals_: dict[str, Any]) -> None:
        if locals_["done"]:
            success = locals_["info"].get("is_success")
            if success is not None:
                self._success_buffer.append(float(success))

    def _evaluate(self, scheduled: int) -> None:
        sync_envs_normalization(self.training_env, self.eval_env)
        self._success_buffer = []
        returns, lengths = evaluate_policy(
            self.model,
            self.eval_env,
            n_eval_episodes=self.n_eval_episodes,
            deterministic=self.deterministic,
            return_episode_rewards=True,
            callback=self._log_success,
        )
        success = float(np.mean(self._success_buffer)) if self._success_buffer else math.nan
        evaluation_memory = getattr(self.model.policy, "evaluation_memory", None)
        memory_is_ec = math.nan
        if callable(evaluation_memory):  # 2M agents (sb3_gcrl.two_memory, sb3_gcrl.tabular)
            from sb3_gcrl.two_memory.schedules import EPISODIC

            memory_is_ec = float(evaluation_memory() == EPISODIC)
        record = {
            "timesteps": int(scheduled),
            "num_timesteps": int(self.num_timesteps),
            "mean_return": float(np.mean(returns)),
            "std_return": float(np.std(returns)),
            "mean_length": float(np.mean(lengths)),
            "success_rate": success,
            "wall_time_s": time.perf_counter() - self._start_time,
            "eval_memory_is_ec": memory_is_ec,
        }
        self.records.append(record)
        self.logger.record("compare/mean_return", record["mean_return"])
        if not math.isnan(success):
            self.logger.record("compare/success_rate", success)
        if self.verbose >= 1:
            print(
                f"eval@{scheduled}: return {record['mean_return']:.3f} +/- {record['std_return']:.3f}, "
                f"success {success:.2f}, length {record['mean_length']:.1f}"
            )
