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
}

#: preset run when ``sb3-gcrl compare`` gets no arguments at all
DEFAULT_PRESET = "quick"
