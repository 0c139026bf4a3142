"""Reproduce the tabular post-exploration ablation of thesis Ch. 6 (Fig. 6.3, Fig. 6.4, Table 6.2 settings).

For every task and variant (``off`` = no post-exploration, ``on`` = ``p_pe = 0.5`` as Table 6.2, ``adaptive`` =
our :class:`~sb3_gcrl.post_exploration.NoveltyAdaptive`) it trains :class:`~sb3_gcrl.imgep.TabularIMGEP`
over seeds x epsilons, evaluates the greedy success over all reachable goals every ``--eval-freq`` steps, and
writes ``results.json``, ``summary.md`` (final table), ``curves.png`` (Fig. 6.3-style) and
``heatmap_<task>.png`` (Fig. 6.4-style visitation heatmaps, seed 0, epsilon 0.1).

Lava tasks use a different layout per seed (the thesis's "environment seeds"); FourRooms keeps layout 0.

Example (a few minutes on one core)::

    nice -n 10 python scripts/reproduce_ch6.py --tasks FourRooms LavaGap LavaCrossing --seeds 5 --steps 100000

Deep IMGEP (Fig. 6.5 / 6.6; DDPG + HER 'future' k = 4, Table 6.3 settings via
:class:`~sb3_gcrl.post_exploration.PostExplorationWrapper`): ``--tasks FetchReach PointUMaze --algo ddpg``; the
all-goals success is measured on a fixed grid of goals (FetchReach: 3x3x3 around the initial gripper position
within the target range; PointUMaze: 4 points in each free cell of the U) and the entropy curve (Eq. 6.7) over
the goal-space bins is recorded at each evaluation.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch as th

import sb3_gcrl  # noqa: F401  (registers GCRL/ envs)
from sb3_gcrl.her import ExecutedActionHerReplayBuffer
from sb3_gcrl.imgep import TabularGoalEnv, TabularIMGEP
from sb3_gcrl.post_exploration import (
    AllGoalsEvalCallback,
    NoveltyAdaptive,
    PostExplorationCallback,
    PostExplorationWrapper,
    ProportionalSteps,
    visitation_entropy,
)

TASKS = {
    "FourRooms": "GCRL/FourRoomsTabular-v0",
    "LavaCrossing": "GCRL/LavaCrossingTabular-v0",
    "LavaGap": "GCRL/LavaGapTabular-v0",
}
VARIANTS = ("off", "on", "adaptive")
#: Table 6.3 (n_pe, n_bins, tau, noise) and the goal-space box used for bins
DEEP_TASKS = {
    "FetchReach": {
        "env_id": "FetchReach-v4",
        "n_pe": 30,
        "n_bins": 20,
        "tau": 0.0,
        "noise": 0.01,
        "low": [1.0, 0.4, 0.35],
        "high": [1.7, 1.1, 0.95],
        "eval_steps": 50,
    },
    "PointUMaze": {
        "env_id": "GCRL/PointUMazeGoal-v0",
        "n_pe": 50,
        "n_bins": 100,
        "tau": 0.01,
        "noise": 0.1,
        "low": [-1.5, -1.5],
        "high": [1.5, 1.5],
        "eval_steps": 150,  # per goal of the grid (the env's horizon is 300)
    },
}


def deep_goal_grid(task: str, env: gym.Env) -> np.ndarray:
    """Fixed evaluation goals over the reachable goal space (see the module docstring)."""
    if task == "FetchReach":
        centre, r = env.unwrapped.initial_gripper_xpos, env.unwrapped.target_range
        axes = [np.linspace(c - r, c + r, 3) for c in centre]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    maze = env.unwrapped.maze
    offsets = np.array([[-0.25, -0.25], [-0.25, 0.25], [0.25, -0.25], [0.25, 0.25]])
    cells = [
        maze.cell_rowcol_to_xy(np.array([i, j]))
        for i, row in enumerate(maze.maze_map)
        for j, free in enumerate(row)
        if free == 0
    ]
    return np.concatenate([c + offsets for c in cells])


class EntropyRecorder(AllGoalsEvalCallback):
    """All-goals evaluation that also records the visitation entropy (Eq. 6.7) of the training env's goal space."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.entropies: list[float] = []

    def _evaluate(self) -> None:
        before = len(self.timesteps)
        super()._evaluate()
        if len(self.timesteps) > before:
            space = self.training_env.get_attr("goal_space")[0]
            self.entropies.append(visitation_entropy(space.counts))


