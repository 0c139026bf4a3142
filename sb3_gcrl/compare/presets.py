"""Named comparisons (``sb3-gcrl compare --preset NAME``) with budgets that fit a small CPU machine."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sb3_gcrl.compare.comparison import ComparisonResult


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

    def compare_kwargs(self, **overrides: Any) -> dict[str, Any]:
        """Keyword arguments of :func:`~sb3_gcrl.compare.comparison.compare` for this preset.

        :param overrides: values that replace the preset's (``methods``, ``envs``, ``seeds``, ``n_timesteps``,
            ``eval_freq``, ``n_eval_episodes``, ``metric``, ``title``) or add to it (``hyperparams`` and
            ``env_kwargs`` are merged over the preset's); ``None`` keeps the preset's value. Any other
            :func:`~sb3_gcrl.compare.comparison.compare` argument (``output``, ``n_workers``...) is passed through.
        :return: the arguments, ready for ``compare(**kwargs)``.
        """
        kwargs: dict[str, Any] = {
            "methods": list(self.methods),
            "envs": list(self.envs),
            "seeds": list(self.seeds),
            "n_timesteps": self.n_timesteps,
            "eval_freq": self.eval_freq,
            "n_eval_episodes": self.n_eval_episodes,
            "metric": self.metric,
            "title": self.description,
        }
        for key in ("hyperparams", "env_kwargs"):
            kwargs[key] = {**getattr(self, key), **(overrides.pop(key, None) or {})}
        kwargs.update({key: value for key, value in overrides.items() if value is not None})
        return kwargs


def variant_methods(algo: str, names: tuple[str, ...], default: str | None = None) -> tuple[str, ...]:
    """Method specs ``NAME=ALGO@NAME`` for variants of one algorithm's sections, labelled by variant.

    :param algo: algorithm of every method.
    :param names: the variants, which also label the methods.
    :param default: the name that stands for the env's default section (``NAME=ALGO``), if one of ``names``.
    :return: the method specs.
    """
    return tuple(f"{name}={algo}" if name == default else f"{name}={algo}@{name}" for name in names)


#: MoReFree (world model), reset-free PEG (the same agent, alpha = 0) and MoReFree-SAC (the model-free port) on a
#: reset-free task (the default sections of ``morefree.yml``, its CPU presets, and of ``sac.yml``), labelled so that
#: the two MoReFree agents are never confused
WORLD_MODEL_METHODS = ("morefree_world_model=morefree", "peg_world_model=morefree@peg", "morefree_sac_port=sac")
#: MoReFree whose imagination trains "stay here" goals (the ``own_goal`` variant of ``morefree.yml``: not the thesis,
#: measured beside it because the thesis's agent loses the goal it reaches; docs/morefree.md)
OWN_GOAL_METHOD = "morefree_own_goal=morefree@own_goal"
#: Ch. 3's reset-free baselines IBC, MEDAL and R3L, labelled by algorithm: their default sections (IBC's CPU sizes,
#: ``ibc.yml``: 2 x 256 networks and batch 256 instead of the official 3 x 512 and 512 of ``ibc_thesis.yml``, which
#: train at about 10 env steps/s on one core; MEDAL and R3L as configured, already 2 x 256 and batch 256)
BASELINE_METHODS = ("ibc=ibc", "medal=medal", "r3l=r3l")
#: Ch. 3 methods of Fig. 3.4 and the ablations of Sec. 3.5.3: MoReFree-SAC (the model-free port, ``morefree``: the
#: default section of ``sac.yml``) and its baselines and ablations (variants of ``sac.yml``)
CH3_METHODS = ("oracle", "naive", "goexplore", "morefree")
CH3_ABLATIONS = ("wo_bf", "wo_relabel", "alpha1")
#: Ch. 6 post-exploration settings (variants ``off``/``on`` of ``imgep.yml``/``ddpg.yml``; ``adaptive``, ours, is
#: their default section)
CH6_VARIANTS = ("off", "on", "adaptive")
#: MinAtar settings that are env constructor arguments (not RL-Zoo YAML keys): the authors' Breakout sticky-action
#: probability, and a time limit (MinAtar registers none; a greedy policy can otherwise keep an episode going forever)
MINATAR_BREAKOUT_ENV_KWARGS: dict[str, Any] = {"sticky_action_prob": 0.2, "max_episode_steps": 10_000}

PRESETS: dict[str, Preset] = {
    "quick": Preset(
        description="CEC vs SAC on GrowingTree (sparse reward, 1-D): episodic control solves it within about "
        "1,000 steps, SAC not at this budget",
        methods=("cec", "sac"),
        envs=("GCRL/GrowingTree-v0",),
        seeds=(0, 1, 2),
        n_timesteps=2_000,
        eval_freq=200,
        # GrowingTree starts at the same height with the same goal and both evaluation policies are greedy, so
        # every evaluation episode of a run is the same episode: one is exact
        n_eval_episodes=1,
        thesis="Ch. 4 toy example (Table 4.3): the authors' notebook solves it with CEC after 2-4k steps",
    ),
    "ch3": Preset(
        description="Reset-free PointUMaze: episodic oracle vs naive reset-free vs Go-Explore (alpha = 0) vs "
        "MoReFree-SAC (the model-free port)",
        methods=variant_methods("sac", CH3_METHODS, default="morefree"),
        envs=("GCRL/PointUMazeGoal-v0",),
        seeds=(0, 1, 2),
        n_timesteps=100_000,
        eval_freq=10_000,
        n_eval_episodes=10,
        thesis="Fig. 3.4-3.5 (PointUMaze panel) at 10% of the thesis's 1e6 steps, MoReFree-SAC",
    ),
    "ch3-ablations": Preset(
        description="Ablations of MoReFree-SAC (the model-free port) on reset-free PointUMaze: without "
        "Back-and-Forth, without task-relevant relabeling, only task goals (alpha = 1)",
        methods=variant_methods("sac", CH3_ABLATIONS),
        envs=("GCRL/PointUMazeGoal-v0",),
        seeds=(0, 1, 2),
        n_timesteps=100_000,
        eval_freq=10_000,
        n_eval_episodes=10,
        thesis="Sec. 3.5.3 ablations at 10% of the thesis's 1e6 steps, model-free port",
    ),
    "ch3-world-model": Preset(
        description="Reset-free PointUMaze: MoReFree (world model) vs reset-free PEG (the same agent, alpha = 0) vs "
        "MoReFree-SAC (the model-free port), equal env steps, CPU presets; beside them MoReFree's own_goal variant "
        "(not the thesis)",
        methods=(*WORLD_MODEL_METHODS, OWN_GOAL_METHOD),
        envs=("GCRL/PointUMazeGoal-v0",),
        seeds=(0, 1, 2),
        n_timesteps=20_000,
        eval_freq=2_000,
        n_eval_episodes=10,
        thesis="Fig. 3.4 (PointUMaze panel: MoReFree >= reset-free PEG, model-based ahead of model-free) at 2% of "
        "the thesis's 1e6 steps; the world-model agents' CPU presets take about 1 h of one core per 50k steps",
    ),
    "ch3-baselines": Preset(
        description="Reset-free PointUMaze: IBC, MEDAL and R3L beside MoReFree (world model), reset-free PEG and the "
        "model-free MoReFree port (SAC), equal env steps",
        methods=(*BASELINE_METHODS, *WORLD_MODEL_METHODS),
        envs=("GCRL/PointUMazeGoal-v0",),
        seeds=(0, 1, 2),
        n_timesteps=100_000,
        eval_freq=10_000,
        n_eval_episodes=10,
        thesis="Fig. 3.4 (PointUMaze panel: MoReFree > reset-free PEG > IBC/MEDAL/R3L) at 10% of the thesis's 1e6 "
        "steps",
    ),
    "ch3-baselines-tabletop": Preset(
        description="Reset-free Tabletop: IBC, MEDAL and R3L beside MoReFree (world model), reset-free PEG and the "
        "model-free MoReFree port (SAC), equal env steps",
        methods=(*BASELINE_METHODS, *WORLD_MODEL_METHODS),
        envs=("GCRL/Tabletop-v0",),
        seeds=(0, 1, 2),
        n_timesteps=100_000,
        eval_freq=10_000,
        n_eval_episodes=10,
        thesis="Fig. 3.4 (Tabletop panel) at 5% of the thesis's 2e6 steps",
    ),
    "ch4": Preset(
        description="CEC vs SAC on the sparse-reward navigation and MountainCar tasks of Ch. 4",
        methods=("cec", "sac"),
        envs=("GCRL/PointUMaze-v0", "GCRL/Point4Rooms-v0", "GCRL/SparseMountainCarContinuous-v0"),
        seeds=(0, 1, 2, 3, 4),
        n_timesteps=100_000,
        eval_freq=10_000,
        n_eval_episodes=5,
        thesis="Figs. 4.3-4.4 at the thesis's 1e5 steps and 5 seeds (authors: 5 episodes every 5,000 steps)",
    ),
    "ch4-navigation": Preset(
        description="CEC vs SAC vs EMAC on the four navigation tasks of Fig. 4.3 (Point4Rooms with its 0.5-reward "
        "sub-goals; PointGoal and CarGoal rebuilt from Safety-Gym)",
        methods=("cec", "sac", "emac"),
        envs=("GCRL/PointUMaze-v0", "GCRL/Point4RoomsSubgoals-v0", "GCRL/PointGoal-v0", "GCRL/CarGoal-v0"),
        seeds=(0, 1, 2, 3, 4),
        n_timesteps=100_000,
        eval_freq=10_000,
        n_eval_episodes=5,
        thesis="Fig. 4.3 (CEC ahead of SAC and EMAC on all four tasks) at the thesis's 1e5 steps and 5 seeds",
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
        methods=("2m=two_memory_dqn", "dqn", "mfec"),
        envs=("MinAtar/Breakout-v1",),
        seeds=(0, 1, 2),
        n_timesteps=100_000,
        eval_freq=10_000,
        n_eval_episodes=5,
        env_kwargs=MINATAR_BREAKOUT_ENV_KWARGS,
        thesis="Fig. 5.6 (Breakout) at 3% of the thesis's 3e6 steps, sticky actions 0.2 as the authors",
    ),
    "ch6": Preset(
        description="Tabular IMGEP on FourRooms: post-exploration off vs on (p_pe = 0.5) vs adaptive (ours)",
        methods=variant_methods("imgep", CH6_VARIANTS, default="adaptive"),
        envs=("GCRL/FourRoomsTabular-v0",),
        seeds=(0, 1, 2, 3, 4),
        n_timesteps=100_000,
        eval_freq=10_000,
        n_eval_episodes=5,
        thesis="Fig. 6.3-6.4 / Table 6.2 (FourRooms) at half the thesis's 2e5 steps; all-goals success, entropy "
        "and coverage recorded at each evaluation (all_goals.csv)",
    ),
    "ch6-deep": Preset(
        description="Deep IMGEP (DDPG + HER) on FetchReach: post-exploration off vs on vs adaptive (ours)",
        methods=variant_methods("ddpg", CH6_VARIANTS, default="adaptive"),
        envs=("FetchReach-v4",),
        seeds=(0, 1, 2, 3, 4),
        n_timesteps=10_000,
        eval_freq=2_000,
        n_eval_episodes=5,
        thesis="Fig. 6.5 (FetchReach) at 20% of the config's 5e4 steps; all-goals success over a goal grid at "
        "each evaluation (all_goals.csv)",
    ),
}


def smoke_test(of: str, n_timesteps: int, eval_freq: int, **changes: Any) -> Preset:
    """A one-seed, few-step version of preset ``of`` that checks its pipeline (a ``-quick`` preset).

    :param of: the full preset's name; everything not changed here is taken from it.
    :param n_timesteps: budget per run.
    :param eval_freq: env steps between evaluations.
    :param changes: other fields to change (e.g. fewer methods or envs).
    :return: the smoke-test preset.
    """
    full = PRESETS[of]
    return replace(
        full,
        description=f"Smoke test of the {of} preset (one seed, {n_timesteps:,} steps: no learning to speak of)",
        seeds=(0,),
        n_timesteps=n_timesteps,
        eval_freq=eval_freq,
        n_eval_episodes=changes.pop("n_eval_episodes", 1),
        thesis=f"pipeline check of the {of} preset",
        **changes,
    )


PRESETS.update(
    {
        "ch3-quick": smoke_test(
            "ch3", 600, 300, methods=variant_methods("sac", ("naive", "morefree"), default="morefree")
        ),
        "ch3-baselines-quick": smoke_test("ch3-baselines", 600, 300),
        "ch4-quick": smoke_test("ch4", 400, 200, envs=("GCRL/PointUMaze-v0",)),
        "ch4-navigation-quick": smoke_test("ch4-navigation", 400, 200, envs=("GCRL/PointGoal-v0", "GCRL/CarGoal-v0")),
        "ch5-quick": smoke_test("ch5", 2_000, 500, n_eval_episodes=2),
        "ch5-minatar-quick": smoke_test("ch5-minatar", 1_500, 500),
        "ch6-quick": smoke_test("ch6", 2_000, 1_000, n_eval_episodes=2),
    }
)

#: preset run when ``sb3-gcrl compare`` gets no arguments at all
DEFAULT_PRESET = "quick"

#: the authors' per-game sticky-action probability on MinAtar (repo yangzhao-666/2m; MinAtar's default is 0.1)
MINATAR_STICKY_ACTION_PROB: dict[str, float] = {
    "Breakout": 0.2,
    "Asterix": 0.1,
    "Seaquest": 0.05,
    "SpaceInvaders": 0.02,
    "Freeway": 0.01,
}


def minatar_env_kwargs(game: str) -> dict[str, Any]:
    """Env constructor arguments of a MinAtar game in the Ch. 5 presets: the authors' sticky actions, a time limit.

    :param game: ``Breakout``, ``Asterix``, ``Seaquest``, ``SpaceInvaders`` or ``Freeway``.
    :return: keyword arguments for ``gym.make("MinAtar/<game>-v1", ...)`` (``--env-kwargs``).
    :raises ValueError: for another game.
    """
    if game not in MINATAR_STICKY_ACTION_PROB:
        raise ValueError(f"Unknown MinAtar game {game!r}; choose one of {sorted(MINATAR_STICKY_ACTION_PROB)}")
    return {**MINATAR_BREAKOUT_ENV_KWARGS, "sticky_action_prob": MINATAR_STICKY_ACTION_PROB[game]}


def preset_labels(name: str) -> list[str]:
    """Labels of a preset's methods (as they appear in tables, plots and run folders)."""
    from sb3_gcrl.compare.methods import method_label

    return [method_label(spec) for spec in get_preset(name).methods]


def get_preset(name: str) -> Preset:
    """The preset called ``name``.

    :raises ValueError: unknown name; the message lists the presets.
    """
    if name not in PRESETS:
        raise ValueError(f"Unknown preset {name!r}; choose one of {sorted(PRESETS)} (sb3-gcrl compare --list-presets)")
    return PRESETS[name]


def select_methods(names: Sequence[str], labels: Sequence[str] | None = None) -> list[str]:
    """Method specs of the presets ``names`` whose labels are in ``labels`` (all of them when ``labels`` is None).

    :param names: preset names; their methods are pooled in order, and where two presets use one label for
        different specs the first preset's spec is kept.
    :param labels: labels to keep, in the order wanted.
    :return: the method specs.
    :raises ValueError: a label that none of the presets has; the message lists the valid labels.
    """
    from sb3_gcrl.compare.methods import method_label

    specs: dict[str, str] = {}
    for name in names:
        for spec in get_preset(name).methods:
            specs.setdefault(method_label(spec), spec)
    if labels is None:
        return list(specs.values())
    unknown = [label for label in labels if label not in specs]
    if unknown:
        raise ValueError(f"Unknown method(s) {unknown} for preset(s) {list(names)}; choose from {list(specs)}")
    return [specs[label] for label in labels]


def run_preset(name: str, output: str | Path, **overrides: Any) -> ComparisonResult:
    """Run a preset through :func:`~sb3_gcrl.compare.comparison.compare` (resumable like ``sb3-gcrl compare``).

    :param name: preset name.
    :param output: comparison folder.
    :param overrides: see :meth:`Preset.compare_kwargs` (``None`` keeps the preset's value).
    :return: the comparison's result.
    """
    from sb3_gcrl.compare.comparison import compare

    return compare(**get_preset(name).compare_kwargs(output=output, **overrides))
