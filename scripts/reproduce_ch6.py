"""Reproduce the tabular post-exploration ablation of thesis Ch. 6 (Fig. 6.3, Fig. 6.4, Table 6.2 settings).

For every task and variant (``off`` = no post-exploration, ``on`` = ``p_pe = 0.5`` as Table 6.2, ``adaptive`` =
our :class:`~sb3_gcrl.post_exploration.NoveltyAdaptive`) it trains :class:`~sb3_gcrl.imgep.TabularIMGEP`
over seeds x epsilons, evaluates the greedy success over all reachable goals every ``--eval-freq`` steps, and
writes ``results.json``, ``summary.md`` (final table), ``curves.png`` (Fig. 6.3-style) and
``heatmap_<task>.png`` (Fig. 6.4-style visitation heatmaps, seed 0, epsilon 0.1).

Lava tasks use a different layout per seed (the thesis's "environment seeds"); FourRooms keeps layout 0.

Example (a few minutes on one core)::

    nice -n 10 python scripts/reproduce_ch6.py --tasks FourRooms LavaGap LavaCrossing --seeds 5 --steps 100000
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
from sb3_gcrl.imgep import TabularGoalEnv, TabularIMGEP
from sb3_gcrl.post_exploration import AllGoalsEvalCallback, NoveltyAdaptive, ProportionalSteps

TASKS = {
    "FourRooms": "GCRL/FourRoomsTabular-v0",
    "LavaCrossing": "GCRL/LavaCrossingTabular-v0",
    "LavaGap": "GCRL/LavaGapTabular-v0",
}
VARIANTS = ("off", "on", "adaptive")


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
    """Markdown table: final all-goals success / entropy / coverage per task and variant (median, mean +- se)."""
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
    for task in tasks:
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
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=list(TASKS))
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--seeds", type=int, default=5, help="seeds (lava tasks: also the layout seeds)")
    parser.add_argument("--epsilons", type=float, nargs="+", default=[0.0, 0.1, 0.3], help="Table 6.2")
    parser.add_argument("--steps", type=int, default=100_000, help="env steps per run (thesis figures: 200k+)")
    parser.add_argument("--eval-freq", type=int, default=10_000)
    parser.add_argument("--out", type=Path, default=Path("results/ch6"))
    args = parser.parse_args()
    th.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    runs = []
    for task in args.tasks:
        for variant in args.variants:
            for seed in range(args.seeds):
                for epsilon in args.epsilons:
                    runs.append(run_one(task, variant, seed, epsilon, args.steps, args.eval_freq))
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