def run_deep(task: str, variant: str, seed: int, algo: str, steps: int, eval_freq: int) -> dict:
    """Train one deep IMGEP agent (DDPG or SAC + HER) with post-exploration off / on / adaptive."""
    from stable_baselines3 import DDPG, SAC
    from stable_baselines3.common.noise import NormalActionNoise

    spec = DEEP_TASKS[task]
    goal_kwargs = {"tau": spec["tau"], "goal_low": spec["low"], "goal_high": spec["high"], "n_bins": spec["n_bins"]}
    rule = {"adaptive": {"n_pe": spec["n_pe"]}} if variant == "adaptive" else {"n_pe": spec["n_pe"]}
    env = PostExplorationWrapper(
        gym.make(spec["env_id"]), post_exploration=variant != "off", scheduler_kwargs=goal_kwargs, **rule
    )
    eval_env = PostExplorationWrapper(gym.make(spec["env_id"]), n_pe=1, scheduler="env_default")  # episodic
    kwargs = {
        "learning_rate": 1e-3,
        "gamma": 0.98,
        "batch_size": 256,
        "learning_starts": 4 * (env.spec.max_episode_steps or 300),  # > longest episode (HER needs it complete)
        "policy_kwargs": {"net_arch": [256, 256, 256]},
        "replay_buffer_class": ExecutedActionHerReplayBuffer,
        "replay_buffer_kwargs": {"n_sampled_goal": 4, "goal_selection_strategy": "future"},
        "seed": seed,
    }
    if algo == "ddpg":
        n_actions = env.action_space.shape[0]
        kwargs["action_noise"] = NormalActionNoise(np.zeros(n_actions), spec["noise"] * np.ones(n_actions))
    model = (DDPG if algo == "ddpg" else SAC)("MultiInputPolicy", env, **kwargs)
    goals = deep_goal_grid(task, eval_env)
    recorder = EntropyRecorder(eval_env, eval_freq=eval_freq, goals=goals, max_steps=spec["eval_steps"])
    start = time.perf_counter()
    model.learn(steps, callback=[PostExplorationCallback(log_freq=eval_freq), recorder])
    return {
        "task": task,
        "variant": variant,
        "seed": seed,
        "epsilon": 0.1,
        "algo": algo,
        "timesteps": recorder.timesteps,
        "success": recorder.success_rates,
        "entropy_curve": recorder.entropies,
        "entropy": recorder.entropies[-1],
        "coverage": float(np.count_nonzero(env.goal_space.counts) / env.goal_space.n_cells),
        "post_exploration_steps": env.post_exploration_steps,
        "episodes": env.episodes,
        "wall_s": time.perf_counter() - start,
    }


def run_one(task: str, variant: str, seed: int, epsilon: float, steps: int, eval_freq: int) -> dict:
    """Train one agent; return its all-goals success curve, final entropy/coverage and visit counts."""
    layout_seed = 0 if task == "FourRooms" else seed
    env = gym.make(TASKS[task], layout_seed=layout_seed)
    eval_env = TabularGoalEnv(gym.make(TASKS[task], layout_seed=layout_seed))
    rule = NoveltyAdaptive(p_pe=0.5) if variant == "adaptive" else ProportionalSteps(0.5)
    model = TabularIMGEP(
        "TabularGoalPolicy",
        env,
        learning_rate=0.1,
        gamma=0.99,
        epsilon=epsilon,
        tau=0.0,
        post_exploration=variant != "off",
        post_exploration_rule=rule,
        seed=seed,
    )
    callback = AllGoalsEvalCallback(eval_env, eval_freq=eval_freq)
    start = time.perf_counter()
    model.learn(steps, callback=callback, log_interval=0)
    return {
        "task": task,
        "variant": variant,
        "seed": seed,
        "epsilon": epsilon,
        "timesteps": callback.timesteps,
        "success": callback.success_rates,
        "entropy": model.visitation_entropy(),
        "coverage": model.coverage(),
        "post_exploration_steps": model._n_post_exploration_steps,
        "episodes": model._n_episodes,
        "wall_s": time.perf_counter() - start,
        "counts": model.goal_space.counts.tolist(),
        "width": int(env.unwrapped.width),
    }


