"""Probes of the world-model MoReFree agent's pieces against ground truth (why it learns, or does not), and the
callback that logs them during training.

The probes stand in :mod:`sb3_gcrl.morefree.probes`, one module a family, each computed on the agent's own replay
data or in its task, through the agent's public interface (:meth:`~sb3_gcrl.morefree.MoReFree.imagine`,
:meth:`~sb3_gcrl.morefree.MoReFree.goal_rewards`, :meth:`~sb3_gcrl.morefree.MoReFree.lambda_returns`, the goal
draws with an explicit generator):

* the distance (:mod:`~sb3_gcrl.morefree.probes.distance`): :func:`distance_rank_correlation` (D against the
  env's true distance, the shortest path through a maze where the env defines it) and
  :func:`distance_minimum_error` (how far from the goal D puts its minimum);
* the learners (:mod:`~sb3_gcrl.morefree.probes.learners`): :func:`goal_sensitivity` (does pi_G's action depend
  on its goal?) and :func:`critic_calibration` (does V_G follow the lambda-returns it regresses?);
* the task (:mod:`~sb3_gcrl.morefree.probes.rollouts`): :func:`evaluation_rollouts`, pi_G's evaluation episodes in
  the real env beside the world model's prediction of the same episodes (is a failure the model's, which thinks
  pi_G gets there, or the learners', whose pi_G fails in the model too?);
* goal holding (:mod:`~sb3_gcrl.morefree.probes.holding`): :func:`goal_holding` and :func:`objective_gaps` (does
  pi_G, started at its goal, stay there, and does its own objective ask it to?).

:func:`diagnose` runs them all; :class:`MoReFreeDiagnosticsCallback` logs them under ``diagnostics/`` during
training (and prints them with ``verbose=1``, a line :func:`parse_diagnostics` reads back);
``scripts/diagnose_morefree.py`` prints them for a run or a saved model.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_gcrl.envs.tasks import find_task
from sb3_gcrl.morefree.probes.distance import (
    VecEnvGeometry,
    distance_minimum_error,
    distance_rank_correlation,
    true_distance,
)
from sb3_gcrl.morefree.probes.holding import HOLD_FIGURES, goal_holding, objective_gaps
from sb3_gcrl.morefree.probes.learners import critic_calibration, goal_sensitivity, untrained_goal_sensitivity
from sb3_gcrl.morefree.probes.rollouts import ROLLOUT_FIGURES, evaluation_rollouts

if TYPE_CHECKING:
    from sb3_gcrl.morefree.morefree import MoReFree

__all__ = [
    "HOLD_FIGURES",
    "LINE_PREFIX",
    "ROLLOUT_FIGURES",
    "MoReFreeDiagnosticsCallback",
    "VecEnvGeometry",
    "critic_calibration",
    "diagnose",
    "distance_minimum_error",
    "distance_rank_correlation",
    "evaluation_rollouts",
    "format_diagnostics",
    "goal_holding",
    "goal_sensitivity",
    "objective_gaps",
    "parse_diagnostics",
    "true_distance",
    "untrained_goal_sensitivity",
]


def diagnose(
    model: MoReFree, env: Any, n: int = 512, seed: int = 0, rollout_envs: Sequence[gym.Env] = ()
) -> dict[str, float]:
    """All probes: ``distance_rank_correlation`` (replayed goals), ``distance_rank_correlation_task`` (evaluation
    goals), ``distance_minimum_error`` (evaluation goals, ``8 n`` candidate states), ``goal_sensitivity``,
    ``goal_sensitivity_untrained``, ``critic_calibration`` (see the module docstring), and with ``rollout_envs`` the
    figures of :func:`evaluation_rollouts` (one episode per env) and, for a task of this package that states its
    success radius, those of :func:`goal_holding`.

    The probes leave the agent's random numbers as they found them: the goals they draw as the agent does come from
    a generator of ``seed`` passed to them (not the agent's), and PyTorch's state is put back afterwards, so that a
    run trains the same with and without probes.

    :param model: the agent.
    :param env: the env whose geometry is the ground truth (see :func:`true_distance`).
    :param n: states (and imagination starts) per probe.
    :param seed: seed of the probes' draws.
    :param rollout_envs: evaluation envs of :func:`evaluation_rollouts`, one episode each (none: no rollouts).
    :return: the figures by name.
    """
    devices = [model.device] if model.device.type == "cuda" else []
    goal_rng = np.random.default_rng(seed)
    with th.random.fork_rng(devices=devices):
        figures = {
            "distance_rank_correlation": distance_rank_correlation(model, env, n, seed=seed),
            "distance_rank_correlation_task": distance_rank_correlation(
                model, env, n, seed=seed, goals="evaluation", goal_rng=goal_rng
            ),
            "distance_minimum_error": distance_minimum_error(model, env, 8 * n, seed=seed, goal_rng=goal_rng),
            "goal_sensitivity": goal_sensitivity(model, n, seed),
            "goal_sensitivity_untrained": untrained_goal_sensitivity(model, n, seed),
            "critic_calibration": critic_calibration(model, n, seed, goal_rng=goal_rng),
        }
        if rollout_envs:
            figures.update(evaluation_rollouts(model, rollout_envs, seed=seed * len(rollout_envs)))
            task = find_task(rollout_envs[0])
            if task is not None and task.success_threshold is not None:
                figures.update(goal_holding(model, env, task.success_threshold, seed=seed, goal_rng=goal_rng))
    return figures


#: what starts the line :class:`MoReFreeDiagnosticsCallback` prints with ``verbose=1`` (read back by
#: :func:`parse_diagnostics`, e.g. from a comparison run's ``train.log``)
LINE_PREFIX = "diagnostics at "


def format_diagnostics(step: int, figures: dict[str, float]) -> str:
    """The printed line of one probe: ``diagnostics at <step>: <name> <value>, ...``."""
    return f"{LINE_PREFIX}{step}: " + ", ".join(f"{name} {value:.4f}" for name, value in figures.items())


def parse_diagnostics(text: str) -> list[tuple[int, dict[str, float]]]:
    """The probes printed in ``text`` (lines of :func:`format_diagnostics`), in order."""
    probes = []
    for line in text.splitlines():
        if not line.startswith(LINE_PREFIX):
            continue
        step, _, rest = line[len(LINE_PREFIX) :].partition(": ")
        pairs = (item.rsplit(" ", 1) for item in rest.split(", ") if item)
        probes.append((int(step), {name: float(value) for name, value in pairs}))
    return probes


class MoReFreeDiagnosticsCallback(BaseCallback):
    """Log :func:`diagnose` under ``diagnostics/`` every ``diagnose_freq`` env steps once training has started.

    :param diagnose_freq: env steps between probes.
    :param n: states (and imagination starts) per probe.
    :param rollout_episodes: evaluation episodes of :func:`evaluation_rollouts` per probe (0: none).
    :param rollout_env: the env of those episodes: an env id or a function that makes the env; ``None``: the
        training env's registered env (``gym.make`` of its spec without the wrappers added around it, so with its
        registered time limit: the evaluation episode of the task).
    :param verbose: print the figures when >= 1.
    """

    def __init__(
        self,
        diagnose_freq: int = 5000,
        n: int = 512,
        rollout_episodes: int = 10,
        rollout_env: str | Callable[[], gym.Env] | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if diagnose_freq < 1 or n < 2 or rollout_episodes < 0:
            raise ValueError(
                f"diagnose_freq must be >= 1, n >= 2 and rollout_episodes >= 0, got {diagnose_freq}, {n}, "
                f"{rollout_episodes}"
            )
        if rollout_env is not None and not (isinstance(rollout_env, str) or callable(rollout_env)):
            raise TypeError(f"rollout_env must be an env id, a function that makes an env or None, got {rollout_env!r}")
        self.diagnose_freq, self.n, self.rollout_episodes = diagnose_freq, n, rollout_episodes
        self.rollout_env = rollout_env
        self._next = diagnose_freq
        #: (timestep, figures) of every probe so far
        self.history: list[tuple[int, dict[str, float]]] = []
        self._geometry: VecEnvGeometry | None = None
        self._rollout_envs: list[gym.Env] = []

    def _make_rollout_env(self) -> gym.Env:
        if isinstance(self.rollout_env, str):
            return gym.make(self.rollout_env)
        if self.rollout_env is not None:
            return self.rollout_env()
        spec = self.training_env.get_attr("spec", indices=[0])[0]
        if spec is None:
            raise ValueError(
                "MoReFreeDiagnosticsCallback: the training env was not made by gym.make, so its evaluation env is "
                "unknown; pass rollout_env (an env id or a function that makes the env) or rollout_episodes=0"
            )
        return gym.make(dataclasses.replace(spec, additional_wrappers=()))

    def _init_callback(self) -> None:
        if not self.rollout_episodes:
            return
        self._rollout_envs = [self._make_rollout_env() for _ in range(self.rollout_episodes)]
        space = self._rollout_envs[0].observation_space
        if space != self.model.observation_space:
            raise ValueError(
                f"MoReFreeDiagnosticsCallback: the rollout env's observation space {space} is not the agent's "
                f"{self.model.observation_space}; pass rollout_env (an env id or a function that makes the env)"
            )

    def _on_training_start(self) -> None:
        # on the grid of diagnose_freq from the run's start: a run resumed from a checkpoint probes where an
        # uninterrupted one does (not again at its first step)
        self._next = (self.num_timesteps // self.diagnose_freq + 1) * self.diagnose_freq

    def _on_step(self) -> bool:
        model = self.model
        if self.num_timesteps < self._next:
            return True
        self._next = (self.num_timesteps // self.diagnose_freq + 1) * self.diagnose_freq
        if getattr(model, "_n_updates", 0) == 0:
            return True
        if self._geometry is None:
            self._geometry = VecEnvGeometry(self.training_env)
        figures = diagnose(
            model,  # type: ignore[arg-type]
            self._geometry,
            self.n,
            seed=self.num_timesteps // self.diagnose_freq - 1,  # the probe's place on the grid, resumed or not
            rollout_envs=self._rollout_envs,
        )
        self.history.append((self.num_timesteps, figures))
        for name, value in figures.items():
            self.logger.record(f"diagnostics/{name}", value)
        if self.verbose >= 1:
            print(format_diagnostics(self.num_timesteps, figures), flush=True)
        return True

    def _on_training_end(self) -> None:
        for env in self._rollout_envs:
            env.close()
        self._rollout_envs = []
