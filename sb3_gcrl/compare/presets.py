"""Named comparisons (``sb3-gcrl compare --preset NAME``) with budgets that fit a small CPU machine."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Preset:
    """A ready-made comparison; every field can be overridden on the command line.

    :param description: one line for ``--list-presets`` and the report.
    :param methods: method specs (see :mod:`sb3_gcrl.compare.methods`).
    :param envs: gymnasium ids.
    :param seeds: run seeds.
    :param n_timesteps: training budget per run (env steps).
    :param eval_freq: env steps between evaluations.
    :param n_eval_episodes: deterministic episodes per evaluation.
    :param hyperparams: overrides applied to every method.
    :param env_kwargs: env constructor arguments for every env.
    :param metric: metric of the table and plots (``auto``, ``success_rate``, ``mean_return``).
    :param thesis: the thesis figure/table the preset mirrors, and how its budget compares.
    """

    description: str
    methods: tuple[str, ...]
    envs: tuple[str, ...]
    seeds: tuple[int, ...]
    n_timesteps: int
    eval_freq: int
    n_eval_episodes: int = 5
    hyperparams: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    metric: str = "auto"
    thesis: str = ""


PRESETS: dict[str, Preset] = {
    "quick": Preset(
        description="CEC vs SAC on GrowingTree (sparse reward, 1-D): episodic control solves it in a few "
        "thousand steps, SAC usually not at this budget",
        methods=("cec", "sac"),
        envs=("GCRL/GrowingTree-v0",),
        seeds=(0, 1, 2),
        n_timesteps=5_000,
        eval_freq=500,
        n_eval_episodes=5,
        thesis="Ch. 4 toy example (Table 4.3): the authors' notebook solves it with CEC after 2-4k steps",
    ),
    "ch3": Preset(
        description="Reset-free PointUMaze: episodic oracle vs naive reset-free vs MoReFree (SAC + HER)",
        methods=(
            "oracle=sac:reset_free_pointumaze_oracle",
            "naive=sac:reset_free_pointumaze_naive",
            "morefree=sac:reset_free_pointumaze_morefree",
        ),
        envs=("GCRL/PointUMazeGoal-v0",),
        seeds=(0, 1, 2),
        n_timesteps=50_000,
        eval_freq=5_000,
        n_eval_episodes=5,
        thesis="Fig. 3.4 (PointUMaze panel) at 5% of the thesis's 1e6 steps, model-free port of MoReFree",
    ),
    "ch4": Preset(
        description="CEC vs SAC on the sparse-reward navigation and MountainCar tasks of Ch. 4",
        methods=("cec", "sac"),
        envs=("GCRL/PointUMaze-v0", "GCRL/Point4Rooms-v0", "GCRL/SparseMountainCarContinuous-v0"),
        seeds=(0, 1, 2),
        n_timesteps=20_000,
        eval_freq=2_000,
        n_eval_episodes=5,
        thesis="Figs. 4.3-4.4 at 20% of the thesis's 1e5 steps and 3 of its 5 seeds",
    ),
    "ch5": Preset(
        description="Tabular 2M vs Q-learning vs episodic control on the stochastic WindyGrid",
        methods=("tabular_2m", "tabular_q", "tabular_ec"),
        envs=("GCRL/WindyGrid-v0",),
        seeds=(0, 1, 2),
        n_timesteps=50_000,
        eval_freq=2_500,
        n_eval_episodes=5,
        metric="mean_return",
        thesis="Fig. 5.5 (left) at 25% of the authors' 2e5 steps; memory-choice panel as Fig. 5.6's top row",
    ),
    "ch5-minatar": Preset(
        description="2M (TwoMemoryDQN) vs DQN vs MFEC on MinAtar Breakout",
        methods=("two_memory_dqn", "dqn=dqn:dqn_minatar", "mfec"),
        envs=("MinAtar/Breakout-v1",),
        seeds=(0, 1, 2),
        n_timesteps=100_000,
        eval_freq=10_000,
        n_eval_episodes=5,
        env_kwargs={"sticky_action_prob": 0.2},  # the authors' Breakout setting (REFERENCE.md)
        thesis="Fig. 5.6 (Breakout) at 3% of the thesis's 3e6 steps, sticky actions 0.2 as the authors",
    ),
}

#: preset run when ``sb3-gcrl compare`` gets no arguments at all
DEFAULT_PRESET = "quick"