def summarise(runs: list[dict]) -> str:
    """Markdown tables: final all-goals success / entropy / coverage per task and variant (median, mean +- se),
    paired differences (same seed and epsilon) between variants, and a per-epsilon breakdown."""
    lines = [
        "| task | variant | runs | success all goals: median | mean +- se | AUC (mean over evals) | "
        "entropy (nats) median | coverage median | post-expl. steps median |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for task in dict.fromkeys(r["task"] for r in runs):
        for variant in VARIANTS:
            sel = [r for r in runs if r["task"] == task and r["variant"] == variant]
            if not sel:
                continue
            final = np.array([r["success"][-1] for r in sel])
            auc = np.array([np.mean(r["success"]) for r in sel])
            se = final.std(ddof=1) / np.sqrt(len(final)) if len(final) > 1 else 0.0
            lines.append(
                f"| {task} | {variant} | {len(sel)} | {np.median(final):.3f} | {final.mean():.3f} +- {se:.3f} | "
                f"{auc.mean():.3f} | {np.median([r['entropy'] for r in sel]):.3f} | "
                f"{np.median([r['coverage'] for r in sel]):.3f} | "
                f"{np.median([r['post_exploration_steps'] for r in sel]):.0f} |"
            )
    lines += [
        "",
        "| task | comparison | pairs | AUC diff median | AUC wins | final diff median | entropy diff median | "
        "entropy wins |",
    ]
    lines.append("|---|---|---|---|---|---|---|---|")
    for task in dict.fromkeys(r["task"] for r in runs):
        by_key = {(r["variant"], r["seed"], r["epsilon"]): r for r in runs if r["task"] == task}
        for variant, reference in (("on", "off"), ("adaptive", "off"), ("adaptive", "on")):
            pairs = [
                (run, by_key[(reference, seed, eps)])
                for (v, seed, eps), run in by_key.items()
                if v == variant and (reference, seed, eps) in by_key
            ]
            if not pairs:
                continue
            d_auc = np.array([np.mean(a["success"]) - np.mean(b["success"]) for a, b in pairs])
            d_final = np.array([a["success"][-1] - b["success"][-1] for a, b in pairs])
            d_ent = np.array([a["entropy"] - b["entropy"] for a, b in pairs])
            lines.append(
                f"| {task} | {variant} - {reference} | {len(pairs)} | {np.median(d_auc):+.3f} | "
                f"{int((d_auc > 0).sum())}/{len(pairs)} | {np.median(d_final):+.3f} | {np.median(d_ent):+.3f} | "
                f"{int((d_ent > 0).sum())}/{len(pairs)} |"
            )
    epsilons = sorted({r["epsilon"] for r in runs})
    if len(epsilons) > 1:
        lines += ["", "| task | variant | " + " | ".join(f"eps={e:g}: final (AUC)" for e in epsilons) + " |"]
        lines.append("|---|---|" + "---|" * len(epsilons))
        for task in dict.fromkeys(r["task"] for r in runs):
            for variant in VARIANTS:
                cells = []
                for eps in epsilons:
                    sel = [r for r in runs if r["task"] == task and r["variant"] == variant and r["epsilon"] == eps]
                    if sel:
                        final = np.median([r["success"][-1] for r in sel])
                        cells.append(f"{final:.3f} ({np.mean([np.mean(r['success']) for r in sel]):.3f})")
                if cells:
                    lines.append(f"| {task} | {variant} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(runs: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(dict.fromkeys(r["task"] for r in runs))
    fig, axes = plt.subplots(1, len(tasks), figsize=(5 * len(tasks), 3.6), squeeze=False)
    colors = {"off": "tab:orange", "on": "tab:blue", "adaptive": "tab:green"}
    for ax, task in zip(axes[0], tasks):
        for variant in VARIANTS:
            sel = [r for r in runs if r["task"] == task and r["variant"] == variant]
            if not sel:
                continue
            x = np.array(sel[0]["timesteps"])
            n = min(len(r["success"]) for r in sel)
            y = np.array([r["success"][:n] for r in sel])
            mean, se = y.mean(0), y.std(0) / np.sqrt(len(y))
            ax.plot(x[:n], mean, color=colors[variant], label=variant)
            ax.fill_between(x[:n], mean - se, mean + se, color=colors[variant], alpha=0.2)
        ax.set_title(task)
        ax.set_xlabel("environment steps")
        ax.set_ylabel("greedy success over all goals")
        ax.legend()
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=120)
    deep = [task for task in tasks if task in DEEP_TASKS]
    if deep:
        fig, axes = plt.subplots(1, len(deep), figsize=(5 * len(deep), 3.6), squeeze=False)
        for ax, task in zip(axes[0], deep):
            for variant in VARIANTS:
                sel = [r for r in runs if r["task"] == task and r["variant"] == variant]
                if not sel:
                    continue
                n = min(len(r["entropy_curve"]) for r in sel)
                y = np.array([r["entropy_curve"][:n] for r in sel])
                ax.plot(sel[0]["timesteps"][:n], y.mean(0), color=colors[variant], label=variant)
            ax.set_title(f"{task}: visitation entropy (Eq. 6.7)")
            ax.set_xlabel("environment steps")
            ax.legend()
        fig.tight_layout()
        fig.savefig(out / "entropy.png", dpi=120)
    for task in tasks:
        if "counts" not in runs[0]:
            continue
        sel = [r for r in runs if r["task"] == task and r["seed"] == 0 and r["epsilon"] == 0.1]
        if not sel:
            continue
        fig, axes = plt.subplots(1, len(sel), figsize=(4 * len(sel), 3.6), squeeze=False)
        for ax, r in zip(axes[0], sel):
            counts = np.array(r["counts"], dtype=float).reshape(-1, r["width"])
            im = ax.imshow(np.log1p(counts), cmap="viridis")
            ax.set_title(f"{task} {r['variant']}: log(1 + visits)")
            fig.colorbar(im, ax=ax, fraction=0.046)
        fig.tight_layout()
        fig.savefig(out / f"heatmap_{task}.png", dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=[*TASKS, *DEEP_TASKS])
    parser.add_argument("--algo", default="ddpg", choices=["ddpg", "sac"], help="deep tasks only")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--seeds", type=int, default=5, help="seeds (lava tasks: also the layout seeds)")
    parser.add_argument("--epsilons", type=float, nargs="+", default=[0.0, 0.1, 0.3], help="Table 6.2")
    parser.add_argument("--steps", type=int, default=100_000, help="env steps per run (thesis figures: 200k+)")
    parser.add_argument("--eval-freq", type=int, default=10_000)
    parser.add_argument("--out", type=Path, default=Path("results/ch6"))
    parser.add_argument("--from-json", action="store_true", help="re-summarise and re-plot OUT/results.json")
    args = parser.parse_args()
    if args.from_json:
        runs = json.loads((args.out / "results.json").read_text())
        table = summarise(runs)
        (args.out / "summary.md").write_text(table + "\n")
        print(table)
        plot(runs, args.out)
        return
    th.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    runs = []
    for task in args.tasks:
        for variant in args.variants:
            for seed in range(args.seeds):
                for epsilon in args.epsilons if task in TASKS else [0.1]:
                    if task in TASKS:
                        runs.append(run_one(task, variant, seed, epsilon, args.steps, args.eval_freq))
                    else:
                        runs.append(run_deep(task, variant, seed, args.algo, args.steps, args.eval_freq))
                    r = runs[-1]
                    print(
                        f"{task:12s} {variant:8s} seed={seed} eps={epsilon:.1f} success={r['success'][-1]:.3f} "
                        f"entropy={r['entropy']:.3f} coverage={r['coverage']:.3f} ({r['wall_s']:.1f}s)",
                        flush=True,
                    )
    (args.out / "results.json").write_text(json.dumps(runs))
    table = summarise(runs)
    (args.out / "summary.md").write_text(table + "\n")
    print(table)
    plot(runs, args.out)


if __name__ == "__main__":
    main()
