"""Thesis Ch. 4 learning comparison: CEC vs SAC on GrowingTree, PointUMaze, Point4Rooms, sparse MountainCar.

Hyperparameters come from ``zoo_configs/cec.yml`` and ``zoo_configs/sac_ch4.yml`` (the same files
``sb3-gcrl train`` uses). Every ``--eval-freq`` steps each agent is evaluated greedily
(``deterministic=True``) for ``--eval-episodes`` episodes; an episode counts as a success when its
return is positive (all four tasks reward only reaching the goal). Per run a JSON curve is written
to ``--out``; at the end a table prints, per task and algorithm, the mean (and per-seed values) of
the evaluation success at each checkpoint, and for GrowingTree the first step with success 1.0.

Example (the budget of the report)::

    python scripts/reproduce_ch4.py --tasks GrowingTree --algos cec --seeds 0 1 2 3 4 --budget 5000 --eval-freq 500
    python scripts/reproduce_ch4.py --tasks PointUMaze Point4Rooms MountainCar --algos cec sac \\
        --seeds 0 1 2 --budget 20000 --eval-freq 5000 --workers 2
"""

from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
TASKS = {
    "GrowingTree": "GCRL/GrowingTree-v0",
    "PointUMaze": "GCRL/PointUMaze-v0",
    "Point4Rooms": "GCRL/Point4Rooms-v0",
    "MountainCar": "GCRL/SparseMountainCarContinuous-v0",
}
CONFIGS = {"cec": ROOT / "zoo_configs" / "cec.yml", "sac": ROOT / "zoo_configs" / "sac_ch4.yml"}
NOT_MODEL_KWARGS = ("n_timesteps", "n_envs", "normalize", "env_wrapper", "callback")


def hyperparameters(algo: str, env_id: str) -> dict[str, Any]:
    with open(CONFIGS[algo]) as f:
        config = yaml.safe_load(f)
    return {k: v for k, v in config[env_id].items() if k not in NOT_MODEL_KWARGS}


def run(task: str, algo: str, seed: int, budget: int, eval_freq: int, eval_episodes: int, out: str) -> dict:
    """Train one agent and return its evaluation curve (also written to ``out``)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import gymnasium as gym
    import torch
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.evaluation import evaluate_policy

    import sb3_gcrl  # noqa: F401
    from sb3_gcrl import CEC

    torch.set_num_threads(1)
    env_id = TASKS[task]
    eval_env = gym.make(env_id)
    eval_env.reset(seed=10_000 + seed)
    curve: dict[str, list] = {"steps": [], "success": [], "mean_return": []}

    class Evaluate(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % eval_freq == 0:
                returns, _ = evaluate_policy(
                    self.model, eval_env, n_eval_episodes=eval_episodes, deterministic=True, return_episode_rewards=True
                )
                curve["steps"].append(self.num_timesteps)
                curve["success"].append(float(np.mean(np.asarray(returns) > 0)))
                curve["mean_return"].append(float(np.mean(returns)))
            return True

    model_class = CEC if algo == "cec" else SAC
    model = model_class(env=gym.make(env_id), seed=seed, **hyperparameters(algo, env_id))
    start = time.perf_counter()
    model.learn(budget, callback=Evaluate(), log_interval=None)
    result = dict(task=task, algo=algo, seed=seed, budget=budget, wall_s=time.perf_counter() - start, **curve)
    path = Path(out) / f"{task}_{algo}_{seed}.json"
    path.write_text(json.dumps(result))
    return result


def print_table(results: list[dict]) -> None:
    print("\n| task | algo | seeds | success at steps (mean; per seed) | first step with success 1.0 | wall s/run |")
    print("|---|---|---|---|---|---|")
    for task in TASKS:
        for algo in CONFIGS:
            runs = sorted((r for r in results if r["task"] == task and r["algo"] == algo), key=lambda r: r["seed"])
            if not runs:
                continue
            steps = runs[0]["steps"]
            cells = []
            for i, step in enumerate(steps):
                values = [r["success"][i] for r in runs if i < len(r["success"])]
                cells.append(f"{step}: {np.mean(values):.2f} ({', '.join(f'{v:.1f}' for v in values)})")
            first = [next((s for s, v in zip(r["steps"], r["success"]) if v >= 1.0), None) for r in runs]
            solved = sum(f is not None for f in first)
            wall = np.median([r["wall_s"] for r in runs])
            print(
                f"| {task} | {algo} | {len(runs)} | {'<br>'.join(cells)} | {solved}/{len(runs)} solved: {first} "
                f"| {wall:.0f} |"
            )


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = [t for t in TASKS if any(r["task"] == t for r in results)]
    fig, axes = plt.subplots(1, len(tasks), figsize=(4 * len(tasks), 3), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        for algo in CONFIGS:
            runs = [r for r in results if r["task"] == task and r["algo"] == algo]
            if not runs:
                continue
            n = min(len(r["success"]) for r in runs)
            success = np.array([r["success"][:n] for r in runs])
            steps = runs[0]["steps"][:n]
            mean, sem = success.mean(0), success.std(0) / np.sqrt(len(runs))
            ax.plot(steps, mean, label=f"{algo.upper()} ({len(runs)} seeds)")
            ax.fill_between(steps, mean - sem, mean + sem, alpha=0.2)
        ax.set_title(task)
        ax.set_xlabel("env steps")
        ax.set_ylim(-0.05, 1.05)
    axes[0][0].set_ylabel("eval success")
    axes[0][-1].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    print(f"curves: {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=list(TASKS))
    parser.add_argument("--algos", nargs="+", default=["cec", "sac"], choices=list(CONFIGS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--budget", type=int, default=100_000, help="env steps per run")
    parser.add_argument("--eval-freq", type=int, default=10_000)
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument("--workers", type=int, default=1, help="parallel processes")
    parser.add_argument("--out", default="results/ch4")
    parser.add_argument("--table-only", action="store_true", help="only print the table of the runs in --out")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if not args.table_only:
        jobs = [
            (task, algo, seed, args.budget, args.eval_freq, args.eval_episodes, str(out))
            for task in args.tasks
            for algo in args.algos
            for seed in args.seeds
        ]
        with ProcessPoolExecutor(args.workers) as pool:
            for result in pool.map(run, *zip(*jobs)):
                print(f"done {result['task']} {result['algo']} seed {result['seed']}: {result['success']}", flush=True)
    results = [json.loads(p.read_text()) for p in sorted(out.glob("*.json"))]
    results = [r for r in results if r["task"] in args.tasks and r["algo"] in args.algos]
    print_table(results)
    plot(results, out / "curves.png")


if __name__ == "__main__":
    main()
